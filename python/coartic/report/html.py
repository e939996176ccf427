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
from pathlib import Path
from typing import Any

import jinja2
import markupsafe
from rich.console import Console

from coartic.fit.bounds import summary_counts
from coartic.fit.result import BAR_MM, FitResult
from coartic.report import plots
from coartic.outputs import atomic_write_text
from coartic.table import ParameterTable

_TEMPLATES = Path(__file__).with_name("templates")


def _ground_truth(result: FitResult) -> ParameterTable | None:
    """The session's ground_truth.json beside the manifest, when there is one (synthetic data)."""
    m = result.spec.corpus.manifest
    if m is None or not (m.parent / "ground_truth.json").is_file():
        return None
    try:
        return ParameterTable.load(m.parent / "ground_truth.json")
    except ValueError:
        return None


def write_report(result: FitResult, out: str | Path, console: Console | None = None,
                 channel_for_trials: str = "LLO") -> Path:
    """Write ``out/report.html`` and its PNGs; return the HTML path."""
    out = Path(out)
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    table = result.table()
    figures: list[dict[str, str]] = []

    def add(fig: Any, name: str, caption: str) -> None:
        if fig is None:
            return
        plots.save(fig, fig_dir / name)
        figures.append({"src": f"figures/{name}", "caption": caption})

    ch = channel_for_trials if channel_for_trials in result.channels else next(iter(result.channels))
    fit = result.channels[ch]
    idx = plots.pick_utterances(fit, plots.FIGURE1_STIMULI)
    if not idx:
        idx = list(range(min(3, len(fit.problem.data.utterances))))
    add(plots.trajectory_figure(fit, table, idx), f"trajectories_{ch}.png",
        f"{ch}: measured (dots) and modelled (line) trajectories, with each segment's weight "
        "S·R·D/ΣR·D underneath (the dominance functions, as in the paper's Figure 1), one colour per phoneme.")
    for other in result.channels:
        if other == ch:
            continue
        o = result.channels[other]
        j = plots.pick_utterances(o, ("a p a", "u f u", "i t i")) or list(range(min(3, len(o.problem.data.utterances))))
        add(plots.trajectory_figure(o, table, j), f"trajectories_{other}.png", f"{other}: measured and modelled.")
    add(plots.residual_figure(result), "residuals.png",
        f"Residual distributions per channel (dashed: ±{BAR_MM} mm; black: normal with the same spread).")
    add(plots.residual_time_figure(result, [fit.problem.data.utterances[i].name for i in idx]), "residuals_time.png",
        f"Model − measured over time in the utterances above, every channel (dashed: ±{BAR_MM} mm).")
    add(plots.phoneme_rmse_figure(result), "rmse_phonemes.png",
        f"RMSE of the samples inside each phoneme's segments, per channel (dashed: the {BAR_MM} mm bar).")
    add(plots.rmse_map_figure(result), "rmse_map.png",
        f"RMSE per consonant and vowel context; red outline: at or above the {BAR_MM} mm bar.")
    if result.choice is not None and (out / "choose.png").is_file():  # written by result.save (choose.csv beside it)
        figures.append({"src": "choose.png", "caption": f"{result.choice.choose.key} chosen by cross-validation on the "
                        f"training data: mean held-out RMSE ± one SE over the folds; star: the chosen value "
                        f"(rule {result.choice.choose.rule}). The numbers are in choose.csv and the fit report below."})
    from coartic.fit.validate import flags

    truth = _ground_truth(result)
    if truth is not None:
        add(plots.truth_figure(result, truth), "truth.png",
            "Synthetic session: fitted against ground-truth targets and resistances (grey: identity).")

    rmse_rows = result.rmse_rows()
    extras = [markupsafe.Markup(p.read_text(encoding="utf-8")) for p in sorted(out.glob("report_*.html"))]
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(_TEMPLATES), autoescape=True)
    html = env.get_template("fit_report.html.j2").render(
        result=result, spec=result.spec, bar=BAR_MM, figures=figures, rmse_rows=rmse_rows,
        channels=result.channels, report_text=result.report_text(), extras=extras,
        validation=_validation_rows(out), validation_flags=flags(result.validation or []),
        bound_notes={c: list(f.stats.bounds.values()) for c, f in result.channels.items() if f.stats and f.stats.bounds},
        bound_counts={c: summary_counts(f.stats.bounds) if f.stats else "" for c, f in result.channels.items()})
    path = out / "report.html"
    atomic_write_text(path, html)
    if console is not None:
        console.print(f"wrote the report with {len(figures)} figures")  # (no path: it may be a staging directory)
    return path


def _validation_rows(out: Path) -> list[dict[str, str]]:
    p = out / "validation" / "validation.csv"
    if not p.is_file():
        return []
    with p.open(newline="") as f:
        return list(csv.DictReader(f))
