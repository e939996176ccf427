"""One HTML report of a fit (jinja2 template), with its figures saved as PNG beside it.

Other parts (the MCMC report) add sections by dropping an HTML fragment named
``report_*.html`` into the same directory: it is included at the end of the page.

Everything else is escaped (``autoescape=True``: the template's ``.j2`` suffix would defeat
``select_autoescape``), so a spec name, a file name or a manifest cell holding markup is shown as
text, never run in the reader's browser. Only those fragments, which the project writes itself
with their own values escaped (coartic.mcmc.plots.html_fragment), are passed as ``Markup``.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Any

import jinja2
import markupsafe
from rich.console import Console

from coartic.estimation.bounds import summary_counts
from coartic.evaluation.choose import Choice
from coartic.evaluation.heldout import flags, held_out, pooled
from coartic.fit.result import BAR_MM, FitResult
from coartic.report import plots
from coartic.outputs import atomic_write_text
from coartic.settings import CHANNEL_SETTINGS
from coartic.table import ParameterTable

_TEMPLATES = Path(__file__).with_name("templates")


def _ground_truth(result: FitResult) -> ParameterTable | None:
    """The session's ground_truth.json beside the manifest, when there is one (synthetic data)."""
    m = None if result.spec.corpus is None else result.spec.corpus.manifest
    if m is None or not (m.parent / "ground_truth.json").is_file():
        return None
    try:
        return ParameterTable.load(m.parent / "ground_truth.json")
    except ValueError:
        return None


# The page's figure sections, in the order a phonetician reads them: what the model does against
# the measurements, where it misses, how it does on data it did not see, then the rest.
SECTIONS = (("trajectories", "Trajectories and dominance"), ("residuals", "Residuals"),
            ("heldout", "Held out: data the fit did not see"), ("other", "More figures"))


def one_line(reading: str) -> str:
    """The gist of an at-bound reading, for its row: the clause after the numbers ("T = 2 mm at the
    top of its box: /e/ heads for a value beyond anything measured on LA: …" gives "/e/ heads for a
    value beyond anything measured on LA"), asides in parentheses dropped. The whole reading opens
    on demand."""
    text = re.sub(r"\s*\([^()]*\)", "", reading)
    parts = text.split(": ")
    gist = parts[1] if len(parts) > 1 else parts[0]
    return gist.split(" — ")[0].split(". ")[0].rstrip(".")


