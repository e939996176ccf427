"""Typed stubs of the Rust extension ``coartic._core`` (checked by ``mypy.stubtest``).

Arrays are NumPy float64 (int64 for indices, bool for masks); C-contiguous input is read in
place, other layouts are copied once. Wrong type or dtype raises TypeError, wrong shape or any
invalid value raises ``CoarticError`` (a ValueError) naming the argument, utterance, segment,
phoneme or parameter, with those as attributes. A buffer whose size is a product of input sizes
(a Jacobian, a batch of walkers) or a copy of a non-contiguous input that does not fit in memory
raises MemoryError naming the sizes.
"""

from typing import Final, final

import numpy as np
import numpy.typing as npt

from coartic.errors import CoarticError as _PackageError

__all__ = [
    "CHANNEL_NAMES",
    "CoarticError",
    "Corpus",
    "MARKER_NAMES",
    "ModelOptions",
    "N_PARAMS",
    "evaluate",
    "evaluate_batch",
    "head_frame",
    "jacobian",
    "jacobian_values",
    "marker_channels",
    "physical_limit_loop",
    "residual_sums_batch",
    "sse_batch",
    "sse_gradient",
]

N_PARAMS: Final[int]
MARKER_NAMES: Final[list[str]]
CHANNEL_NAMES: Final[list[str]]

class CoarticError(_PackageError, ValueError):
    """Invalid input to the model core. The message names the place at fault (utterances and
    segments counted from 1); the attributes give it as indices counted from 0: ``utterance``,
    ``segment`` (within its utterance), ``phoneme`` (row of the parameter matrix, an int),
    ``parameter`` (name, or a global such as ``"beta"``), ``value``, ``sample``, ``walker``, and
    ``reason`` (what is wrong); ``None`` where they do not apply."""

@final
class Corpus:
    """Many utterances in CSR form (docs/ARCHITECTURE.md, "Corpus layout"), validated once."""

    def __new__(
        cls,
        seg_offsets: npt.NDArray[np.int64],
        seg_phoneme: npt.NDArray[np.int64],
        seg_start: npt.NDArray[np.float64],
        seg_end: npt.NDArray[np.float64],
        sample_offsets: npt.NDArray[np.int64],
        sample_times: npt.NDArray[np.float64],
        n_phonemes: int,
    ) -> Corpus: ...
    @property
    def n_utterances(self) -> int: ...
    @property
    def n_samples(self) -> int: ...
    @property
    def n_segments(self) -> int: ...
    @property
    def n_phonemes(self) -> int: ...
    @property
    def jacobian_nnz(self) -> int:
        """Number of stored Jacobian entries: the length of ``data_out`` of ``jacobian_values``."""
    def jacobian_pattern(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """(indptr, indices) of the CSR Jacobian, equal to those ``jacobian`` returns. Built once
        per corpus; the same read-only arrays on every call."""

@final
class ModelOptions:
    """Variant ("original" or "modified"), apex fraction a and edge extent Λ of one channel, and
    the rate-aware options of MODEL.md §2.1: dominance "centre" (default, today's model) or
    "plateau" (D flat within plateau_fraction h of the segment's duration around its target),
    and handover (the forward side of a segment's dominance takes θ_fw, c_fw of the next
    segment's phoneme)."""

    def __new__(
        cls,
        variant: str = "modified",
        apex_fraction: float = 0.5,
        edge_extent: float = 1.0,
        *,
        dominance: str = "centre",
        plateau_fraction: float = 0.5,
        handover: bool = False,
    ) -> ModelOptions: ...
    @property
    def variant(self) -> str: ...
    @property
    def apex_fraction(self) -> float: ...
    @property
    def edge_extent(self) -> float: ...
    @property
    def dominance(self) -> str: ...
    @property
    def plateau_fraction(self) -> float: ...
    @property
    def handover(self) -> bool: ...

def evaluate(
    corpus: Corpus, params: npt.NDArray[np.float64], beta: float, options: ModelOptions
) -> npt.NDArray[np.float64]:
    """F at every sample: ndarray[n_samples]; params is [n_phonemes, 10]."""

def jacobian(
    corpus: Corpus, params: npt.NDArray[np.float64], beta: float, options: ModelOptions
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """(values, indptr, indices, data): CSR Jacobian of shape (n_samples, n_phonemes*10 + 1)."""

def jacobian_values(
    corpus: Corpus,
    params: npt.NDArray[np.float64],
    beta: float,
    options: ModelOptions,
    values_out: npt.NDArray[np.float64] | None = None,
    data_out: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """(values, data) of the Jacobian whose pattern is ``corpus.jacobian_pattern()``, bit for bit
    those of ``jacobian``. Given buffers (float64, C-contiguous, writeable, aligned, shapes
    [n_samples] and [corpus.jacobian_nnz], no memory shared with params or each other) are filled
    in place and returned as they are: nothing is allocated. On error they hold partial results."""

def sse_gradient(
    corpus: Corpus,
    params: npt.NDArray[np.float64],
    beta: float,
    options: ModelOptions,
    observed: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64],
) -> tuple[float, npt.NDArray[np.float64], float]:
    """(SSE, dSSE/dparams [n_phonemes*10], dSSE/dbeta), SSE = sum w (observed - F)^2."""

def evaluate_batch(
    corpus: Corpus, params: npt.NDArray[np.float64], betas: npt.NDArray[np.float64], options: ModelOptions
) -> npt.NDArray[np.float64]:
    """params [W, n_phonemes, 10], betas [W] -> ndarray[W, n_samples]."""

def sse_batch(
    corpus: Corpus,
    params: npt.NDArray[np.float64],
    betas: npt.NDArray[np.float64],
    options: ModelOptions,
    observed: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """SSE of each of W parameter sets: ndarray[W]; an invalid walker gets +inf."""

def residual_sums_batch(
    corpus: Corpus,
    params: npt.NDArray[np.float64],
    betas: npt.NDArray[np.float64],
    options: ModelOptions,
    observed: npt.NDArray[np.float64],
    weights: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """SSE ndarray[W] and each utterance's sum of w (y - F) ndarray[W, n_utterances]; an invalid
    walker gets +inf and NaN sums."""

def physical_limit_loop(corpus: Corpus, params: npt.NDArray[np.float64], options: ModelOptions) -> float:
    """Only the exponentials and powers the model needs (benchmark yardstick); a checksum."""

def marker_channels(markers: npt.NDArray[np.float64], rest: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """markers [F, 8, 3] (NOSE, EAR_L, EAR_R, UL, LL, LC_L, LC_R, CHIN), rest [F] -> [F, 7]
    (ULO, LLO, ULP, LLP, LR, JO, LA); NaN where a needed marker is missing."""

def head_frame(markers: npt.NDArray[np.float64], nose: int, ear_l: int, ear_r: int) -> npt.NDArray[np.float64]:
    """markers [F, M, 3] expressed in each frame's head frame; NaN where it is undefined."""
