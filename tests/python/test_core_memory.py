"""Inputs that are valid but need more memory than the machine has: MemoryError naming the sizes,
never an aborted interpreter (Rust's default when an allocation fails).

The cases run in a child interpreter whose address space is capped (RLIMIT_AS) a little above
what it already uses, so every oversized allocation fails at once, whatever memory this machine
has, and nothing is ever touched: cheap and deterministic.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("resource")

CHILD = textwrap.dedent(
    r"""
    import resource
    import numpy as np
    from coartic import _core

    def vm_size():
        with open("/proc/self/status") as f:
            return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))

    # Every array below is built before the cap; the cap leaves 2 GiB for the calls' own work.
    n = 20000  # phonemes, one segment each, in one utterance
    long_utt = _core.Corpus(np.array([0, n]), np.arange(n), np.arange(n) * 0.01, np.arange(1, n + 1) * 0.01,
                            np.array([0, 100000]), np.linspace(0.0, n * 0.01, 100000), n)
    params = np.tile([1.0, 1.0, 20.0, 20.0, 1.0, 1.0, 0.5, 0.0, 10.0, 0.0], (n, 1))
    vcv = _core.Corpus(np.array([0, 1]), np.array([0]), np.array([0.0]), np.array([1.0]),
                       np.array([0, 200000]), np.linspace(0.0, 1.0, 200000), 1)
    opts = _core.ModelOptions()
    walkers = np.broadcast_to(params[:1], (100000, 1, 10))  # a view: no memory
    huge_view = np.broadcast_to(params[:1], (10**9, 1, 10))  # a view whose copy is 80 GB
    resource.setrlimit(resource.RLIMIT_AS, (vm_size() + (2 << 30), resource.RLIM_INFINITY))

    cases = {
        "jacobian_pattern": lambda: long_utt.jacobian_pattern(),
        "jacobian_values": lambda: _core.jacobian_values(long_utt, params, 1.0, opts),
        "jacobian": lambda: _core.jacobian(long_utt, params, 1.0, opts),
        "evaluate_batch": lambda: _core.evaluate_batch(vcv, walkers, np.ones(100000), opts),
        "residual_sums_batch": lambda: _core.residual_sums_batch(
            _core.Corpus(np.zeros(100001, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0),
                         np.zeros(100001, dtype=np.int64), np.zeros(0), 1),
            np.broadcast_to(params[:1], (10**6, 1, 10)), np.ones(10**6), opts, np.zeros(0), np.zeros(0)),
        "copy of a broadcast view": lambda: _core.evaluate_batch(vcv, huge_view, np.broadcast_to(1.0, (10**9,)), opts),
    }
    for name, call in cases.items():
        try:
            call()
        except MemoryError as e:
            print(f"{name}: MemoryError: {e}")
        else:
            print(f"{name}: no error")
    # Still alive, and still computing.
    print("after:", _core.evaluate(vcv, params[:1], 1.0, opts).shape)
    """
)


def test_oversized_buffers_raise_memory_error_naming_the_sizes() -> None:
    run = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"child died ({run.returncode}): {run.stderr[-2000:]}"
    out = dict(line.split(": ", 1) for line in run.stdout.splitlines())
    jac = "MemoryError: cannot allocate the Jacobian's {} (100000 samples; up to 20000 distinct phonemes"
    assert out["jacobian_pattern"].startswith(jac.format("column indices")), out
    assert out["jacobian_values"].startswith(jac.format("values")), out
    assert out["jacobian"].startswith(jac.format("column indices")), out
    assert "20000100000 values of 8 bytes = 149.0 GiB" in out["jacobian"]
    assert out["evaluate_batch"] == (
        "MemoryError: cannot allocate the output of a batch (100000 walkers × 200000 samples): "
        "20000000000 values of 8 bytes = 149.0 GiB"
    )
    assert out["residual_sums_batch"].startswith(
        "MemoryError: cannot allocate the output of a batch (1000000 walkers × 100000 utterances)"
    ), out
    assert out["copy of a broadcast view"] == (
        "MemoryError: cannot allocate a C-ordered copy of argument 'params' (shape (1000000000, 1, 10), "
        "not C-contiguous): 10000000000 values of 8 bytes = 74.5 GiB"
    )
    assert out["after"] == "(200000,)"
