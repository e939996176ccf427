"""What a batch writes from its landed units: a table per group, the pooled table, one report.

Per group (``groups/<group>/``) and for the pooled fit (``pooled/``): ``table.json``, ``table.csv``,
``rmse.csv``, ``parameters.csv``, ``fit_report.txt`` and ``summary.json``, the files ``coartic fit``
writes, put together from the units' single-channel results in the spec's channel order (so the
table, RMSE and parameter files hold what one ``coartic fit`` of that group writes, bit for bit; the
table's metadata says when each channel was fitted). Across groups: ``rmse_groups.csv`` (RMSE per
group and channel), ``spread.csv`` (each parameter's spread across groups), figures, and
``report.html`` (everything from the data is escaped).
"""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jinja2
import numpy as np

from coartic.batch.layout import is_done, land_dir, unit_dir
from coartic.batch.outcome import BatchOutcome
from coartic.batch.spec import BatchSpec
from coartic.batch.tasks import UnitFailed, UnitKey
from coartic.fit.result import BAR_MM
from coartic.outputs import atomic_write_bytes
from coartic.table import PARAMETERS, ParameterTable

# The parameters whose spread across speakers the report plots (shape and timing offsets are
# mostly fixed or small; they are in spread.csv all the same).
PLOTTED = ("target", "alpha", "theta_bw", "theta_fw", "k_r", "delta")
LOG_PLOTTED = frozenset({"alpha", "theta_bw", "theta_fw"})
POOLED_NOTE = ("The pooled fit is one least-squares fit of every group's trials together: dynamics are shared "
               "by all groups, and each group's trajectories are the first group's scaled and offset "
               "(coartic.fit [model] speakers = \"offset_scale\"; the fitted offset and scale per group are in "
               "pooled/table.json metadata \"speakers\" and pooled/fit_report.txt). The pooled table's targets "
               "are the first group's; the per-group tables carry the full speaker variation.")


def merge_tables(tables: Sequence[ParameterTable], source: str) -> ParameterTable:
    """One table from single-channel tables, channels in the given order (as FitResult.table builds it)."""
    first = tables[0]
    t = ParameterTable(variant=first.variant, source=source)
    meta: dict[str, Any] = {k: v for k, v in first.metadata.items() if k != "mcmc"}
    for key in ("rmse", "status"):
        meta[key] = {}
    meta["interrupted"] = False
    dates = {}
    for tb in tables:
        for ch, cs in tb.channels.items():
            t.channels[ch] = cs
            if ch in tb.bounds:
                t.bounds[ch] = dict(tb.bounds[ch])
            phon = tb.phonemes_for(ch)
            mat, beta = tb.to_matrix(ch, phon)
            t.set_from_matrix(ch, phon, mat, beta)
            for ph, chans in tb.uncertainty.items():  # posterior quantiles (coartic.mcmc)
                if ch in chans:
                    t.uncertainty.setdefault(ph, {})[ch] = chans[ch]
            for key in ("rmse", "status"):
                if ch in tb.metadata.get(key, {}):
                    meta[key][ch] = tb.metadata[key][ch]
            dates[ch] = tb.metadata.get("date")
        meta["interrupted"] = meta["interrupted"] or bool(tb.metadata.get("interrupted"))
        if "mcmc" in tb.metadata:
            nc = meta.setdefault("mcmc", {"not_converged": []})["not_converged"]
            nc += tb.metadata["mcmc"].get("not_converged", [])
    meta["date"] = dates
    t.metadata = meta
    return t


def _concat_csv(texts: Sequence[str]) -> str:
    """CSV files with one header: the header once, then every file's rows (line ends kept as written)."""
    header = ""
    body: list[str] = []
    for text in texts:
        lines = text.splitlines(keepends=True)
        if not lines:
            continue
        if header and lines[0] != header:
            raise UnitFailed(f"CSV headers differ: {header!r} and {lines[0]!r}")
        header = lines[0]
        body += lines[1:]
    return header + "".join(body)


