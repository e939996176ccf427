"""How fast does `coartic` start, and does `speak` keep up with real time including start-up? (issue 20, item 6)

Each round runs, one after the other in fresh interpreters, the reference `python -c 'import numpy'`,
`coartic --help`, `coartic --version` and `coartic speak` of a 2-s sentence (with `--preview none`
and with the default GIF preview); the rounds are interleaved so that the reference sees the same
machine load as what it is compared with. Reported: the median wall time of each and its ratio to
the reference (goal: `--help` within 3x), and for `speak` the wall and CPU time (the command and
Festival, user + system) against the duration of the speech it wrote (below 1 = faster than real
time). CPU time is what the command costs; wall time also holds the waits for the shared cores.

The table is the one shipped with coartic (what `coartic speak` uses without --table), unless
--table names another.

`--before DIR` adds, in the same rounds, the two `speak` commands run from another checkout's
python/ directory (e.g. a `git worktree` of an earlier commit, with the Rust extension copied in):
the change and what it is compared with see the same load.

Run: .venv/bin/python bench/startup.py [--rounds 7] [--table T] [--before DIR] [--out bench/results/startup.txt]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import wave
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SENTENCE = "Il babbo mangia la pappa."


def run(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system of the process and its children) of one command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--table", default=None, help="default: the shipped table (no --table)")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--before", default=None, help="another checkout's python/ directory, run alongside")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "startup.txt"))
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "python"), "COLUMNS": "100"}
    py = sys.executable
    coartic = [py, "-m", "coartic.cli"]
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        table = ["--table", args.table] if args.table else []

        def speak(out: str, *extra: str) -> list[str]:
            return [*coartic, "speak", SENTENCE, *table, "--out", f"{tmp}/{out}", *extra, "--force"]

        cases: dict[str, list[str]] = {
            "python -c 'import numpy'": [py, "-c", "import numpy"],
            "coartic --help": [*coartic, "--help"],
            "coartic --version": [*coartic, "--version"],
            "coartic speak --preview none": speak("none", "--preview", "none"),
            "coartic speak (default: GIF)": speak("gif"),
        }
        envs = {name: env for name in cases}
        if args.before:
            before_env = {**env, "PYTHONPATH": str(Path(args.before).resolve())}
            cases["coartic speak --preview none BEFORE"] = speak("before_none", "--preview", "none")
            cases["coartic speak (default: GIF) BEFORE"] = speak("before_gif")
            envs["coartic speak --preview none BEFORE"] = envs["coartic speak (default: GIF) BEFORE"] = before_env
        walls: dict[str, list[float]] = {k: [] for k in cases}
        cpus: dict[str, list[float]] = {k: [] for k in cases}
        run(cases["coartic --help"], env)  # warm the file cache once
        for _ in range(args.rounds):
            for name, cmd in cases.items():
                w, c = run(cmd, envs[name])
                walls[name].append(w)
                cpus[name].append(c)
        wav = next(Path(f"{tmp}/none").glob("*.wav"))
        with wave.open(str(wav)) as f:
            speech = f.getnframes() / f.getframerate()
    ref = statistics.median(walls["python -c 'import numpy'"])
    ref_cpu = statistics.median(cpus["python -c 'import numpy'"])
    lines = [f"coartic start-up, {args.rounds} interleaved rounds, medians; sentence {SENTENCE!r} "
             f"({speech:.3f} s of speech, Festival pc_diphone), table "
             f"{Path(args.table).name if args.table else 'shipped (italian_table.json)'}",
             f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
             f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end "
             "(other jobs share the cores)", "",
             *([f"BEFORE: the same speak commands from {args.before}"] if args.before else []), "",
             f"{'command':39s} {'wall s':>8s} {'x numpy':>8s} {'CPU s':>8s} {'x numpy':>8s} {'wall/speech':>12s} "
             f"{'CPU/speech':>11s}"]
    for name in cases:
        w, c = statistics.median(walls[name]), statistics.median(cpus[name])
        per_speech = f"{w / speech:12.2f} {c / speech:11.2f}" if name.startswith("coartic speak") else ""
        lines.append(f"{name:39s} {w:8.3f} {w / ref:8.2f} {c:8.3f} {c / ref_cpu:8.2f} {per_speech}")
    lines += ["", "goals (issue 20): --help within 3x numpy's import; speak of a 2-s sentence, start-up included, "
              "faster than real time (wall/speech < 1)"]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