def write_report(result: FitResult, out: str | Path, console: Console | None = None,
                 channel_for_trials: str = "LLO") -> Path:
    """Write ``out/report.html`` and its PNGs; return the HTML path.

    The page leads with the RMSE summary (held-out RMSE beside it when validated), then the
    figures, then the compact at-bound table whose explanations open on demand; sections with
    nothing to show are left out."""
    out = Path(out)
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    table = result.table()
    figures: dict[str, list[dict[str, str]]] = {name: [] for name, _ in SECTIONS}

    def add(fig: Any, name: str, caption: str, section: str) -> None:
        if fig is None:
            return
        plots.save(fig, fig_dir / name)
        figures[section].append({"src": f"figures/{name}", "caption": caption})

    ch = channel_for_trials if channel_for_trials in result.channels else next(iter(result.channels))
    fit = result.channels[ch]
    idx = plots.pick_utterances(fit, plots.FIGURE1_STIMULI)
    if not idx:
        idx = list(range(min(3, len(fit.problem.data.utterances))))
    add(plots.trajectory_figure(fit, table, idx), f"trajectories_{ch}.png",
        f"{ch}: measured (dots) and modelled (line) trajectories, with each segment's weight "
        "S·R·D/ΣR·D underneath (the dominance functions, as in the paper's Figure 1), one colour per phoneme.",
        "trajectories")
    for other in result.channels:
        if other == ch:
            continue
        o = result.channels[other]
        j = plots.pick_utterances(o, ("a p a", "u f u", "i t i")) or list(range(min(3, len(o.problem.data.utterances))))
        add(plots.trajectory_figure(o, table, j), f"trajectories_{other}.png",
            f"{other}: measured and modelled, with the segments' weights.", "trajectories")
    add(plots.residual_time_figure(result, [fit.problem.data.utterances[i].name for i in idx]), "residuals_time.png",
        f"Model − measured over time in the utterances above, every channel (dashed: ±{BAR_MM} mm).", "residuals")
    add(plots.residual_figure(result), "residuals.png",
        f"Residual distributions per channel (dashed: ±{BAR_MM} mm; black: normal with the same spread).",
        "residuals")
    add(plots.phoneme_rmse_figure(result), "rmse_phonemes.png",
        f"RMSE of the samples inside each phoneme's segments, per channel (dashed: the {BAR_MM} mm bar).",
        "residuals")
    add(plots.rmse_map_figure(result), "rmse_map.png",
        f"RMSE per consonant and vowel context; red outline: at or above the {BAR_MM} mm bar.", "residuals")
    if held_out(result):
        add(plots.heldout_figure(result), "heldout.png",
            "RMSE per channel on the samples the fit did not see (every split pooled), as measured and with each "
            "utterance's offset removed, beside the fit's own RMSE and the baselines' held-out RMSE on the same "
            f"samples (dashed: the {BAR_MM} mm bar).", "heldout")
    if isinstance(result.choice, Choice) and (out / "choose.png").is_file():  # written by result.save (choose.csv beside it)
        figures["other"].append({"src": "choose.png", "caption": f"{result.choice.choose.key} chosen by "
                                 "cross-validation on the training data: mean held-out RMSE ± one SE over the folds; "
                                 f"star: the chosen value (rule {result.choice.choose.rule}). The numbers are in "
                                 "choose.csv and the fit report below."})

    truth = _ground_truth(result)
    if truth is not None:
        add(plots.truth_figure(result, truth), "truth.png",
            "Synthetic session: fitted against ground-truth targets and resistances (grey: identity).", "other")

    # each model setting as the fit used it, with its default and meaning (coartic.settings)
    used = {ch: result.channel_settings(ch) for ch in result.channels}
    def shown(v: Any) -> str:
        return str(v).lower() if isinstance(v, bool) else f"{v:.4g}" if isinstance(v, float) else str(v)

    settings = [{"name": name, "meaning": s.meaning, "default": shown(s.default),
                 "values": {ch: shown(getattr(cs, name)) for ch, cs in used.items()}}
                for name, s in CHANNEL_SETTINGS.items()]
    bounds = [{"channel": c, "note": n, "line": one_line(n.reading)}
              for c, f in result.channels.items() if f.stats and f.stats.bounds for n in f.stats.bounds.values()]
    extras = [markupsafe.Markup(p.read_text(encoding="utf-8")) for p in sorted(out.glob("report_*.html"))]
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(_TEMPLATES), autoescape=True)
    html = env.get_template("fit_report.html.j2").render(
        result=result, spec=result.spec, bar=BAR_MM, figures=figures, sections=SECTIONS,
        # speech alone is a column of the channels' table, not a group
        group_rows=[r for r in result.rmse_rows() if r["group"] not in ("all", "speech")],
        speech=result.speech_rmse(),
        channels=result.channels, report_text=result.report_text(), extras=extras,
        validation=_validation_rows(out), validation_flags=flags(held_out(result)),
        heldout=_heldout_summary(result), bounds=bounds, settings=settings,
        bound_counts={c: summary_counts(f.stats.bounds) if f.stats else "" for c, f in result.channels.items()})
    path = out / "report.html"
    atomic_write_text(path, html)
    n_figures = sum(len(v) for v in figures.values())
    if console is not None:
        console.print(f"wrote the report with {n_figures} figures")  # (no path: it may be a staging directory)
    return path


def _heldout_summary(result: FitResult) -> dict[str, tuple[float, float, int]]:
    """Per channel, the held-out RMSE over every split's test samples (as measured, offset
    removed, samples): the summary table's column."""

    return pooled(held_out(result))


def _validation_rows(out: Path) -> list[dict[str, str]]:
    p = out / "validation" / "validation.csv"
    if not p.is_file():
        return []
    with p.open(newline="") as f:
        return list(csv.DictReader(f))
