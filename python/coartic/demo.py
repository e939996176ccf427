"""`coartic demo --out DIR`: the model at work on /a p a/, /a f a/, /a t a/ at two speaking rates.

The point of the Cosi–Perin modification, shown in one picture: with a resistant consonant
(k_R = 1: the bilabial closure of /p/, the labiodental contact of /f/) the modified model reaches
the consonant's target at any rate, while the original Cohen–Massaro model undershoots it when
speech is three times faster. /t/ (k_R < 1) is allowed to undershoot in both.

The parameter values are ILLUSTRATIVE (chosen by hand to look like lower-lip opening in Italian
VCVs), not fitted to any recording.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import numpy.typing as npt
import typer
from rich.console import Console
from rich.table import Table

from coartic.model import segment_weights, trajectories
from coartic.outputs import OutputDir
from coartic.table import PARAMETERS, ParameterTable

CHANNEL = "LLO"
CONSONANTS = ("p", "f", "t")
RATES = {"normal": 1.0, "3x faster": 3.0}
VARIANT_STYLE = {"modified": "-", "original": "--"}
FPS = 1000.0
# Normal-rate durations (s) of # V C V #; the pauses keep their length at the fast rate.
PAUSE_S = 0.15
VCV_S = (0.14, 0.10, 0.16)


def illustrative_table(variant: str = "modified") -> ParameterTable:
    """A small hand-made LLO table for #, a, p, f, t (clearly not fitted: see ``reasons``)."""

    def row(target: float, alpha: float, theta: float, k_r: float, sigma: float = 0.0) -> dict[str, float]:
        values = (target, alpha, theta, theta, 1.0, 1.0, k_r, sigma, 200.0, 0.0)
        return dict(zip(PARAMETERS, values))

    rows = {
        "#": {CHANNEL: row(0.0, 0.5, 20.0, 0.0)},
        "a": {CHANNEL: row(12.0, 1.0, 30.0, 0.2, sigma=0.05)},
        "p": {CHANNEL: row(-2.0, 1.5, 60.0, 1.0)},
        "f": {CHANNEL: row(-4.0, 1.3, 60.0, 1.0)},
        "t": {CHANNEL: row(5.0, 0.6, 50.0, 0.3)},
    }
    why = "illustrative value chosen by hand for the demo, not fitted"
    reasons = {ph: {CHANNEL: {"target": why}} for ph in rows}
    table = ParameterTable.from_rows(rows, {CHANNEL: "a"}, variant=variant, reasons=reasons)
    table.metadata = {"method": "illustrative (hand-chosen)", "software": "coartic demo"}
    return table


def vcv_segments(consonant: str, rate: float) -> tuple[list[str], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Labels, starts, ends of # a C a # at a speaking rate (1 = normal)."""
    durations = [PAUSE_S] + [d / rate for d in VCV_S] + [PAUSE_S]
    edges = np.concatenate([[0.0], np.cumsum(durations)])
    return ["#", "a", consonant, "a", "#"], edges[:-1], edges[1:]


def run_demo(out: Path) -> dict[str, dict[str, dict[str, float]]]:
    """Write demo.png, table.json and reached.json to ``out`` (an existing directory; the command
    stages it, see ``demo_command``); return the consonant values reached.

    ``reached[stimulus][rate][variant]`` is F at the consonant's target time; the target is
    ``reached[stimulus]["target"]``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tables = {v: illustrative_table(v) for v in VARIANT_STYLE}
    tables["modified"].save(out / "table.json")
    fig, axes = plt.subplots(
        2 * len(CONSONANTS), len(RATES), figsize=(11, 12), sharex="col",
        gridspec_kw={"height_ratios": [3, 1.4] * len(CONSONANTS)},
    )
    reached: dict[str, dict[str, dict[str, float]]] = {}
    colours = {"#": "0.6", "a": "tab:blue", "p": "tab:red", "f": "tab:orange", "t": "tab:green"}
    for r, cons in enumerate(CONSONANTS):
        stim = f"a{cons}a"
        target = tables["modified"].values[cons][CHANNEL]["target"]
        reached[stim] = {"target": {"value": target}}
        for c, (rate_name, rate) in enumerate(RATES.items()):
            labels, starts, ends = vcv_segments(cons, rate)
            times = np.arange(0.0, ends[-1], 1.0 / FPS)
            t_cons = 0.5 * (starts[2] + ends[2])
            top, bottom = axes[2 * r, c], axes[2 * r + 1, c]
            reached[stim][rate_name] = {}
            for variant, style in VARIANT_STYLE.items():
                table = tables[variant]
                f = trajectories(table, labels, starts, ends, times, channels=[CHANNEL])[CHANNEL]
                at = trajectories(table, labels, starts, ends, [t_cons], channels=[CHANNEL])[CHANNEL][0]
                reached[stim][rate_name][variant] = float(at)
                top.plot(times, f, style, color="k", lw=1.6, label=f"{variant} model")
                w = segment_weights(table, CHANNEL, labels, starts, ends, times)
                for i, lab in enumerate(labels):
                    bottom.plot(times, w[i], style, color=colours[lab], lw=1.2)
            for i, lab in enumerate(labels):
                top.axvspan(starts[i], ends[i], color=colours[lab], alpha=0.08, lw=0)
                top.text(0.5 * (starts[i] + ends[i]), 13.5, f"/{lab}/", ha="center", fontsize=9)
                t_i = 0.5 * (starts[i] + ends[i])
                top.plot([t_i], [tables["modified"].values[lab][CHANNEL]["target"]], "o", color=colours[lab], ms=5)
            top.axhline(target, color=colours[cons], lw=0.6, ls=":")
            top.set_ylim(-6, 15)
            top.set_title(f"/# a {cons} a #/, {rate_name} rate", fontsize=10)
            top.set_ylabel("LLO (mm)")
            bottom.set_ylim(-0.02, 1.05)
            bottom.set_ylabel("weight")
            if r == 0 and c == 0:
                top.legend(loc="lower left", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(
        "Lower-lip opening: modified (Cosi–Perin, solid) vs original (Cohen–Massaro, dashed) model\n"
        "dots: targets at their target times; lower panels: normalised dominance (weight of each "
        "segment's target in F)\nILLUSTRATIVE parameter values, not fitted to data",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / "demo.png", dpi=110)
    plt.close(fig)
    (out / "reached.json").write_text(json.dumps(reached, indent=2) + "\n", encoding="utf-8")
    return reached


def demo_command(
    out: Annotated[Path, typer.Option(help="Directory for demo.png, table.json and reached.json.")] = Path(
        "results/demo"
    ),
    force: Annotated[bool, typer.Option("--force", help="Replace --out even if it holds another run's output.")] = False,
) -> None:
    """Plot the model on /a p a/, /a f a/, /a t a/ at a normal and a 3x faster rate (illustrative table)."""
    console = Console()
    with OutputDir(out, "demo", {}, force=force) as staging:
        reached = run_demo(staging)
    summary = Table(title=f"{CHANNEL} at the consonant's target time (illustrative parameters)")
    summary.add_column("stimulus")
    summary.add_column("target", justify="right")
    for rate in RATES:
        for variant in VARIANT_STYLE:
            summary.add_column(f"{rate}, {variant}", justify="right")
    for stim, per in reached.items():
        cells = [f"{per[rate][v]:.2f}" for rate in RATES for v in VARIANT_STYLE]
        summary.add_row(stim, f"{per['target']['value']:.2f}", *cells)
    console.print(summary)
    console.print(f"written: {out / 'demo.png'}, {out / 'table.json'}, {out / 'reached.json'}")
