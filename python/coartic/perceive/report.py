"""The analysis as an HTML page with its plots (matplotlib, Agg), its numbers and its exclusions.

The page is a Jinja template with autoescaping on: condition names, items and answers come from
the study spec and from participants, and are shown as text. Plots are PNG files beside the page.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from jinja2 import Environment, select_autoescape

from coartic.perceive.analysis import Analysis

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{{ title }}: perceptual test</title>
<style>body{font-family:sans-serif;max-width:60rem;margin:1rem auto;padding:0 1rem}
table{border-collapse:collapse;margin:0.5rem 0}td,th{border:1px solid #bbb;padding:0.2rem 0.5rem;text-align:right}
th{background:#eee}.credible{font-weight:bold}.note{color:#a40}</style></head><body>
<h1>{{ title }}</h1>
<p>Study <code>{{ name }}</code>, design <strong>{{ design }}</strong>: {{ n_participants }} participants analysed
({{ n_simulated }} simulated), {{ n_answers }} answers to stimuli{% if excluded %}; {{ excluded|length }} participants
excluded{% endif %}. Written by <code>{{ command }}</code>.</p>
{% for note in notes %}<p class="note">{{ note }}</p>{% endfor %}
{% if excluded %}<h2>Exclusions</h2><table><tr><th>participant</th><th>why</th></tr>
{% for p, why in excluded.items() %}<tr><td>{{ p }}</td><td style="text-align:left">{{ why }}</td></tr>{% endfor %}</table>{% endif %}
<h2>Model</h2><p>{{ model }}</p>
<table><tr><th>effect</th><th>estimate</th><th>sd / se</th><th>95 % interval</th>{% if logit %}<th>odds ratio</th>{% endif %}</tr>
{% for e in effects %}<tr class="{{ 'credible' if e.credible else '' }}"><td style="text-align:left">{{ e.name }}</td>
<td>{{ '%.3f'|format(e.estimate) }}</td><td>{{ '%.3f'|format(e.se) }}</td><td>[{{ '%.3f'|format(e.low) }}, {{ '%.3f'|format(e.high) }}]</td>
{% if logit %}<td>{{ '%.2f'|format(e.odds) }}</td>{% endif %}</tr>{% endfor %}</table>
<p>Bold: the 95 % interval excludes 0. Random effects:
{% for k, v in variance.items() %}{{ k }} {{ '%.3f'|format(v) }}{{ '; ' if not loop.last else '.' }}{% endfor %}</p>
{% for plot in plots %}<figure><img src="{{ plot.file }}" alt="{{ plot.caption }}"><figcaption>{{ plot.caption }}</figcaption></figure>{% endfor %}
<h2>{{ cells_title }}</h2>{{ cells_html }}
{% for name, table in confusions %}<h3>Confusions: {{ name }}</h3><p>Rows: the right answer; columns: the answer given.</p>{{ table }}{% endfor %}
<p>The answers, one row each: <a href="answers.csv">answers.csv</a>; the numbers: <a href="summary.json">summary.json</a>.</p>
</body></html>
"""


def _figure(width: float, height: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: Path) -> str:
    from coartic.outputs import atomic_path

    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path.name


