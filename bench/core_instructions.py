"""A fixed, single-threaded workload of the Rust core for instruction counting (callgrind), when
timings on a busy machine are too noisy to compare two builds (bench/core_speed.py).

The bench corpus of core_speed.py (150 utterances x 100 samples x 7 segments), in both variants:
evaluate x3, jacobian_values x2, sse_gradient x2, physical_limit_loop x1. Instruction counts are
exact and repeatable; compare two builds function by function:

    RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=cg.out \\
        .venv/bin/python bench/core_instructions.py
    callgrind_annotate --inclusive=yes --threshold=100 cg.out | grep coartic::

(the other build: the same with PYTHONPATH pointing at a copy of python/ holding its extension).
``--rate-aware`` runs the same workload with the options of MODEL.md §2.1 (plateau dominance,
h = 0.5, and handover), to see what they cost.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests" / "python"))

import core_speed  # noqa: E402
from conftest import random_params  # type: ignore[import-not-found]  # noqa: E402

from coartic import _core  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate-aware", action="store_true", help="plateau dominance (h = 0.5) and handover")
    rate = {"dominance": "plateau", "plateau_fraction": 0.5, "handover": True} if ap.parse_args().rate_aware else {}
    rng = np.random.default_rng(1)
    corpus = _core.Corpus(**core_speed.vcv_corpus(150, 100, rng))
    params = random_params(rng, 12)
    y, w = np.zeros(corpus.n_samples), np.ones(corpus.n_samples)
    for variant in ("modified", "original"):
        opts = _core.ModelOptions(variant, **rate)  # type: ignore[arg-type]
        for _ in range(3):
            _core.evaluate(corpus, params, 1.0, opts)
        for _ in range(2):
            _core.jacobian_values(corpus, params, 1.0, opts)
            _core.sse_gradient(corpus, params, 1.0, opts, y, w)
        _core.physical_limit_loop(corpus, params, opts)


if __name__ == "__main__":
    main()
