"""CPU seconds of every Python test file, and the quiet 2-core wall time they imply (issue 28, item 7).

On a machine shared with other jobs wall time says little, CPU time (user + system of pytest and
every process it waited for: dask workers, subprocess commands, Festival) says what a file costs.
Each file runs in its own `pytest -q -p no:cacheprovider FILE` (no xdist), `--jobs` at a time; a
file's CPU is read from os.wait4 of its pytest process. The estimate of `make test-python` on a
quiet 2-core machine is the longest-processing-time schedule of the files over two workers in the
order conftest.py gives them (longest first, then the files with a slow test, then the rest: what
`-n 2 --dist loadfile` does) plus one interpreter start-up and collection per worker, which a
single-process run of each file pays once per file and xdist once per worker. It is an estimate:
files that share a worker also share caches, and two busy cores contend for memory.

`--before FILE` (an earlier output of this script) adds a before/after column per file.

Run: .venv/bin/python bench/test_suite_cpu.py [--jobs 2] [--before bench/results/test_suite_cpu_before.txt]
         [--out bench/results/test_suite_cpu.txt] [FILE ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests" / "python"
LINE = re.compile(r"^(test_\S+\.py)\s+([0-9.]+)\s+([0-9.]+)\s+(\S+)")


def run_files(files: list[Path], jobs: int, env: dict[str, str],
              done: Callable[[dict[str, tuple[float, float, str]]], None]) -> dict[str, tuple[float, float, str]]:
    """{file name: (CPU s, wall s, pytest's last line)} of each file run alone; ``done`` sees the
    results so far after each file (a run stopped early still leaves them)."""
    pending = list(files)
    running: dict[int, tuple[Path, float, subprocess.Popen[str]]] = {}
    out: dict[str, tuple[float, float, str]] = {}
    while pending or running:
        while pending and len(running) < jobs:
            f = pending.pop(0)
            log = open(f"/tmp/test_suite_cpu.{os.getpid()}.{f.stem}.log", "w")
            proc = subprocess.Popen(
                [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(f)],
                cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT, text=True,
            )
            running[proc.pid] = (f, time.perf_counter(), proc)
        pid, status, usage = os.wait4(-1, 0)
        if pid not in running:
            continue
        f, t0, proc = running.pop(pid)
        proc.returncode = os.waitstatus_to_exitcode(status)
        log_path = Path(f"/tmp/test_suite_cpu.{os.getpid()}.{f.stem}.log")
        lines = [ln for ln in log_path.read_text().splitlines() if ln.strip()]
        log_path.unlink()
        last = lines[-1] if lines else f"exit {proc.returncode}"
        out[f.name] = (usage.ru_utime + usage.ru_stime, time.perf_counter() - t0, last.replace(" ", "_"))
        print(f"{f.name:40s} {out[f.name][0]:8.1f} CPU-s {out[f.name][1]:8.1f} wall-s  {last}", flush=True)
        done(out)
    return out


def order(names: list[str]) -> list[str]:
    """The order `make test-python` hands the files out in (conftest.pytest_collection_modifyitems)."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    import conftest

    text = {n: (TESTS / n).read_text() for n in names}
    slow = {n for n in names if "mark.slow" in text[n]}

    def rank(n: str) -> tuple[int, int]:
        if n in conftest.LONGEST_FIRST:
            return 0, conftest.LONGEST_FIRST.index(n)
        return (1 if n in slow else 2), 0

    return sorted(sorted(names), key=rank)  # pytest collects files alphabetically


def schedule(cpu: dict[str, float], names: list[str], startup: float, workers: int = 2) -> float:
    """Wall time of handing files in order to the first free of `workers` workers."""
    free = [startup] * workers
    for n in names:
        i = min(range(workers), key=lambda w: free[w])
        free[i] += max(cpu[n] - startup, 0.0)
    return max(free)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="*", help="test files (default: every tests/python/test_*.py)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--before", default=None)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "test_suite_cpu.txt"))
    args = ap.parse_args()
    files = [Path(f).resolve() for f in args.files] or sorted(TESTS.glob("test_*.py"))
    env = {**os.environ, "PYTHONPATH": str(ROOT / "python")}
    # the longest known first, so that two jobs finish together
    before: dict[str, float] = {}
    if args.before:
        for ln in Path(args.before).read_text().splitlines():
            m = LINE.match(ln)
            if m:
                before[m.group(1)] = float(m.group(2))
    files.sort(key=lambda f: -before.get(f.name, 0.0))
    load0 = os.getloadavg()[0]
    # interpreter start-up and collection: an empty selection of a small file
    t = subprocess.run([sys.executable, "-c", "import resource,subprocess,sys; subprocess.run([sys.executable,'-m','pytest','-q',"
                        "'-p','no:cacheprovider','--co',sys.argv[1]],capture_output=True); "
                        "r=resource.getrusage(resource.RUSAGE_CHILDREN); print(r.ru_utime+r.ru_stime)",
                        str(TESTS / "test_console.py")], env=env, cwd=ROOT, capture_output=True, text=True)
    startup = float(t.stdout.strip() or 0.0)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    def write(res: dict[str, tuple[float, float, str]]) -> None:
        text = report(res, len(files), args.jobs, args.before, before, load0, startup, commit)
        tmp = Path(args.out + ".partial")
        tmp.write_text(text)
        tmp.replace(args.out)

    res = run_files(files, args.jobs, env, write)
    print(report(res, len(files), args.jobs, args.before, before, load0, startup, commit))


def report(res: dict[str, tuple[float, float, str]], n_files: int, jobs: int, before_path: str | None,
           before: dict[str, float], load0: float, startup: float, commit: str) -> str:
    names = order(list(res))
    cpu = {n: res[n][0] for n in names}
    # no file costs less than its start-up (the --co measurement varies with the page cache)
    startup = min([startup, *cpu.values()])
    total = sum(cpu.values())
    lines = [
        f"# bench/test_suite_cpu.py --jobs {jobs}{' --before ' + before_path if before_path else ''}",
        f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {platform.node()}, {os.cpu_count()} cores, "
        f"load average {load0:.1f} at start, {os.getloadavg()[0]:.1f} now; commit {commit}; "
        f"{len(res)} of {n_files} files done" + ("" if len(res) == n_files else " (partial: the estimate below covers these only)"),
        "# file  CPU-s(user+sys, with children)  wall-s(under that load)  pytest's summary"
        + ("  | CPU-s before  change" if before else ""),
    ]
    for n in sorted(names, key=lambda n: -cpu[n]):
        c, w, last = res[n]
        row = f"{n:40s} {c:8.1f} {w:8.1f} {last}"
        if before:
            b = before.get(n)
            row += f"  | {b:8.1f} {c - b:+8.1f}" if b is not None else "  | (new)"
        lines.append(row)
    lines.append(f"# total CPU {total:.0f} s over {len(names)} files; start-up and collection of one pytest {startup:.1f} CPU-s")
    if before:
        lines.append(f"# before: total CPU {sum(before.values()):.0f} s over {len(before)} files")
    est = schedule(cpu, names, startup)
    lines.append(
        f"# estimated quiet 2-core wall of make test-python (files in conftest order to the first free worker): {est:.0f} s "
        f"= {est / 60:.1f} min (total/2, every file paying its own start-up: {total / 2 / 60:.1f} min)"
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
