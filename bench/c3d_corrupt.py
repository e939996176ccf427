"""Corrupted C3D files against the reader: refused quickly with a DataError, never a crash (issue 11).

Mutates the Optotrak fixture (tests/data/realdata) in its parameter section — the byte that ezc3d
trusted for POINT:LABELS' number of dimensions set to 255, and 40 copies with 1-3 bytes deleted at
random (seed 3), which shift every later entry — and reads each with `read_c3d` in a child
process, so that a segfault is counted instead of ending the run. Prints the outcome counts
(read, DataError, crash, timeout) and the slowest read.

Run: .venv/bin/python bench/c3d_corrupt.py [--out bench/results/c3d_corrupt.txt]
"""

from __future__ import annotations

import argparse
import random
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests/data/realdata/c3d-optotrak/Optotrak.c3d"
CHILD = """
import sys, time
from coartic.io import DataError
from coartic.io.c3d import read_c3d
t0 = time.perf_counter()
try:
    read_c3d(sys.argv[1], allow_truncated=True)
    what = "read"
except DataError:
    what = "DataError"
print(what, time.perf_counter() - t0)
"""


def outcome(data: bytes, tmp: Path, timeout: float = 300.0) -> tuple[str, float]:
    path = tmp / "mutant.c3d"
    path.write_bytes(data)
    try:
        r = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", timeout
    if r.returncode < 0:
        return f"crash (signal {-r.returncode})", float("nan")
    fields = r.stdout.split()
    if len(fields) != 2:
        return f"other (exit {r.returncode})", float("nan")
    return fields[0], float(fields[1])  # the read alone, timed in the child


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench/results/c3d_corrupt.txt")
    args = ap.parse_args()
    src = FIXTURE.read_bytes()
    lines = [f"# {Path(__file__).name}: corrupted copies of {FIXTURE.relative_to(ROOT)}, each read in a child process"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        what, secs = outcome(src, tmp)
        lines.append(f"the intact file: {what} in {secs:.3f} s")
        one = bytearray(src)
        at = one.index(b"LABELS") + len("LABELS") + 3
        one[at] = 255
        what, secs = outcome(bytes(one), tmp)
        lines.append(f"POINT:LABELS dimension count set to 255: {what} in {secs:.3f} s")
        rng = random.Random(3)
        counts: Counter[str] = Counter()
        worst = 0.0
        for _ in range(40):
            pos, n = rng.randrange(520, 3000), rng.randrange(1, 4)
            what, secs = outcome(src[:pos] + src[pos + n:], tmp)
            counts[what] += 1
            worst = max(worst, secs) if secs == secs else worst
        lines.append("40 copies with 1-3 bytes deleted in the parameter section: "
                     + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
                     + f"; slowest read {worst:.3f} s")
    text = "\n".join(lines) + "\n"
    print(text, end="")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)


if __name__ == "__main__":
    main()
