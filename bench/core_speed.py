"""Speed of the Rust core, measured in one run on this machine (issue 2, "Speed").

Prints, and saves to bench/results/core_speed.txt:
(a) a corpus of ~600 utterances x 100 samples x 7 segments: Rust evaluate vs the NumPy reference
    of MODEL.md (tests/python/numpy_model.py; aim >= 30x) and vs the physical limit, a loop of
    only the exponentials and powers the model needs (aim <= 3x);
(b) the full Jacobian / one evaluation (aim <= 4x);
(c) the cost of one Python call for one VCV (prebuilt Corpus, 100 samples; aim < 5 us), and the
    bare calling overhead (a 1-segment, 1-sample corpus).
Times are the best of several rounds (timeit), the contenders of one ratio timed in turns, so that
other load on this shared machine inflates them less and alike.

Run: .venv/bin/python bench/core_speed.py [--utterances 600] [--out bench/results/core_speed.txt]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import timeit
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))

import numpy_model as nm  # type: ignore[import-not-found]  # noqa: E402
from conftest import random_params  # type: ignore[import-not-found]  # noqa: E402

from coartic import _core  # noqa: E402


def interleaved(fns: dict[str, tuple[Callable[[], object], int]], rounds: int) -> dict[str, float]:
    """Best time per call (s) of each function, timed in turns round after round, so that a busy
    spell on this shared machine slows all of them alike instead of one."""
    out = {name: float("inf") for name in fns}
    for _ in range(rounds):
        for name, (fn, number) in fns.items():
            out[name] = min(out[name], timeit.timeit(fn, number=number) / number)
    return out


def best(fn: Callable[[], object], repeat: int, number: int) -> float:
    """Best time per call (s) over `repeat` rounds of `number` calls."""
    return min(timeit.repeat(fn, repeat=repeat, number=number)) / number


def vcv_corpus(n_utt: int, n_samples: int, rng: np.random.Generator) -> dict[str, Any]:
    """n_utt utterances # V C V C V # (7 segments), durations varied, n_samples evenly spaced."""
    n_seg = 7
    seg_phoneme = np.empty(n_utt * n_seg, dtype=np.int64)
    starts = np.empty(n_utt * n_seg)
    ends = np.empty(n_utt * n_seg)
    times = np.empty(n_utt * n_samples)
    for u in range(n_utt):
        dur = np.array([0.15, 0.13, 0.09, 0.14, 0.09, 0.15, 0.15]) * rng.uniform(0.6, 1.1)
        e = np.cumsum(dur)
        s = e - dur
        s[1:] = e[:-1]  # exactly adjacent
        v, c = rng.integers(1, 4, 3), rng.integers(4, 12, 2)
        seg_phoneme[u * n_seg : (u + 1) * n_seg] = [0, v[0], c[0], v[1], c[1], v[2], 0]
        starts[u * n_seg : (u + 1) * n_seg] = s
        ends[u * n_seg : (u + 1) * n_seg] = e
        times[u * n_samples : (u + 1) * n_samples] = np.linspace(0.0, e[-1], n_samples, endpoint=False)
    return {
        "seg_offsets": np.arange(0, n_utt * n_seg + 1, n_seg, dtype=np.int64),
        "seg_phoneme": seg_phoneme,
        "seg_start": starts,
        "seg_end": ends,
        "sample_offsets": np.arange(0, n_utt * n_samples + 1, n_samples, dtype=np.int64),
        "sample_times": times,
        "n_phonemes": 12,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--utterances", type=int, default=600)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "core_speed.txt")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    lines: list[str] = []

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    say(f"coartic core speed; {platform.machine()}, {os.cpu_count()} CPUs (shared), "
        f"RAYON_NUM_THREADS={os.environ.get('RAYON_NUM_THREADS', 'default')}, numpy {np.__version__}, "
        f"load average {os.getloadavg()[0]:.1f} at start")
    arrays = vcv_corpus(args.utterances, 100, rng)
    corpus = _core.Corpus(**arrays)
    params = random_params(rng, 12)
    params[:, 9] = 0.0
    params[4:, 6] = 1.0  # resistant consonants, as /p b m f v/
    beta = 1.0
    say(f"corpus: {corpus.n_utterances} utterances, {corpus.n_segments} segments, {corpus.n_samples} samples")

    for variant in ("modified", "original"):
        opts = _core.ModelOptions(variant)
        got = _core.evaluate(corpus, params, beta, opts)
        def reference(variant: str = variant) -> np.ndarray:
            return nm.evaluate_corpus_arrays(params, arrays, beta, variant)

        want = reference()
        err = float(np.max(np.abs(got - want) / np.maximum(1.0, np.abs(want))))
        y = got + rng.normal(0, 0.1, got.shape)
        w = np.ones_like(y)
        t = interleaved(
            {
                "rust": (lambda: _core.evaluate(corpus, params, beta, opts), 10),
                "numpy": (reference, 1),
                "limit": (lambda: _core.physical_limit_loop(corpus, params, opts), 10),
                "jac": (lambda: _core.jacobian(corpus, params, beta, opts), 3),
                "sse": (lambda: _core.sse_gradient(corpus, params, beta, opts, y, w), 5),
            },
            rounds=6,
        )
        t_rust, t_numpy, t_limit, t_jac, t_sse = (t[k] for k in ("rust", "numpy", "limit", "jac", "sse"))
        if variant == "modified":
            t_rust_mod = t_rust
        say(f"[{variant}] max relative difference Rust vs NumPy reference: {err:.1e}")
        say(f"[{variant}] (a) evaluate          {t_rust * 1e3:8.3f} ms")
        say(f"[{variant}]     NumPy reference   {t_numpy * 1e3:8.1f} ms   -> Rust is {t_numpy / t_rust:6.1f}x faster (aim >= 30x)")
        say(f"[{variant}]     physical limit    {t_limit * 1e3:8.3f} ms   -> evaluate / limit = {t_rust / t_limit:5.2f}x (aim <= 3x)")
        say(f"[{variant}] (b) full Jacobian     {t_jac * 1e3:8.3f} ms   -> Jacobian / evaluate = {t_jac / t_rust:5.2f}x (aim <= 4x)")
        say(f"[{variant}]     SSE + gradient    {t_sse * 1e3:8.3f} ms   -> / evaluate = {t_sse / t_rust:5.2f}x")

    one = vcv_corpus(1, 100, rng)
    vcv = _core.Corpus(**one)
    p_vcv = params.copy()
    opts = _core.ModelOptions()
    t_call = best(lambda: _core.evaluate(vcv, p_vcv, beta, opts), repeat=9, number=20000)
    tiny = _core.Corpus(np.array([0, 1]), np.array([0]), np.array([0.0]), np.array([0.1]), np.array([0, 1]),
                        np.array([0.05]), 12)
    t_bare = best(lambda: _core.evaluate(tiny, p_vcv, beta, opts), repeat=9, number=20000)
    say(f"(c) one VCV (7 segments, 100 samples) from Python: {t_call * 1e6:6.2f} us per call (aim < 5 us)")
    say(f"    bare calling overhead (1 segment, 1 sample):   {t_bare * 1e6:6.2f} us per call")
    say(f"    so the VCV call is {t_bare * 1e6:.2f} us of overhead + {(t_call - t_bare) * 1e9 / 100:.0f} ns of model "
        f"per sample (the batch above: {t_rust_mod * 1e9 / corpus.n_samples:.0f} ns per sample)")
    say(f"load average {os.getloadavg()[0]:.1f} at the end (other work on the machine slows both sides of a ratio)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"saved to {args.out}")


if __name__ == "__main__":
    main()
