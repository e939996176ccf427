"""Bad input to coartic._core: a clear Python exception naming the culprit, never a panic."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from conftest import random_params

from coartic import _core


def vcv() -> dict[str, Any]:
    return {
        "seg_offsets": np.array([0, 5], dtype=np.int64),
        "seg_phoneme": np.array([2, 0, 1, 0, 2], dtype=np.int64),
        "seg_start": np.array([0.0, 0.1, 0.25, 0.33, 0.5]),
        "seg_end": np.array([0.1, 0.25, 0.33, 0.5, 0.6]),
        "sample_offsets": np.array([0, 60], dtype=np.int64),
        "sample_times": np.arange(60) / 100.0,
        "n_phonemes": 3,
    }


def with_(**changes: Any) -> dict[str, Any]:
    a = vcv()
    a.update(changes)
    return a


@pytest.fixture
def corpus() -> _core.Corpus:
    return _core.Corpus(**vcv())


@pytest.fixture
def params() -> np.ndarray:
    return random_params(np.random.default_rng(0), 3)


OPTS = _core.ModelOptions()


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"seg_start": np.array([0.0, 0.1, 0.25, 0.33])}, r"seg_start.*length 4, expected 5"),
        ({"sample_offsets": np.array([0, 61], dtype=np.int64)}, r"sample_offsets"),
        ({"seg_offsets": np.array([0, 4], dtype=np.int64)}, r"seg_offsets"),
        ({"seg_start": np.array([0.0, 0.1, 0.34, 0.33, 0.5])}, r"utterance 1, segment 3 \(counted from 1; seg_start\[2\]\): end 0.33 is not after start 0.34"),
        ({"seg_start": np.array([0.0, 0.1, 0.2, 0.33, 0.5])}, r"utterance 1, segment 3 \(counted from 1; seg_start\[2\]\): starts at 0.2, before the previous segment ends"),
        ({"seg_phoneme": np.array([2, 0, 3, 0, 2], dtype=np.int64)}, r"utterance 1, segment 3 \(counted from 1; seg_phoneme\[2\]\): phoneme index 3 is not below n_phonemes = 3"),
        ({"seg_phoneme": np.array([2, 0, -1, 0, 2], dtype=np.int64)}, r"seg_phoneme\[2\] = -1 is negative"),
        ({"sample_times": np.where(np.arange(60) == 7, np.nan, np.arange(60) / 100.0)}, r"sample_times\[7\].*not finite"),
    ],
)
def test_bad_corpus_is_a_value_error_naming_the_culprit(changes: dict[str, Any], pattern: str) -> None:
    with pytest.raises(ValueError, match=pattern):
        _core.Corpus(**with_(**changes))


@pytest.mark.parametrize(
    ("name", "value", "exc", "pattern"),
    [
        ("seg_start", [0.0, 0.1, 0.25, 0.33, 0.5], TypeError, r"'seg_start' must be a numpy.ndarray of dtype float64, got list"),
        ("seg_start", np.array([0.0, 0.1, 0.25, 0.33, 0.5], dtype=np.float32), TypeError, r"'seg_start'.*dtype float32"),
        ("seg_phoneme", np.array([2, 0, 1, 0, 2], dtype=np.int32), TypeError, r"'seg_phoneme'.*int64.*int32"),
        ("seg_end", np.zeros((5, 1)), ValueError, r"'seg_end' has shape \(5, 1\), expected \(\*,\)"),
    ],
)
def test_wrong_type_dtype_or_shape_names_the_argument(name: str, value: Any, exc: type[Exception], pattern: str) -> None:
    with pytest.raises(exc, match=pattern):
        _core.Corpus(**with_(**{name: value}))


@pytest.mark.parametrize(
    ("row", "col", "value", "pattern"),
    [
        (1, 1, np.nan, r"phoneme 1, parameter alpha: value NaN is not finite"),
        (0, 0, np.inf, r"phoneme 0, parameter target.*not finite"),
        (2, 6, 1.5, r"phoneme 2, parameter k_r: value 1.5 is outside its domain \[0, 1\]"),
        (1, 2, 0.0, r"phoneme 1, parameter theta_bw.*> 0"),
    ],
)
def test_bad_parameters_are_value_errors(corpus: _core.Corpus, params: np.ndarray, row: int, col: int, value: float, pattern: str) -> None:
    params[row, col] = value
    for call in (
        lambda: _core.evaluate(corpus, params, 1.0, OPTS),
        lambda: _core.jacobian(corpus, params, 1.0, OPTS),
        lambda: _core.sse_gradient(corpus, params, 1.0, OPTS, np.zeros(60), np.ones(60)),
    ):
        with pytest.raises(ValueError, match=pattern):
            call()


def test_negative_counts_and_indices_name_the_argument() -> None:
    with pytest.raises(ValueError, match=r"argument 'n_phonemes' = -1 must be >= 0"):
        _core.Corpus(**with_(n_phonemes=-1))
    with pytest.raises(ValueError, match=r"argument 'ear_l' = -2 must be >= 0"):
        _core.head_frame(np.zeros((2, 3, 3)), 0, -2, 1)


def test_empty_input_gives_empty_output(params: np.ndarray) -> None:
    empty = _core.Corpus(np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0),
                         np.zeros(1, dtype=np.int64), np.zeros(0), 3)
    assert _core.evaluate(empty, params, 1.0, OPTS).shape == (0,)
    assert _core.evaluate_batch(empty, np.stack([params] * 2), np.ones(2), OPTS).shape == (2, 0)
    assert _core.marker_channels(np.zeros((0, 8, 3)), np.zeros(0, dtype=bool)).shape == (0, 7)


def test_bad_globals_and_options(corpus: _core.Corpus, params: np.ndarray) -> None:
    with pytest.raises(ValueError, match=r"beta = -1 is invalid"):
        _core.evaluate(corpus, params, -1.0, OPTS)
    with pytest.raises(ValueError, match=r"unknown model variant \"modifed\""):
        _core.ModelOptions("modifed")
    with pytest.raises(ValueError, match=r"apex_fraction = 1.5"):
        _core.ModelOptions("modified", 1.5)
    with pytest.raises(ValueError, match=r"edge_extent = 0"):
        _core.ModelOptions("modified", 0.5, 0.0)


def test_shapes_of_params_and_samples(corpus: _core.Corpus, params: np.ndarray) -> None:
    with pytest.raises(ValueError, match=r"'params' has shape \(2, 10\), expected \(3, 10\)"):
        _core.evaluate(corpus, params[:2], 1.0, OPTS)
    with pytest.raises(ValueError, match=r"'params' has shape \(30,\)"):
        _core.evaluate(corpus, params.ravel(), 1.0, OPTS)
    with pytest.raises(TypeError, match=r"'params'.*dtype float64, got an array of dtype int64"):
        _core.evaluate(corpus, params.astype(np.int64), 1.0, OPTS)
    with pytest.raises(ValueError, match=r"'observed' has shape \(59,\), expected \(60,\)"):
        _core.sse_gradient(corpus, params, 1.0, OPTS, np.zeros(59), np.ones(59))
    with pytest.raises(ValueError, match=r"'betas' has shape \(3,\), expected \(2,\)"):
        _core.evaluate_batch(corpus, np.stack([params, params]), np.ones(3), OPTS)
    with pytest.raises(ValueError, match=r"observed\[4\] = NaN is not finite but its weight is 1"):
        y = np.zeros(60)
        y[4] = np.nan
        _core.sse_gradient(corpus, params, 1.0, OPTS, y, np.ones(60))
    with pytest.raises(ValueError, match=r"weights\[3\] = -1 is invalid"):
        w = np.ones(60)
        w[3] = -1.0
        _core.sse_gradient(corpus, params, 1.0, OPTS, np.zeros(60), w)
    with pytest.raises(TypeError):
        _core.evaluate("corpus", params, 1.0, OPTS)  # type: ignore[arg-type]


def test_read_only_input_is_accepted(corpus: _core.Corpus, params: np.ndarray) -> None:
    want = _core.evaluate(corpus, params, 1.0, OPTS)
    params.setflags(write=False)
    assert np.array_equal(_core.evaluate(corpus, params, 1.0, OPTS), want)


def test_errors_are_coartic_errors_with_the_place_as_attributes(corpus: _core.Corpus, params: np.ndarray) -> None:
    from coartic.errors import CoarticError

    assert issubclass(_core.CoarticError, CoarticError) and issubclass(_core.CoarticError, ValueError)
    with pytest.raises(_core.CoarticError) as bad_segment:
        _core.Corpus(**with_(seg_start=np.array([0.0, 0.1, 0.34, 0.33, 0.5])))
    e = bad_segment.value
    # Indices from 0 in the attributes, counted from 1 in the message ("utterance 1, segment 3").
    assert (e.utterance, e.segment, e.value, e.reason) == (0, 2, 0.33, "end is not after start")
    assert (e.phoneme, e.parameter, e.sample, e.walker) == (None, None, None, None)

    params[2, 6] = 1.5
    with pytest.raises(CoarticError) as bad_param:
        _core.jacobian(corpus, params, 1.0, OPTS)
    e = bad_param.value
    assert (e.phoneme, e.parameter, e.value, e.reason) == (2, "k_r", 1.5, "is outside its domain [0, 1]")
    assert (e.utterance, e.segment, e.sample, e.walker) == (None, None, None, None)

    batch = np.stack([random_params(np.random.default_rng(1), 3)] * 3)
    batch[1, 0, 1] = np.nan
    with pytest.raises(_core.CoarticError, match=r"walker 1: phoneme 0, parameter alpha: value NaN is not finite") as walker:
        _core.evaluate_batch(corpus, batch, np.ones(3), OPTS)
    assert (walker.value.walker, walker.value.phoneme, walker.value.parameter) == (1, 0, "alpha")

    w = np.ones(60)
    w[3] = -1.0
    with pytest.raises(ValueError) as bad_weight:
        _core.sse_gradient(corpus, random_params(np.random.default_rng(0), 3), 1.0, OPTS, np.zeros(60), w)
    assert (bad_weight.value.sample, bad_weight.value.value) == (3, -1.0)  # type: ignore[attr-defined]

    # The binding's own argument checks are CoarticErrors too (no attributes but the message).
    with pytest.raises(_core.CoarticError, match=r"'params' has shape \(2, 10\)") as shape:
        _core.evaluate(corpus, params[:2], 1.0, OPTS)
    assert shape.value.utterance is None and shape.value.reason is None


def test_degenerate_sample_is_named_by_utterance_and_sample() -> None:
    # theta * |tau|^c overflows to inf for every segment at the sample 1e200 s away.
    c = _core.Corpus(np.array([0, 1, 2]), np.array([0, 0]), np.array([0.0, 0.0]), np.array([1.0, 1.0]),
                     np.array([0, 1, 3]), np.array([0.5, 0.5, 1e200]), 1)
    p = random_params(np.random.default_rng(0), 1)
    with pytest.raises(_core.CoarticError, match=r"utterance 2 \(counted from 1\), sample_times\[2\]: every segment has zero weight") as e:
        _core.evaluate(c, p, 1.0, _core.ModelOptions("original"))
    assert (e.value.utterance, e.value.sample) == (1, 2)


def test_every_error_class_of_the_package_has_the_one_base() -> None:
    """Every exception class defined under python/coartic subclasses coartic.errors.CoarticError."""
    import ast
    import importlib
    from pathlib import Path

    from coartic.errors import CoarticError

    root = Path(__file__).resolve().parents[2] / "python"
    # scripts that run in another program's Python, where coartic is not importable: Blender's
    standalone = {"coartic.runtime.blender_keys"}
    found = []
    for path in sorted((root / "coartic").rglob("*.py")):
        module = ".".join(path.relative_to(root).with_suffix("").parts)
        if module in standalone:
            imports = [n for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                       if isinstance(n, (ast.Import, ast.ImportFrom))]
            assert not any("coartic" in ast.unparse(n) for n in imports), module  # still standalone
            continue
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            bases = [b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in getattr(node, "bases", [])]
            if isinstance(node, ast.ClassDef) and any(b.endswith(("Error", "Exception")) for b in bases):
                cls = getattr(importlib.import_module(module), node.name)
                if isinstance(cls, type) and issubclass(cls, BaseException) and cls is not CoarticError:
                    found.append(cls)
                    assert issubclass(cls, CoarticError), f"{module}.{node.name} does not subclass CoarticError"
    assert len(found) >= 10
