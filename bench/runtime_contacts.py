"""Do the FAP frames show the k_R = 1 contacts, and what does the runtime cost? (issue 6)

For one Italian sentence rich in /p b m f v/ said by Festival at the normal and a fast rate, prints
the worst distance between the frame nearest each target time and the value the table promises
there (T (1 + sigma), MODEL.md §3 item 3): lip aperture ULO + LLO against the closure on /p b m/,
LLO against the lip-teeth contact on /f v/, with uniform frames and with contact snapping; then the
time of `speak` without preview and of the preview per frame, as ratios to the speech's duration.

Run: .venv/bin/python bench/runtime_contacts.py [--out bench/results/runtime_contacts.txt]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from coartic.runtime.animate import Animation, neutral_posture, target_times
from coartic.runtime.pipeline import speak_text
from coartic.runtime.preview import render_preview
from coartic.table import ParameterTable

ROOT = Path(__file__).resolve().parents[1]
SENTENCE = "Il babbo mangia la pappa, poi va via."


def reached(table: ParameterTable, ph: str, ch: str) -> float:
    row = table.values[ph][ch]
    return row["target"] * (1.0 + row["sigma"])


def worst_gaps(table: ParameterTable, a: Animation) -> tuple[float, float]:
    seg = a.segments
    k = np.minimum(np.rint(target_times(table, seg, "ULO") * a.fps).astype(int), a.n_frames - 1)
    la = a.channels["ULO"] + a.channels["LLO"]
    bil = [abs(la[k[i]] - reached(table, p, "ULO") - reached(table, p, "LLO"))
           for i, p in enumerate(seg.labels) if p in ("p", "b", "m")]
    lab = [abs(a.channels["LLO"][k[i]] - reached(table, p, "LLO")) for i, p in enumerate(seg.labels) if p in ("f", "v")]
    return max(bil), max(lab)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=str(ROOT / "corpus-synthetic" / "ground_truth.json"))
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "runtime_contacts.txt"))
    args = ap.parse_args()
    table = ParameterTable.load(args.table)
    lines = [f"sentence: {SENTENCE!r}, table: {Path(args.table).name}, Festival voice pc_diphone", "",
             "stretch  fps  snapping  worst |LA - closure| /p b m/  worst |LLO - contact| /f v/"]
    with tempfile.TemporaryDirectory() as tmp:
        for stretch in (1.0, 0.6):
            for fps in (25.0, 50.0):
                for snap in (False, True):
                    a = speak_text(SENTENCE, table, Path(tmp) / "o", fps=fps, stretch=stretch, preview="none",
                                   snap_contacts=snap).animation
                    b, f = worst_gaps(table, a)
                    lines.append(f"{stretch:7.1f}  {fps:3.0f}  {'on ' if snap else 'off'}       "
                                 f"{b:10.3f} mm                  {f:10.3f} mm")
        t0 = time.perf_counter()
        res = speak_text(SENTENCE, table, Path(tmp) / "t", preview="none")
        t_speak = time.perf_counter() - t0
        t0 = time.perf_counter()
        render_preview(res.animation, neutral_posture(table), Path(tmp) / "p.gif")
        t_gif = time.perf_counter() - t0
    dur = res.animation.duration
    lines += ["",
              f"speak (Festival + channels + FAP + plot, no preview): {t_speak:.2f} s for {dur:.2f} s of speech "
              f"= {t_speak / dur:.2f} x real time",
              f"GIF preview: {t_gif:.2f} s for {res.animation.n_frames} frames = {1000 * t_gif / res.animation.n_frames:.0f} ms "
              f"per frame = {t_gif / dur:.2f} x real time at {res.animation.fps:g} fps"]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
