"""Read a generated session back through coartic's readers and compare it with its truth.

    python corpus-synthetic/check_session.py SESSION [--every 1]

Prints, per channel, the RMS and mean of (channel read back from the C3D − generated channel) over
the frames without occlusions, the occlusions per marker, and how far y_0 taken over the whole first
pause and over the reader's rest frames lies from the rest line. Use it after changing
session.toml (noise, geometry, head motion) to see what the fitting tools will get.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.progress import track
from rich.table import Table

from coartic.io import load_trial
from coartic.table import CHANNELS


def main(
    session: Annotated[Path, typer.Argument(help="A session written by `coartic corpus synth`.")],
    every: Annotated[int, typer.Option(min=1, help="Check every n-th trial of the manifest.")] = 1,
) -> None:
    with open(session / "manifest.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))[::every]
    res: dict[str, list[np.ndarray]] = {ch: [] for ch in CHANNELS}
    occlusions: dict[str, int] = {}
    y0_whole, y0_reader = [], []
    trials_with_gaps = 0
    for r in track(rows, description="reading back", transient=True):
        with np.load(session / r["truth"]) as z:
            t = {k: z[k] for k in z.files}
        trial = load_trial(session / r["file"], labels=session / r["labels"])
        got = trial.channels()
        mask = t["dropout_mask"]
        trials_with_gaps += bool(mask.any())
        for m, name in enumerate(t["marker_names"]):
            occlusions[str(name)] = occlusions.get(str(name), 0) + int(np.sum(np.diff(mask[:, m].astype(int)) == 1) + mask[0, m])
        rest = trial.rest_frames()
        whole = (t["times"] >= t["starts"][0]) & (t["times"] <= t["ends"][0])
        y0_whole.append(float(np.mean(t["ULO"][whole] - t["LLO"][whole]) / 2.0))
        y0_reader.append(float(np.mean(t["ULO"][rest] - t["LLO"][rest]) / 2.0))
        ok = ~mask.any(axis=1)
        for ch in CHANNELS:
            res[ch].append((got[ch] - t[ch])[ok])
    console = Console(width=110)
    out = Table(title=f"{session}: {len(rows)} trials read back through coartic.io.load_trial")
    for col in ("channel", "RMS (mm)", "mean (mm)", "max |diff| (mm)"):
        out.add_column(col, justify="right")
    for ch in CHANNELS:
        d = np.concatenate(res[ch])
        out.add_row(ch, f"{np.sqrt(np.mean(d**2)):.3f}", f"{np.mean(d):+.4f}", f"{np.max(np.abs(d)):.3f}")
    console.print(out)
    console.print(f"occlusions per marker: {occlusions}; trials with any: {trials_with_gaps} of {len(rows)}")
    console.print(
        f"y_0 offset from the rest line, |mean of (ULO-LLO)/2|: whole first pause mean "
        f"{np.mean(np.abs(y0_whole)):.3f} max {np.max(np.abs(y0_whole)):.3f} mm; the reader's rest frames "
        f"mean {np.mean(np.abs(y0_reader)):.3f} max {np.max(np.abs(y0_reader)):.3f} mm "
        f"(ULO reads -offset, LLO +offset)"
    )


if __name__ == "__main__":
    typer.run(main)
