"""Where the time of `coartic speak` goes, phase by phase, start-up included (issue 20, item 6).

Each round runs `coartic speak` of the 2-s sentence of bench/startup.py in a fresh interpreter,
with timers put around the functions that bound its phases (nothing else changed), and reports the
median wall and CPU time of each phase over the rounds, against the speech's duration:
Python's own start-up and exit (the interpreter, site, the finalisation), the command line (coartic.cli, typer and its
option parsing) until Festival is started, what runs while Festival synthesises (NumPy, the model,
the table, the output directory), the wait for Festival, the animation, each exporter (its import
included), and the rest (the swap of the output directory, the summary). Festival's own CPU time
is that of the child processes.

Run: .venv/bin/python bench/speak_phases.py [--rounds 5] [--preview gif|none] [--out bench/results/speak_phases.txt]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import wave
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SENTENCE = "Il babbo mangia la pappa."

# Runs in the measured interpreter: wraps the phase boundaries, runs the CLI, prints the marks.
_PROBE = r"""
import json, resource, sys, time
marks = [("start", time.perf_counter(), time.process_time())]
def mark(name):
    marks.append((name, time.perf_counter(), time.process_time()))
import coartic.runtime.festival as festival, coartic.runtime.exporters as exporters
start, result, load = festival.start_synthesis, festival.Synthesis.result, exporters.load_exporter
def start_synthesis(*a, **k):
    mark("command line (coartic.cli, typer)")
    return start(*a, **k)
def wait(self, *a, **k):
    mark("imports, table, output dir (Festival running)")
    out = result(self, *a, **k)
    mark("waiting for Festival")
    return out
def load_exporter(name):
    fn = load(name)
    def timed(*a, **k):
        out = fn(*a, **k)
        mark(f"exporter {name} (its import included)")
        return out
    return timed
run_exports = exporters.run_exports
def run_exports_timed(*a, **k):
    mark("animation")
    return run_exports(*a, **k)
festival.start_synthesis, festival.Synthesis.result = start_synthesis, wait
exporters.load_exporter, exporters.run_exports = load_exporter, run_exports_timed
from coartic.cli import main
sys.argv[0] = "coartic"
try:
    main()  # the program as its console script runs it
except SystemExit:
    pass
finally:
    mark("output dir swapped in, summary")
    child = resource.getrusage(resource.RUSAGE_CHILDREN)
    print("MARKS " + json.dumps({"marks": marks, "festival_cpu": child.ru_utime + child.ru_stime}))
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--preview", default="gif")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "speak_phases.txt"))
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "python"), "COLUMNS": "100"}
    load0 = os.getloadavg()[0]
    phases: dict[str, list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", _PROBE, "speak", SENTENCE, "--out", f"{tmp}/o", "--preview", args.preview,
               "--force"]
        for _ in range(args.rounds):
            t0, c0 = time.perf_counter(), os.times()
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
            wall, c1 = time.perf_counter() - t0, os.times()
            if proc.returncode != 0:
                raise SystemExit(proc.stderr)
            got = json.loads(next(ln for ln in proc.stdout.splitlines() if ln.startswith("MARKS "))[6:])
            marks = got["marks"]
            cpu_all = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
            inside_wall, inside_cpu = marks[-1][1] - marks[0][1], marks[-1][2] - marks[0][2]
            rows = [("Python start-up and exit (interpreter, site, finalisation)", wall - inside_wall,
                     cpu_all - inside_cpu - got["festival_cpu"])]
            rows += [(name, t - marks[i][1], c - marks[i][2]) for i, (name, t, c) in enumerate(marks[1:])]
            rows += [("Festival (its own CPU, in parallel)", 0.0, got["festival_cpu"]), ("total", wall, cpu_all)]
            for name, w, c in rows:
                phases.setdefault(name, []).append((w, c))
        with wave.open(str(next(Path(f"{tmp}/o").glob("*.wav")))) as f:
            speech = f.getnframes() / f.getframerate()
    lines = [f"coartic speak {SENTENCE!r} --preview {args.preview} (the shipped table): {speech:.3f} s of speech; "
             f"medians of {args.rounds} fresh runs",
             f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
             f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (other jobs share the cores)",
             "", f"{'phase':60s} {'wall s':>7s} {'CPU s':>7s} {'wall/speech':>11s} {'CPU/speech':>10s}"]
    for name, vals in phases.items():
        w = statistics.median(v[0] for v in vals)
        c = statistics.median(v[1] for v in vals)
        lines.append(f"{name:60s} {w:7.3f} {c:7.3f} {w / speech:11.3f} {c / speech:10.3f}")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
