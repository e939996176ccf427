"""Shared fixtures: random models and corpora for the core, the illustrative VCV table, synthetic
sessions without their overview figure.

``random_params``, ``random_corpus_arrays`` and ``without_overview`` are plain functions (tests
import them with ``from conftest import ...``); the first two are also offered as fixtures.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import settings

# numpy_model.py (the NumPy reference) sits beside the tests; make it importable from any rootdir.
sys.path.insert(0, str(Path(__file__).parent))

# The property tests draw the same examples on every run (derandomized): make test on a clean
# checkout then passes or fails on the code, not on the draw, and a failure reproduces. Hunting for
# new counterexamples is a separate, deliberate run: HYPOTHESIS_PROFILE=explore make test-python.
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
CorpusArrays = dict[str, Any]


def random_params(rng: np.random.Generator, n_phonemes: int) -> F64:
    """A random model within the default bounds of MODEL.md §1 (δ small enough never to clamp)."""
    n = n_phonemes
    return np.column_stack(
        [
            rng.uniform(-10.0, 20.0, n),  # target
            rng.uniform(0.2, 3.0, n),  # alpha
            rng.uniform(5.0, 120.0, n),  # theta_bw
            rng.uniform(5.0, 120.0, n),  # theta_fw
            rng.uniform(0.5, 3.0, n),  # c_bw
            rng.uniform(0.5, 3.0, n),  # c_fw
            rng.uniform(0.0, 1.0, n),  # k_r
            rng.uniform(-0.5, 0.5, n),  # sigma
            rng.uniform(1.0, 400.0, n),  # psi
            rng.uniform(-0.015, 0.015, n),  # delta
        ]
    )


def random_corpus_arrays(
    rng: np.random.Generator,
    n_utterances: int,
    n_phonemes: int,
    segments: tuple[int, int] = (3, 8),
    samples: int = 80,
) -> CorpusArrays:
    """CSR corpus arrays (docs/ARCHITECTURE.md) of random utterances: segments 40–200 ms long,
    samples at random times from 50 ms before the first to 50 ms after the last segment."""
    seg_offsets, sample_offsets = [0], [0]
    phon: list[I64] = []
    st: list[F64] = []
    en: list[F64] = []
    tm: list[F64] = []
    for _ in range(n_utterances):
        n_seg = int(rng.integers(segments[0], segments[1] + 1))
        dur = rng.uniform(0.04, 0.2, n_seg)
        gaps = np.where(rng.random(n_seg) < 0.2, rng.uniform(0.0, 0.03, n_seg), 0.0)
        starts = np.empty(n_seg)
        ends = np.empty(n_seg)
        t = rng.uniform(0.0, 0.5)
        for i in range(n_seg):  # sequentially, so that start_i >= end_(i-1) holds in floating point
            starts[i] = t + gaps[i]
            ends[i] = starts[i] + dur[i]
            t = ends[i]
        phon.append(rng.integers(0, n_phonemes, n_seg))
        st.append(starts)
        en.append(ends)
        tm.append(np.sort(rng.uniform(starts[0] - 0.05, ends[-1] + 0.05, samples)))
        seg_offsets.append(seg_offsets[-1] + n_seg)
        sample_offsets.append(sample_offsets[-1] + samples)
    return {
        "seg_offsets": np.asarray(seg_offsets, dtype=np.int64),
        "seg_phoneme": np.concatenate(phon).astype(np.int64),
        "seg_start": np.concatenate(st),
        "seg_end": np.concatenate(en),
        "sample_offsets": np.asarray(sample_offsets, dtype=np.int64),
        "sample_times": np.concatenate(tm),
        "n_phonemes": n_phonemes,
    }


@pytest.fixture
def make_params() -> Callable[[np.random.Generator, int], F64]:
    return random_params


@pytest.fixture
def make_corpus_arrays() -> Callable[..., CorpusArrays]:
    return random_corpus_arrays


@pytest.fixture
def illustrative_table() -> Any:
    """The demo's hand-made LLO table (#, a, p, f, t), a valid modified-model table."""
    from coartic.demo import illustrative_table as make

    return make()


@contextlib.contextmanager
def without_overview() -> Iterator[ModuleType]:
    """The synthetic-session generator (corpus-synthetic/generate.py, coartic.synthetic_cli) with
    its overview figure left out while the block runs: plot_overview costs about 2 CPU-s a session
    (and matplotlib's import where nothing else draws), more than generating a small session's
    trials. For tests that use a session's trials or test its staging, never the figure;
    test_synthetic.py's module session still draws it."""
    from coartic.synthetic_cli import load_generator

    gen = load_generator()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(gen, "plot_overview", lambda *args, **kwargs: None)
        yield gen


@pytest.fixture(autouse=True, scope="session")
def single_start_fits() -> Any:
    """Fits in the tests start once from ``[parameters.start]`` (``[fit] starts = 1``, the old
    behaviour) unless a spec sets ``[fit] starts`` or the test is marked ``multistart``: the
    default 32 starts would make every fit test several times slower without testing anything
    more. Session-wide, so module-scoped fixtures that fit see it too; the multi-start itself is
    tested in test_fit_multistart.py. (Fits in other processes, e.g. dask workers, do not see it:
    their specs set ``[fit] starts``.)"""
    import coartic.fit.spec

    default = coartic.fit.spec.DEFAULT_STARTS
    coartic.fit.spec.DEFAULT_STARTS = 1
    yield default
    coartic.fit.spec.DEFAULT_STARTS = default


