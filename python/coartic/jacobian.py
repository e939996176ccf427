"""The model's Jacobian as a ``scipy.sparse.csr_matrix``: what least-squares fitting uses.

Apart from ``coartic.model`` so that evaluating the model (the runtime: ``animate``, ``speak``)
never imports SciPy; this module uses ``coartic.model``, never the reverse.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from coartic import _core
from coartic.io.labelmap import LabelMap
from coartic.model import F64, utterance_channels
from coartic.table import N_PARAMS, ParameterTable


class JacobianBuffer:
    """The Jacobian of one corpus as a ``scipy.sparse.csr_matrix``, refilled in place.

    The sparsity pattern depends only on the corpus, so it is built once here; every
    ``compute`` writes the values and the Jacobian's entries into the same arrays
    (``_core.jacobian_values``), allocating nothing: an optimiser's loop then costs about two
    evaluations per Jacobian instead of allocating tens of MB each time.

    ``compute`` returns ``(values, matrix)``: the buffer's own arrays, overwritten by the next
    ``compute`` (copy them to keep them). Treat ``matrix`` as read-only; operations that change
    its structure in place (``eliminate_zeros``, ``sum_duplicates``) would detach its data from
    the buffer.

    Examples
    --------
    >>> buf = JacobianBuffer(corpus)
    >>> for params, beta in steps:                      # doctest: +SKIP
    ...     values, jac = buf.compute(params, beta, options)
    """

    def __init__(self, corpus: _core.Corpus) -> None:
        self.corpus = corpus
        indptr, indices = corpus.jacobian_pattern()
        self.values: F64 = np.empty(corpus.n_samples)
        self.data: F64 = np.empty(corpus.jacobian_nnz)
        shape = (corpus.n_samples, corpus.n_phonemes * N_PARAMS + 1)
        self.matrix = sp.csr_matrix((self.data, indices, indptr), shape=shape)
        # SciPy may keep a view or a copy of the data; the buffer must be the matrix's storage.
        self.matrix.data = self.data

    def compute(self, params: F64, beta: float, options: _core.ModelOptions) -> tuple[F64, sp.csr_matrix]:
        """Values F [n_samples] and the Jacobian (n_samples, n_phonemes*10 + 1) at ``params``
        [n_phonemes, 10] and ``beta``; the core's ValueError if they are invalid (the buffer then
        holds partial results)."""
        _core.jacobian_values(self.corpus, params, beta, options, self.values, self.data)
        return self.values, self.matrix


def trajectory_jacobians(
    table: ParameterTable,
    labels: Sequence[str],
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    times: npt.ArrayLike,
    channels: Sequence[str] | None = None,
    *,
    label_map: LabelMap | Mapping[str, str] | str | None = None,
) -> dict[str, tuple[F64, sp.csr_matrix]]:
    """``channel -> (values, J)``: ``coartic.model.trajectories`` (same arguments and errors) with
    each channel's Jacobian, a ``scipy.sparse.csr_matrix`` of shape ``(len(times), 10 * n + 1)``:
    column ``10 k + j`` is ∂F/∂(parameter j of phoneme k), phonemes ordered as
    ``table.phonemes_for(channel)`` (``coartic.model.jacobian_columns`` names them), and the last
    column ∂F/∂β."""
    out: dict[str, tuple[F64, sp.csr_matrix]] = {}
    for problem in utterance_channels(table, labels, starts, ends, times, channels, label_map=label_map):
        try:
            out[problem.channel] = JacobianBuffer(problem.corpus).compute(problem.params, problem.beta,
                                                                           problem.options)
        except ValueError as err:
            raise problem.error(err) from None
    return out