def plot_cells(result: Analysis, out: Path) -> dict[str, str]:
    """The cell means with their bootstrap intervals."""
    cells = result.cells
    fig = _figure(6.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    if result.design in ("intelligibility", "emotion") and "snr_db" in cells and cells["snr_db"].notna().any() \
            and cells["snr_db"].nunique() > 1:
        for cond, rows in cells.groupby("condition", sort=False):
            ax.errorbar(rows["snr_db"], rows["mean"], yerr=[rows["mean"] - rows["low"], rows["high"] - rows["mean"]],
                        marker="o", capsize=3, label=str(cond))
        ax.set_xlabel("SNR (dB)")
        ax.legend(fontsize=8)
    else:
        key = "pair" if result.design == "preference" else "condition"
        x = np.arange(len(cells))
        ax.bar(x, cells["mean"], color="#8ab")
        ax.errorbar(x, cells["mean"], yerr=[cells["mean"] - cells["low"], cells["high"] - cells["mean"]], fmt="none",
                    ecolor="k", capsize=3)
        ax.set_xticks(x, [str(v) for v in cells[key]], rotation=20, fontsize=8)
    ylabel = {"intelligibility": "proportion right", "emotion": "proportion right",
              "preference": "share choosing the first-named", "mushra": "mean rating"}[result.design]
    ax.set_ylabel(ylabel)
    if result.design != "mushra":
        ax.set_ylim(0, 1)
    return {"file": _save(fig, out / "cells.png"), "caption": f"{ylabel} with 95 % intervals (participants resampled)"}


def plot_effects(result: Analysis, out: Path) -> dict[str, str]:
    effects = [e for e in result.effects if e.name != "intercept"]
    fig = _figure(6.0, 0.5 + 0.35 * max(1, len(effects)))
    ax = fig.add_subplot(1, 1, 1)
    y = np.arange(len(effects))
    ax.errorbar([e.estimate for e in effects], y, xerr=[[e.estimate - e.low for e in effects],
                                                         [e.high - e.estimate for e in effects]], fmt="o", capsize=3)
    ax.axvline(0.0, color="0.5", lw=1)
    ax.set_yticks(y, [e.name for e in effects], fontsize=8)
    ax.set_xlabel("effect (logit)" if result.design != "mushra" else "effect (rating points)")
    return {"file": _save(fig, out / "effects.png"), "caption": "fixed effects with 95 % intervals"}


def plot_confusion(name: str, table: pd.DataFrame, path: Path) -> dict[str, str]:
    fig = _figure(1.2 + 0.45 * len(table.columns), 1.0 + 0.4 * len(table.index))
    ax = fig.add_subplot(1, 1, 1)
    counts = table.to_numpy(dtype=float)
    rows = counts.sum(axis=1, keepdims=True)
    share = np.divide(counts, rows, out=np.zeros_like(counts), where=rows > 0)
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    for (i, j), v in np.ndenumerate(counts):
        ax.text(j, i, f"{int(v)}", ha="center", va="center", fontsize=7, color="k" if share[i, j] < 0.6 else "w")
    ax.set_xticks(range(len(table.columns)), [str(c) for c in table.columns], fontsize=8)
    ax.set_yticks(range(len(table.index)), [str(c) for c in table.index], fontsize=8)
    ax.set_xlabel("answer given")
    ax.set_ylabel("right answer")
    ax.set_title(name, fontsize=9)
    return {"file": _save(fig, path), "caption": f"confusions, {name} (shade: share of the row)"}


def write_report(result: Analysis, manifest: dict[str, Any], tidy: pd.DataFrame, out: Path, command: str) -> Path:
    """out/report.html, out/answers.csv, out/summary.json and the plots."""
    from coartic.outputs import atomic_write_text
    from coartic.perceive.tidy import write_csv

    write_csv(tidy, out / "answers.csv")
    atomic_write_text(out / "summary.json", json.dumps(result.summary(), indent=1, default=_json_default) + "\n")
    plots = [plot_cells(result, out), plot_effects(result, out)]
    for k, (name, table) in enumerate(result.confusions.items()):
        plots.append(plot_confusion(name, table, out / f"confusion_{k + 1}.png"))
    logit = result.design != "mushra"
    env = Environment(autoescape=select_autoescape(default=True, default_for_string=True))
    effects = [{"name": e.name, "estimate": e.estimate, "se": e.se, "low": e.low, "high": e.high,
                "credible": e.credible and e.name != "intercept", "odds": float(np.exp(e.estimate))} for e in result.effects]
    html = env.from_string(PAGE).render(
        title=manifest["title"], name=manifest["name"], design=result.design, n_participants=result.n_participants,
        n_simulated=result.n_simulated, n_answers=result.n_answers, excluded=result.excluded, notes=result.notes,
        model=result.model, effects=effects, logit=logit, variance=result.variance, plots=plots, command=command,
        cells_title="Cells" if result.design != "preference" else "Pairs",
        cells_html=_table_html(result.cells), confusions=[(n, _table_html(t, index=True)) for n, t in result.confusions.items()])
    page = out / "report.html"
    atomic_write_text(page, html)
    return page


def _table_html(frame: pd.DataFrame, index: bool = False) -> Any:
    from markupsafe import Markup

    # pandas escapes the cells (escape=True is its default); Markup keeps Jinja from escaping the tags again
    return Markup(frame.to_html(index=index, float_format=lambda v: f"{v:.3f}", border=0, escape=True))


def _json_default(v: Any) -> Any:
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return None if not np.isfinite(v) else float(v)
    return str(v)