@pytest.fixture(autouse=True, scope="session")
def one_blas_thread() -> Any:
    """BLAS at one thread for the whole session, as `coartic fit` runs it (coartic.fit.runner limits
    it around every channel's fit, docs/FITTING.md). Tests that call the engines, the multi-start or
    the pooling's evidence directly ran their small dense solves (SVDs of a few hundred rows by 60) on
    a multi-threaded OpenBLAS, whose threads spin on cores the other xdist worker and the Rust core
    need: test_multistart_is_deterministic's two capped searches took 36 CPU-s under load, 0.9 at
    one thread (test_fit_multistart.py 96 -> 43 CPU-s; bench/results/test_suite_cpu_fit2.txt). The
    tests compute what they computed; only the BLAS thread count is the one the fits use anyway."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture(autouse=True)
def multistart_default(request: pytest.FixtureRequest, single_start_fits: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A test marked ``multistart`` sees the real default ``[fit] starts``."""
    if request.node.get_closest_marker("multistart") is not None:
        import coartic.fit.spec

        monkeypatch.setattr(coartic.fit.spec, "DEFAULT_STARTS", single_start_fits)


def pytest_configure(config: pytest.Config) -> None:
    """Under xdist the controller rewrites the asserts of every test module once and caches the result where
    pytest looks for it (__pycache__/*-pytest-*.pyc, checked against the source's hash), before it starts the
    workers: each worker imports every module to collect, and rewriting them all cost 4.7 CPU-s a process
    against 0.4 for compiling them (bench/results/test_suite_cpu_core3.txt); the workers then load the cached
    code, as every later run does. Nothing is written where bytecode must not be (PYTHONDONTWRITEBYTECODE,
    which make test-python clears) or asserts are not rewritten (--assert=plain).

    And the files are handed out in the order pytest_collection_modifyitems gives (LONGEST_FIRST below):
    xdist (3.6 on) otherwise hands out the files with the most tests first (``--loadscope-reorder``, its
    default), which undid that order: the calibration file (3 tests, 83 s of the session's 248 on a
    quiet machine) started 151 s in, and one worker ran 33 s after the other had finished."""
    if not hasattr(config, "workerinput") and hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False
    if (hasattr(config, "workerinput") or not config.getoption("numprocesses", None) or sys.dont_write_bytecode
            or config.getoption("assertmode") != "rewrite"):
        return
    from _pytest.assertion import rewrite  # pytest's own cache format (pinned in constraints.txt)

    state = config.stash[rewrite.assertstate_key]
    for source in sorted(Path(__file__).parent.glob("test_*.py")):
        pyc = rewrite.get_cache_dir(source) / (source.name[:-3] + rewrite.PYC_TAIL)
        if rewrite._read_pyc(source, pyc) is None and rewrite.try_makedirs(pyc.parent):
            source_hash, code = rewrite._rewrite_test(source, config)
            rewrite._write_pyc(state, code, source_hash, pyc)


# The files whose tests take longest, longest first (seconds of each file's tests in a whole run on a quiet
# 2-core machine, 12-02: 90, 36, 24, 23, 21, 20, 18, 18, 18 s of the session's 452; the next is 12.5 s;
# docs/ARCHITECTURE.md, Tests). `make test-python` hands whole files to the two
# workers (`--dist loadfile`, so a module's fixtures are built once) in collection order, each
# worker taking the next file when it is nearly done: the longest files first, then every other
# file holding a test marked `slow`, then the rest, so that no long file starts last and leaves one
# worker idle at the end. Only the order changes: every test still runs.
LONGEST_FIRST = ("test_mcmc_calibration.py", "test_fit_multistart.py", "test_batch.py", "test_fit_run.py",
                 "test_batch_cluster.py", "test_perceive_browser.py", "test_mcmc_cli.py", "test_emotions_compare.py",
                 "test_view.py")


# make test runs the core's test files (the Makefile's CORE_TESTS) on the installed core wheel in a fresh
# environment (make core-tests) beside this session and names them in COARTIC_CORE_TESTS: this session leaves
# their tests to that one, but for those marked ``full_env``, which need what only this environment has (the
# extras, the checkout) and are skipped there. Run without it (make test-python, pytest), every test runs here.
CORE_TESTS = frozenset(Path(p).name for p in os.environ.get("COARTIC_CORE_TESTS", "").split())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    in_core_env = [i for i in items if i.path.name in CORE_TESTS and i.get_closest_marker("full_env") is None]
    if in_core_env:
        config.hook.pytest_deselected(items=in_core_env)
        left_out = set(in_core_env)
        items[:] = [i for i in items if i not in left_out]
    slow_files = {item.path.name for item in items if item.get_closest_marker("slow") is not None}

    def rank(item: pytest.Item) -> tuple[int, int]:
        name = item.path.name
        if name in LONGEST_FIRST:
            return 0, LONGEST_FIRST.index(name)
        return (1 if name in slow_files else 2), 0

    items.sort(key=rank)  # stable: the order inside a file, and among files of one rank, is kept