def _table_files(table: ParameterTable, stem: str) -> dict[str, bytes]:
    """The table as ParameterTable.save writes it, JSON and CSV."""
    text = json.dumps(table.to_json_dict(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    return {f"{stem}.json": text.encode(), f"{stem}.csv": table.to_csv().encode()}


def assemble(out: Path, dirs: Sequence[Path], target: Path, source: str,
             posterior_dirs: Sequence[Path] | None = None) -> None:
    """Write the group's (or pooled) files into ``target`` from its units' folders; with
    ``posterior_dirs`` (one per channel: the posterior unit's folder, or the fit's where the
    channel has no posteriors) also ``table_mcmc.json``/``.csv``, the table with the quantiles."""

    tables = [ParameterTable.load(d / "table.json") for d in dirs]
    table = merge_tables(tables, source)
    files = _table_files(table, "table")
    if posterior_dirs is not None:
        with_q = merge_tables([ParameterTable.load(d / "table.json") for d in posterior_dirs], source)
        files |= _table_files(with_q, "table_mcmc")
    for name in ("rmse.csv", "parameters.csv"):
        # bytes, not text mode: the CSV writer ends lines with \r\n, which text mode would rewrite
        files[name] = _concat_csv([(d / name).read_bytes().decode("utf-8") for d in dirs]).encode()
    files["fit_report.txt"] = "\n".join((d / "fit_report.txt").read_text(encoding="utf-8") for d in dirs).encode()
    summaries = [json.loads((d / "summary.json").read_text(encoding="utf-8")) for d in dirs]
    summary = dict(summaries[0])
    summary["channels"] = {ch: v for s in summaries for ch, v in s["channels"].items()}
    summary["interrupted"] = any(s.get("interrupted") for s in summaries)
    files["summary.json"] = (json.dumps(summary, indent=2) + "\n").encode()
    land_dir(target, files)


# ----------------------------------------------------------------------------- across groups


def _rmse_all(unit: Path) -> tuple[float, int]:
    """The unit's overall RMSE and sample count (its rmse.csv row group = all)."""
    with open(unit / "rmse.csv", newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            if r["group"] == "all":
                return float(r["rmse_mm"]), int(r["samples"])
    return math.nan, 0


def rmse_rows(spec: BatchSpec, out: Path) -> list[dict[str, Any]]:

    rows = []
    for name in [*spec.group_names, *([None] if spec.pooled else [])]:
        for ch in spec.channels:
            key = UnitKey(name, ch)
            if not is_done(out, key):
                continue
            rmse, n = _rmse_all(unit_dir(out, key))
            rows.append({"group": name if name is not None else "pooled", "channel": ch, "rmse_mm": rmse,
                         "samples": n, "below_bar": rmse < BAR_MM})
    return rows


def spread_rows(tables: dict[str, ParameterTable], pooled: ParameterTable | None,
                channels: Sequence[str]) -> list[dict[str, Any]]:
    """Per channel, phoneme and parameter: its value across the groups (count, mean, sd, min, max)."""
    rows = []
    for ch in channels:
        phonemes: dict[str, None] = {}
        for t in tables.values():
            if ch in t.channels:
                phonemes.update(dict.fromkeys(t.phonemes_for(ch)))
        for ph in phonemes:
            for p in PARAMETERS:
                v = np.array([t.values[ph][ch][p] for t in tables.values() if ch in t.values.get(ph, {})])
                pv = pooled.values.get(ph, {}).get(ch, {}).get(p) if pooled is not None else None
                rows.append({"channel": ch, "phoneme": ph, "parameter": p, "groups": int(v.size),
                             "mean": float(v.mean()), "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                             "min": float(v.min()), "max": float(v.max()),
                             "pooled": float(pv) if pv is not None else ""})
    return rows


def _csv_text(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return ""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()


def _figures(spec: BatchSpec, rmse: list[dict[str, Any]], tables: dict[str, ParameterTable],
             pooled: ParameterTable | None) -> dict[str, bytes]:
    """PNG figures: RMSE per group and channel, and each channel's parameter spread across groups."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs: dict[str, bytes] = {}

    def save(fig: Any, name: str) -> None:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=80)
        plt.close(fig)
        figs[name] = buf.getvalue()

    names = [r for r in [*spec.group_names, "pooled"] if any(x["group"] == r for x in rmse)]
    if names:
        grid = np.full((len(names), len(spec.channels)), np.nan)
        for r in rmse:
            grid[names.index(r["group"]), spec.channels.index(r["channel"])] = r["rmse_mm"]
        fig, ax = plt.subplots(figsize=(1.2 * len(spec.channels) + 2.5, 0.35 * len(names) + 1.8))
        im = ax.imshow(grid, aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(spec.channels)), spec.channels)
        ax.set_yticks(range(len(names)), names)
        if len(names) * len(spec.channels) <= 400:
            for i in range(len(names)):
                for j in range(len(spec.channels)):
                    if np.isfinite(grid[i, j]):
                        ax.text(j, i, f"{grid[i, j]:.3f}", ha="center", va="center", fontsize=7,
                                color="red" if grid[i, j] >= BAR_MM else "white")
        fig.colorbar(im, ax=ax, label="RMSE (mm)")
        ax.set_title(f"RMSE per group and channel (red: at or above the {BAR_MM} mm bar)")
        fig.tight_layout()
        save(fig, "rmse.png")
    for ch in spec.channels:
        have = {g: t for g, t in tables.items() if ch in t.channels}
        if not have:
            continue
        phonemes: dict[str, None] = {}
        for t in have.values():
            phonemes.update(dict.fromkeys(t.phonemes_for(ch)))
        ph = list(phonemes)
        fig, axes = plt.subplots(len(PLOTTED), 1, figsize=(max(6.0, 0.32 * len(ph) + 2), 2.0 * len(PLOTTED)),
                                 sharex=True)
        x = np.arange(len(ph))
        for ax, p in zip(axes, PLOTTED):
            for gi, (g, t) in enumerate(have.items()):
                vals = [t.values[q][ch][p] if ch in t.values.get(q, {}) else np.nan for q in ph]
                jitter = (gi - (len(have) - 1) / 2) * min(0.5 / max(len(have), 1), 0.08)
                ax.plot(x + jitter, vals, ".", ms=4, alpha=0.7, color="C0", label="groups" if gi == 0 else None)
            if pooled is not None and ch in pooled.channels:
                pv = [pooled.values[q][ch][p] if ch in pooled.values.get(q, {}) else np.nan for q in ph]
                ax.plot(x, pv, "x", color="C3", ms=6, label="pooled")
            if p in LOG_PLOTTED:
                ax.set_yscale("log")
            ax.set_ylabel(p)
            ax.grid(axis="y", lw=0.3)
        axes[0].legend(loc="upper right", fontsize=7)
        axes[0].set_title(f"{ch}: each phoneme's parameters across {len(have)} group(s)")
        axes[-1].set_xticks(x, ph)
        fig.tight_layout()
        save(fig, f"spread_{ch}.png")
    return figs


_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>coartic batch: {{ name }}</title>
<style>body{font-family:sans-serif;max-width:70em;margin:1em auto;padding:0 1em}
table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}
th:first-child,td:first-child{text-align:left}.bad{color:#b00}.note{background:#ffe;padding:.5em}
img{max-width:100%}</style></head><body>
<h1>coartic batch: {{ name }}</h1>
<p>Spec <code>{{ spec }}</code>, fit spec <code>{{ fit_spec }}</code>; {{ n_groups }} group(s), channels
{{ channels|join(", ") }}; {{ done }} of {{ total }} units finished.</p>
{% if failed %}<div class="note"><b>Units that failed</b> (rerun to retry):<ul>
{% for k, v in failed.items() %}<li>{{ k }}: {{ v }}</li>{% endfor %}</ul></div>{% endif %}
{% if missing %}<div class="note">Not finished: {{ missing|join(", ") }}.</div>{% endif %}
<h2>RMSE per group and channel (mm)</h2>
<table><tr><th>group</th>{% for ch in channels %}<th>{{ ch }}</th>{% endfor %}</tr>
{% for g in grid %}<tr><td>{% if g.link %}<a href="{{ g.link }}">{{ g.name }}</a>{% else %}{{ g.name }}{% endif %}</td>
{% for v in g.cells %}<td{% if v is not none and v >= bar %} class="bad"{% endif %}>{{ "%.3f"|format(v) if v is not none else "–" }}</td>{% endfor %}</tr>
{% endfor %}</table>
<p>The paper's bar is {{ bar }} mm. Per-group tables: <code>groups/&lt;group&gt;/table.json</code>; pooled: <code>pooled/table.json</code>.</p>
{% if pooled %}<p class="note">{{ pooled_note }}</p>{% endif %}
{% if posteriors %}<h2>Posteriors (coartic.mcmc) per group and channel</h2>
<table><tr><th>group</th>{% for ch in posterior_channels %}<th>{{ ch }}</th>{% endfor %}</tr>
{% for row in posteriors %}<tr><td>{{ row.name }}</td>{% for c in row.cells %}<td>{{ c }}</td>{% endfor %}</tr>{% endfor %}
</table><p>Chains, summaries and plots: <code>posteriors/&lt;group&gt;/&lt;channel&gt;/</code>; each group's table with
the posterior quantiles: <code>groups/&lt;group&gt;/table_mcmc.json</code>.</p>{% endif %}
{% for f in figures %}<figure><img src="{{ f.src }}" alt="{{ f.src }}"><figcaption>{{ f.caption }}</figcaption></figure>{% endfor %}
<h2>Largest spread across groups</h2>
<table><tr><th>channel</th><th>phoneme</th><th>parameter</th><th>groups</th><th>mean</th><th>sd</th><th>min</th><th>max</th><th>pooled</th></tr>
{% for r in spread %}<tr><td>{{ r.channel }}</td><td>{{ r.phoneme }}</td><td>{{ r.parameter }}</td><td>{{ r.groups }}</td>
<td>{{ "%.4g"|format(r.mean) }}</td><td>{{ "%.4g"|format(r.sd) }}</td><td>{{ "%.4g"|format(r.min) }}</td>
<td>{{ "%.4g"|format(r.max) }}</td><td>{{ "%.4g"|format(r.pooled) if r.pooled != "" else "" }}</td></tr>{% endfor %}
</table><p>Every parameter: <code>spread.csv</code>.</p>
</body></html>
"""


def write_outputs(spec: BatchSpec, out: Path, outcome: BatchOutcome, report: bool = True) -> None:
    """The per-group and pooled tables of every complete group, the summary files and (``report``)
    the figures and report.html."""

    tables: dict[str, ParameterTable] = {}
    missing: list[str] = []
    for g in spec.groups:
        keys = [UnitKey(g.name, ch) for ch in spec.channels]
        post = [UnitKey(g.name, ch, "posterior") for ch in spec.posterior_channels]
        missing += [k.label for k in keys + post if not is_done(out, k)]
        if all(is_done(out, k) for k in keys):
            post_dirs = None
            if post and all(is_done(out, k) for k in post):
                post_dirs = [unit_dir(out, UnitKey(g.name, ch, "posterior" if ch in spec.posterior_channels else "fit"))
                             for ch in spec.channels]
            assemble(out, [unit_dir(out, k) for k in keys], out / "groups" / g.name, f"batch {spec.path}: {g.name}",
                     post_dirs)
            tables[g.name] = ParameterTable.load(out / "groups" / g.name / "table.json")
    pooled: ParameterTable | None = None
    if spec.pooled:
        keys = [UnitKey(None, ch) for ch in spec.channels]
        if all(is_done(out, k) for k in keys):
            assemble(out, [unit_dir(out, k) for k in keys], out / "pooled", f"batch {spec.path}: pooled")
            pooled = ParameterTable.load(out / "pooled" / "table.json")
        else:
            missing += [k.label for k in keys if not is_done(out, k)]
    rmse = rmse_rows(spec, out)
    spread = spread_rows(tables, pooled, spec.channels) if tables else []
    atomic_write_bytes(out / "rmse_groups.csv", _csv_text(rmse).encode())
    atomic_write_bytes(out / "spread.csv", _csv_text(spread).encode())
    if not report:  # an earlier run's page would no longer match the tables
        (out / "report.html").unlink(missing_ok=True)
        shutil.rmtree(out / "figures", ignore_errors=True)
    if report:  # the figures and the page (the tables and CSVs above are written either way)
        figs = _figures(spec, rmse, tables, pooled)
        land_dir(out / "figures", figs)
        by = {(r["group"], r["channel"]): r["rmse_mm"] for r in rmse}
        grid = [{"name": n, "link": (f"groups/{n}/table.json" if n in tables else
                                     "pooled/table.json" if n == "pooled" and pooled is not None else ""),
                 "cells": [by.get((n, ch)) for ch in spec.channels]}
                for n in [*spec.group_names, *(["pooled"] if spec.pooled else [])]]
        # The spread table shows the largest relative spreads (sd over |mean|, targets over their range).
        ranked = sorted((r for r in spread if r["groups"] > 1 and r["sd"] > 0),
                        key=lambda r: -r["sd"] / max(abs(r["mean"]), 1e-9))[:25]
        captions = {"rmse.png": "RMSE of every group's fit (and the pooled fit) per channel."}
        captions |= {f"spread_{ch}.png": f"{ch}: every phoneme's parameters in each group's fit (dots) and in the "
                     "pooled fit (crosses)." for ch in spec.channels}
        posteriors = []
        for g in spec.groups if spec.posterior_channels else ():
            cells = []
            for ch in spec.posterior_channels:
                key = UnitKey(g.name, ch, "posterior")
                cells.append(json.loads((unit_dir(out, key) / "unit.json").read_text(encoding="utf-8"))["status"]
                             if is_done(out, key) else "–")
            posteriors.append({"name": g.name, "cells": cells})
        env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
        html = env.from_string(_TEMPLATE).render(
            name=spec.name, spec=str(spec.path), fit_spec=str(spec.fit.path), n_groups=len(spec.groups),
            channels=list(spec.channels), done=outcome.total - len(missing), total=outcome.total,
            failed=outcome.failed, missing=missing, grid=grid, bar=BAR_MM, pooled=spec.pooled, pooled_note=POOLED_NOTE,
            figures=[{"src": f"figures/{n}", "caption": captions.get(n, n)} for n in figs], spread=ranked,
            posteriors=posteriors, posterior_channels=list(spec.posterior_channels))
        atomic_write_bytes(out / "report.html", html.encode())
    status = {"spec": str(spec.path), "units": outcome.total, "finished": outcome.total - len(missing),
              "skipped_as_done": outcome.skipped, "landed_now": [k.label for k in outcome.landed],
              "failed": outcome.failed, "interrupted": outcome.interrupted, "missing": missing,
              "workers": outcome.workers, "rayon_threads_per_worker": outcome.threads}
    atomic_write_bytes(out / "status.json", (json.dumps(status, indent=2) + "\n").encode())
