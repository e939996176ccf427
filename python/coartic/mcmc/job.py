"""The MCMC job as a library function: ``sample(spec, fit, out)`` is ``coartic mcmc`` without the console.

``sample`` reads the fit spec and its ``[mcmc]`` section, finds the least-squares table, claims
``out`` (resuming the chains it holds), samples every posterior the configuration asks for, and
writes what the command writes: per posterior its chunks, ``posterior.nc`` (ArviZ InferenceData),
``summary.json`` and plots; the table with the posterior quantiles (``table.json``/``table.csv``),
``mcmc.html``, ``mcmc.json`` and the fragment in the fit's report. It returns an ``McmcResult``.
``coartic mcmc`` (``mcmc_cli``) prints it; ``coartic batch`` calls ``sample_table``, the sampling of
one table on loaded utterances, which ``sample`` calls too.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from coartic.extras import require
from coartic.fit.data import load_utterances
from coartic.mcmc import plots
from coartic.mcmc.idata import split_name
from coartic.mcmc.run import (ChannelSampling, McmcConfig, PosteriorRun, channel_runs, fixed_noise, read_spec,
                              table_problem, table_speakers)
from coartic.mcmc.sampler import SCOPES
from coartic.mcmc.summary import QUANTILE_LEVELS, write_uncertainty
from coartic.outputs import OutputDir, OutputError, atomic_write_text, read_marker
from coartic.table import ParameterTable
from coartic.mcmc.errors import McmcConfigError, McmcError
from coartic.model import Utterance

if TYPE_CHECKING:
    from coartic.fit.spec import FitSpec


def find_table(fit: Path) -> Path:
    """The least-squares table: ``fit`` itself if a file, else the table JSON inside the fit directory."""
    if fit.is_file():
        return fit
    if not fit.is_dir():
        raise FileNotFoundError(f"{fit}: no such fit directory or table file")
    for name in ("table.json", "parameters.json", "fitted_table.json"):
        if (fit / name).is_file():
            return fit / name
    found = []
    for p in sorted(fit.glob("*.json")):
        try:
            if json.loads(p.read_text()).get("schema") == "coartic.table/1":
                found.append(p)
        except (OSError, ValueError, AttributeError):
            continue
    if len(found) != 1:
        what = "no" if not found else f"{len(found)} ({', '.join(p.name for p in found)})"
        raise FileNotFoundError(f"{fit}: expected one parameter table (coartic.table/1 JSON), found {what}; pass the file itself with --fit")
    return found[0]


def mcmc_output(spec: Path, fit: Path, table_path: Path, out: Path, force: bool = False) -> OutputDir:
    """``out`` claimed for this job, in place (its chains are resumed). Refused if it is, or is
    inside, the fit directory (a new fit replaces that directory whole, and the fit's table.json
    must not be overwritten by the table with uncertainty), if its table.json would be the table
    sampled from, or if it holds another spec's or fit's chains."""
    here = Path(os.path.abspath(out))
    table_abs = Path(os.path.abspath(table_path))
    fit_dir = Path(os.path.abspath(fit)) if fit.is_dir() else table_abs.parent
    is_fit_output = fit.is_dir() or (read_marker(fit_dir) or {}).get("command") == "fit"
    if here / "table.json" == table_abs or (is_fit_output and (here == fit_dir or fit_dir in here.parents)):
        where = "the" if here == fit_dir else "inside the"
        raise OutputError(f"--out {out}: is {where} fit directory {fit_dir}; the MCMC table would overwrite the "
                          "least-squares one, and a new fit replaces that directory whole. Choose an output "
                          f"directory beside it, e.g. --out {fit_dir.with_name(fit_dir.name + '_mcmc')}")
    def legacy(d: Path) -> bool:
        # chains written before coartic_run.json: resumed as before (each posterior's chains/meta.json
        # still refuses chains of another posterior), not deleted by a --force the user had to give
        return (d / "mcmc.json").is_file() or any(d.glob("*/*/chains/meta.json"))

    return OutputDir(out, "mcmc", {"spec": str(spec.resolve()), "fit": str(table_abs.resolve())},
                     force=force, staged=False, protect=[spec, table_path], recognise=legacy)


STALE_TOLERANCE = 0.01


def check_fit_matches_data(table: ParameterTable, table_path: Path, sampling: ChannelSampling,
                           allow_stale: bool = False) -> None:
    """Refuse a table fitted to other data: the RMSE at its values on the data loaded now must be
    the RMSE the fit recorded (metadata.rmse), to 1 %. Otherwise the walkers would not start at the
    optimum and every per-phoneme posterior would be conditioned on values that no longer fit."""
    channel = sampling.channel
    recorded = (table.metadata or {}).get("rmse", {}).get(channel)
    if recorded is None or allow_stale:
        return
    now = fixed_noise(sampling.data, sampling.packing, sampling.options, speakers=sampling.speakers)
    if abs(now - recorded) > STALE_TOLERANCE * recorded:
        raise McmcError(
            f"{table_path}: fitted to other data than the spec gives now: on {channel} the RMSE at the table's "
            f"values is {now:.4f} mm, the fit recorded {recorded:.4f} mm (metadata.rmse). Refit with coartic fit, "
            "or pass --allow-stale-fit to sample anyway"
        )


def configure(cfg: McmcConfig, *, channels: Sequence[str] | None = None, phonemes: Sequence[str] | None = None,
              scope: str | None = None, max_steps: int | None = None) -> McmcConfig:
    """``cfg`` with the command line's (or a caller's) overrides of its ``[mcmc]`` keys."""
    cfg = replace(cfg, settings=replace(cfg.settings))
    if channels:
        cfg.channels = tuple(channels)
    if phonemes:
        cfg.phonemes = tuple(phonemes)
    if scope:
        if scope not in SCOPES:
            raise McmcConfigError(f"scope {scope!r}: expected one of {', '.join(SCOPES)}")
        cfg.scope = scope
    if max_steps is not None:
        cfg.settings.max_steps = max_steps
        cfg.settings.min_steps = min(cfg.settings.min_steps, max_steps)
    return cfg


def record_posterior(table: ParameterTable, run: PosteriorRun) -> None:
    """Put a finished posterior's quantiles into ``table`` and keep metadata.mcmc.not_converged
    (the posteriors whose intervals are not to be trusted) up to date."""
    write_uncertainty(table, run.channel, run.summaries)
    meta = table.metadata.setdefault("mcmc", {})
    if run.held_fixed:  # what the fit estimated but no posterior sampled: no interval for it
        meta.setdefault("held_fixed", {})[run.channel] = list(run.held_fixed)
    bad = meta.setdefault("not_converged", [])
    if not run.result.converged and run.label not in bad:
        bad.append(run.label)
    if run.result.converged and run.label in bad:
        bad.remove(run.label)


def sample_table(fit_spec: FitSpec, cfg: McmcConfig, table: ParameterTable, table_path: Path,
                 utterances: Sequence[Utterance], out: Path,
                 *, progress: bool = False, allow_stale: bool = False,
                 on_done: Callable[[PosteriorRun], None] | None = None) -> tuple[list[PosteriorRun], bool]:
    """Every posterior ``cfg`` asks for around the fitted ``table`` (read from ``table_path``), on
    ``utterances``, into ``out``; returns them and whether the run was interrupted (Ctrl-C: the
    posteriors after it are not started)."""
    runs: list[PosteriorRun] = []
    for channel in cfg.channels or fit_spec.channels:
        sampling = ChannelSampling.of(table_problem(fit_spec, table, channel, utterances),
                                      table_speakers(fit_spec, table, channel))
        check_fit_matches_data(table, table_path, sampling, allow_stale)
        done, interrupted = channel_runs(sampling, cfg, out, progress, on_done=on_done)
        runs += done
        if interrupted:
            return runs, True
    return runs, False


@dataclass
class McmcResult:
    """What ``sample`` did: every posterior (in order), whether interrupted, and where."""

    out: Path
    runs: list[PosteriorRun]
    interrupted: bool
    table: ParameterTable  # with the posterior quantiles

    @property
    def converged(self) -> bool:
        return bool(self.runs) and not self.interrupted and all(r.result.converged for r in self.runs)

    def to_dataframe(self) -> Any:
        """One row per posterior and sampled quantity (pandas): channel, phoneme, parameter,
        speaker, least-squares start, mean, sd, quantiles, R-hat, bulk ESS, identified, converged."""
        require("dataframe", "to_dataframe()")
        import pandas as pd

        rows = []
        for r in self.runs:
            for s in r.summaries:
                phoneme, parameter, speaker = split_name(s.name)
                rows.append({"posterior": r.label, "channel": r.channel, "phoneme": phoneme, "parameter": parameter,
                             "speaker": speaker, "start": s.start, "mean": s.mean, "sd": s.sd, **s.quantiles,
                             "rhat": s.rhat, "ess_bulk": s.ess_bulk, "identified": s.identified,
                             "converged": r.result.converged})
        columns = ["posterior", "channel", "phoneme", "parameter", "speaker", "start", "mean", "sd",
                   *QUANTILE_LEVELS, "rhat", "ess_bulk", "identified", "converged"]
        return pd.DataFrame(rows, columns=columns)


def sample(spec: str | Path, fit: str | Path, out: str | Path, *, channels: Sequence[str] | None = None,
           phonemes: Sequence[str] | None = None, scope: str | None = None, max_steps: int | None = None,
           progress: bool = False, allow_stale: bool = False, force: bool = False) -> McmcResult:
    """Sample the posteriors of a least-squares fit, as ``coartic mcmc SPEC --fit FIT --out OUT``.

    ``spec``: the fit spec the table was fitted with (its ``[mcmc]`` section configures sampling;
    ``channels``, ``phonemes``, ``scope`` and ``max_steps`` override it). ``fit``: the fit's output
    directory or its table. A rerun into the same ``out`` resumes the saved chains.
    """
    require("mcmc", "coartic mcmc")
    spec, fit, out = Path(spec), Path(fit), Path(out)
    fit_spec, cfg = read_spec(spec)
    cfg = configure(cfg, channels=channels, phonemes=phonemes, scope=scope, max_steps=max_steps)
    table_path = find_table(fit)
    with mcmc_output(spec, fit, table_path, out, force) as directory:
        table = ParameterTable.load(table_path)
        utterances = load_utterances(fit_spec)
        directory.mkdir(parents=True, exist_ok=True)
        runs: list[PosteriorRun] = []
        sections: list[str] = []

        def save(r: PosteriorRun) -> None:
            # after every posterior, so an interrupted job keeps what is finished
            runs.append(r)
            if r.result.interrupted:
                return  # chains saved for resuming; no intervals from a partial chain
            record_posterior(table, r)
            table.save(directory / "table.json")
            table.save(directory / "table.csv")
            verdict = r.result.report.summary() if r.result.report else "no convergence check"
            sections.append(plots.html_fragment(r.label, r.images, r.summaries, verdict.splitlines()[0],
                                                r.result.converged, directory))
            atomic_write_text(directory / "mcmc.html", _wrap("".join(sections)))
            add_to_fit_report(table_path.parent, directory, runs)
            index = [
                {"label": x.label, "channel": x.channel, "phoneme": x.phoneme, "converged": x.result.converged,
                 "held_fixed": x.held_fixed,
                 "directory": str(x.directory.relative_to(directory)),
                 "inference_data": str((x.directory / "posterior.nc").relative_to(directory)),
                 "images": [str(p.relative_to(directory)) for p in x.images]}
                for x in runs
            ]
            atomic_write_text(directory / "mcmc.json", json.dumps(index, indent=1))

        _, interrupted = sample_table(fit_spec, cfg, table, table_path, utterances, directory, progress=progress,
                                      allow_stale=allow_stale, on_done=save)
    return McmcResult(out, runs, interrupted, table)


def _wrap(body: str) -> str:
    return f'<div class="coartic-mcmc">\n<h2>Posteriors (emcee)</h2>\n{body}</div>\n'


BEGIN, END = "<!-- coartic-mcmc begin -->", "<!-- coartic-mcmc end -->"


def add_to_fit_report(fit_dir: Path, out: Path, runs: list[PosteriorRun]) -> Path:
    """Put the posteriors into the least-squares report: ``report_mcmc.html`` in the fit directory
    (the report includes every ``report_*.html`` when it is written) and, if ``report.html`` is
    already there, the same block inserted (or replaced) before its ``</body>``."""
    sections = []
    for r in runs:
        verdict = r.result.report.summary().splitlines()[0] if r.result.report else "no convergence check"
        section = plots.html_fragment(r.label, r.images, r.summaries, verdict, r.result.converged, out)
        # image paths as seen from the fit directory
        for p in r.images:
            rel_out = str(p.relative_to(out))
            section = section.replace(f'src="{rel_out}"', f'src="{os.path.relpath(p, fit_dir)}"')
        sections.append(section)
    block = f"{BEGIN}\n{_wrap(''.join(sections))}{END}\n"
    frag = fit_dir / "report_mcmc.html"
    atomic_write_text(frag, block)
    report = fit_dir / "report.html"
    if report.is_file():
        text = report.read_text(encoding="utf-8")
        if BEGIN in text and END in text:
            text = text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) + 1 :]
        elif "</body>" in text:
            text = text.replace("</body>", block + "</body>", 1)
        atomic_write_text(report, text)
    return frag


__all__ = ["sample", "sample_table", "McmcResult", "configure", "record_posterior", "find_table",
           "check_fit_matches_data", "mcmc_output", "add_to_fit_report"]
