"""What each of `coartic speak`'s default pictures costs in CPU, against the speech's duration.

In-process, after one warm-up (fonts loaded): channels.png, strip.png and preview.gif of the 2-s
sentence of bench/startup.py, each the median CPU time (user + system, time.process_time) of
--rounds runs; and, in fresh interpreters, the import of coartic.runtime.preview (Pillow and
coartic.runtime.raster; matplotlib before they drew with Pillow alone) beyond what `speak --preview
none` imports. bench/startup.py measures the whole command.

Run: .venv/bin/python bench/speak_pictures.py [--rounds 5] [--out bench/results/speak_pictures.txt]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "python"))

from coartic.runtime import pipeline  # noqa: E402
from coartic.table import ParameterTable  # noqa: E402

SENTENCE = "Il babbo mangia la pappa."
_IMPORT = ("import time, coartic.runtime.pipeline; t = time.process_time(); import coartic.runtime.preview; "
           "print(time.process_time() - t)")


def cpu(fn: Callable[[], object], rounds: int) -> float:
    fn()  # warm-up: fonts, caches
    times = []
    for _ in range(rounds):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=str(ROOT / "corpus-synthetic" / "ground_truth.json"))
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "speak_pictures.txt"))
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "python")}
    imports = [float(subprocess.run([sys.executable, "-c", _IMPORT], env=env, capture_output=True, text=True,
                                    check=True).stdout) for _ in range(args.rounds)]
    table = ParameterTable.load(args.table)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        res = pipeline.speak_text(SENTENCE, table, out / "speak", preview="none")
        from coartic.runtime.preview import plot_channels, render_preview, render_strip

        a = res.animation
        rows = [("import coartic.runtime.preview (Pillow)", statistics.median(imports)),
                ("channels.png", cpu(lambda: plot_channels(a, out / "channels.png", title="x"), args.rounds)),
                ("strip.png", cpu(lambda: render_strip(a, table, out / "strip.png"), args.rounds)),
                (f"preview.gif ({a.n_frames} frames)",
                 cpu(lambda: render_preview(a, a.neutral, out / "preview.gif", title="x"), args.rounds))]
    speech = a.duration
    lines = [f"speak's default pictures, CPU s (median of {args.rounds}); sentence {SENTENCE!r}, "
             f"{speech:.3f} s animated; load average {os.getloadavg()[0]:.1f}", "",
             f"{'what':52s} {'CPU s':>7s} {'/speech':>8s}"]
    lines += [f"{name:52s} {t:7.3f} {t / speech:8.3f}" for name, t in rows]
    total = sum(t for _, t in rows)
    lines.append(f"{'all pictures, import included':52s} {total:7.3f} {total / speech:8.3f}")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
