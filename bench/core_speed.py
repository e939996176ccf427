"""Speed of the Rust core, measured in one run on this machine (issue 2, "Speed").

Prints, and saves to bench/results/core_speed.txt:
(a) a corpus of ~600 utterances x 100 samples x 7 segments: Rust evaluate vs the NumPy reference
    of MODEL.md (tests/python/numpy_model.py; aim >= 30x) and vs the physical limit, a loop of
    only the exponentials and powers the model needs (aim <= 3x);
(b) the Jacobian / one evaluation (aim <= 4x): as a fitting loop computes it, the values refilled
    into reused buffers (jacobian_values; the pattern is built once per corpus), and, for
    comparison, the full jacobian() that allocates and returns pattern and values every call;
(c) one Python call for one VCV (prebuilt Corpus, 7 segments, 100 samples): its total time, and
    its calling overhead (aim < 5 us) measured two ways: the total minus the same VCV's model time
    inside one call over a batch of identical VCVs, and the bare call on a 1-segment, 1-sample
    corpus.
Times are the best of several rounds (timeit), the contenders of one ratio timed in turns, so that
other load on this shared machine inflates them less and alike.

Run: .venv/bin/python bench/core_speed.py [--utterances 600] [--out bench/results/core_speed.txt]
(after `.venv/bin/maturin develop --release --quiet`: a debug build measures nothing useful)
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
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


def build_provenance() -> str:
    """Which core is measured: the extension's build time against the checkout's HEAD, since the
    build takes whatever src/ holds, committed or not."""
    so = Path(_core.__file__)
    built = time.strftime("%H:%M:%S UTC", time.gmtime(so.stat().st_mtime))
    try:
        head = subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h %cd", "--date=format-local:%H:%M:%S"],
                              capture_output=True, text=True, check=True, env={**os.environ, "TZ": "UTC"}).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", "src"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return f"extension built {built} (no git)"
    return f"extension built {built}; HEAD {head} UTC{', src/ has uncommitted changes' if dirty else ''}"


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

    say(f"$ {' '.join([Path(sys.executable).name, *sys.argv])}")
    say(f"at {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}; {build_provenance()}")
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
        values_buf, data_buf = np.empty(corpus.n_samples), np.empty(corpus.jacobian_nnz)
        corpus.jacobian_pattern()  # built once per corpus, outside the loop, as a fit does
        t = interleaved(
            {
                "rust": (lambda: _core.evaluate(corpus, params, beta, opts), 10),
                "numpy": (reference, 1),
                "limit": (lambda: _core.physical_limit_loop(corpus, params, opts), 10),
                "jac": (lambda: _core.jacobian(corpus, params, beta, opts), 3),
                "jac_buf": (lambda: _core.jacobian_values(corpus, params, beta, opts, values_buf, data_buf), 3),
                "sse": (lambda: _core.sse_gradient(corpus, params, beta, opts, y, w), 5),
            },
            rounds=6,
        )
        t_rust, t_numpy, t_limit, t_jac, t_jac_buf, t_sse = (
            t[k] for k in ("rust", "numpy", "limit", "jac", "jac_buf", "sse")
        )
        if variant == "modified":
            t_rust_mod = t_rust
        say(f"[{variant}] max relative difference Rust vs NumPy reference: {err:.1e}")
        say(f"[{variant}] (a) evaluate          {t_rust * 1e3:8.3f} ms")
        say(f"[{variant}]     NumPy reference   {t_numpy * 1e3:8.1f} ms   -> Rust is {t_numpy / t_rust:6.1f}x faster (aim >= 30x)")
        say(f"[{variant}]     physical limit    {t_limit * 1e3:8.3f} ms   -> evaluate / limit = {t_rust / t_limit:5.2f}x (aim <= 3x)")
        say(f"[{variant}] (b) Jacobian, buffers {t_jac_buf * 1e3:8.3f} ms   -> Jacobian / evaluate = {t_jac_buf / t_rust:5.2f}x (aim <= 4x)"
            f"  [jacobian_values into reused arrays, {corpus.jacobian_nnz * 8 / 1e6:.0f} MB]")
        say(f"[{variant}]     full jacobian()   {t_jac * 1e3:8.3f} ms   -> Jacobian / evaluate = {t_jac / t_rust:5.2f}x"
            f"  [allocates and returns values, pattern and data every call]")
        say(f"[{variant}]     SSE + gradient    {t_sse * 1e3:8.3f} ms   -> / evaluate = {t_sse / t_rust:5.2f}x")

    one = vcv_corpus(1, 100, rng)
    vcv = _core.Corpus(**one)
    # The same VCV K times in one corpus: K x 707 (sample, segment) pairs stays below the core's
    # threshold for going parallel, so this is the single-threaded model time of one VCV (were it
    # parallel, the model time would come out smaller and the overhead larger, not smaller).
    k = 20
    same: dict[str, Any] = {
        "seg_offsets": np.arange(0, 7 * k + 1, 7, dtype=np.int64),
        "seg_phoneme": np.tile(one["seg_phoneme"], k),
        "seg_start": np.tile(one["seg_start"], k),
        "seg_end": np.tile(one["seg_end"], k),
        "sample_offsets": np.arange(0, 100 * k + 1, 100, dtype=np.int64),
        "sample_times": np.tile(one["sample_times"], k),
        "n_phonemes": 12,
    }
    batch = _core.Corpus(**same)
    tiny = _core.Corpus(np.array([0, 1]), np.array([0]), np.array([0.0]), np.array([0.1]), np.array([0, 1]),
                        np.array([0.05]), 12)
    p_vcv = params.copy()
    opts = _core.ModelOptions()
    v_vcv, d_vcv = np.empty(vcv.n_samples), np.empty(vcv.jacobian_nnz)
    t = interleaved(
        {
            "call": (lambda: _core.evaluate(vcv, p_vcv, beta, opts), 5000),
            "batch": (lambda: _core.evaluate(batch, p_vcv, beta, opts), 250),
            "bare": (lambda: _core.evaluate(tiny, p_vcv, beta, opts), 5000),
            "jac": (lambda: _core.jacobian_values(vcv, p_vcv, beta, opts, v_vcv, d_vcv), 2000),
        },
        rounds=9,
    )
    t_model = t["batch"] / k
    say(f"(c) one VCV (7 segments, 100 samples), evaluate from Python: {t['call'] * 1e6:6.2f} us per call in total")
    say(f"    its model time inside a call over {k} identical VCVs: {t_model * 1e6:6.2f} us per VCV")
    say(f"    -> calling overhead = total - model time:    {(t['call'] - t_model) * 1e6:6.2f} us (aim < 5 us)")
    say(f"    bare call (1 segment, 1 sample):              {t['bare'] * 1e6:6.2f} us (aim < 5 us)")
    say(f"    one VCV, jacobian_values into reused buffers: {t['jac'] * 1e6:6.2f} us per call "
        f"({t['jac'] / t['call']:.2f}x its evaluate)")
    say(f"    model time per sample: {t_model * 1e9 / 100:.0f} ns in the VCV batch, "
        f"{t_rust_mod * 1e9 / corpus.n_samples:.0f} ns in the {corpus.n_utterances}-utterance corpus (parallel)")
    say(f"load average {os.getloadavg()[0]:.1f} at the end (other work on the machine slows both sides of a ratio)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"saved to {args.out}")


if __name__ == "__main__":
    main()
