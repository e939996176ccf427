//! `Corpus`: many utterances in CSR form, validated once, and its Jacobian pattern.

use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;

use crate::ModelError;

use super::arrays::{as_i64, count, f64_vec, index_vec};
use super::errors::model_err;

/// The Jacobian's CSR (indptr, indices), int64.
pub(super) type Pattern = (Py<PyArray1<i64>>, Py<PyArray1<i64>>);
pub(super) type BoundPattern<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>);

/// Many utterances in CSR form, validated once (docs/ARCHITECTURE.md, "Corpus layout").
#[pyclass(module = "coartic._core", frozen)]
pub struct Corpus {
    pub(super) inner: crate::Corpus,
    /// The Jacobian's (indptr, indices), read-only, built on first request: it depends only on
    /// the corpus, so a fitting loop asks once and refills only the values.
    pub(super) pattern: PyOnceLock<Pattern>,
}

#[pymethods]
impl Corpus {
    #[new]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        seg_offsets: &Bound<'_, PyAny>,
        seg_phoneme: &Bound<'_, PyAny>,
        seg_start: &Bound<'_, PyAny>,
        seg_end: &Bound<'_, PyAny>,
        sample_offsets: &Bound<'_, PyAny>,
        sample_times: &Bound<'_, PyAny>,
        n_phonemes: i64,
    ) -> PyResult<Self> {
        let n_phonemes = count(n_phonemes, "n_phonemes")?;
        let seg_offsets = index_vec(seg_offsets, "seg_offsets")?;
        let seg_phoneme = index_vec(seg_phoneme, "seg_phoneme")?;
        let seg_start = f64_vec(seg_start, "seg_start", None, "one start time per segment")?;
        let seg_end = f64_vec(seg_end, "seg_end", None, "one end time per segment")?;
        let sample_offsets = index_vec(sample_offsets, "sample_offsets")?;
        let sample_times = f64_vec(sample_times, "sample_times", None, "one time per sample")?;
        let inner = py
            .detach(|| {
                crate::Corpus::new(
                    seg_offsets,
                    seg_phoneme,
                    seg_start,
                    seg_end,
                    sample_offsets,
                    sample_times,
                    n_phonemes,
                )
            })
            .map_err(model_err)?;
        Ok(Corpus {
            inner,
            pattern: PyOnceLock::new(),
        })
    }

    /// Number of stored Jacobian entries (the length of `data_out` of `jacobian_values`).
    #[getter]
    fn jacobian_nnz(&self) -> usize {
        self.inner.jacobian_nnz()
    }

    /// The Jacobian's sparsity pattern (indptr, indices), equal to those `jacobian` returns.
    /// Built once per corpus and returned read-only, the same arrays on every call.
    fn jacobian_pattern<'py>(&self, py: Python<'py>) -> PyResult<BoundPattern<'py>> {
        let (indptr, indices) = self.pattern.get_or_try_init(py, || -> PyResult<_> {
            let (indptr, indices) = py
                .detach(|| -> Result<_, ModelError> {
                    Ok((
                        as_i64(self.inner.jacobian_indptr().to_vec()),
                        as_i64(self.inner.jacobian_indices()?),
                    ))
                })
                .map_err(model_err)?;
            let frozen = |v: Vec<i64>| -> PyResult<Py<PyArray1<i64>>> {
                let a = v.into_pyarray(py);
                // Shared by every caller: nobody may edit it under another's CSR matrix.
                a.getattr("flags")?.setattr("writeable", false)?;
                Ok(a.unbind())
            };
            Ok((frozen(indptr)?, frozen(indices)?))
        })?;
        Ok((indptr.bind(py).clone(), indices.bind(py).clone()))
    }

    #[getter]
    fn n_utterances(&self) -> usize {
        self.inner.n_utterances()
    }
    #[getter]
    fn n_samples(&self) -> usize {
        self.inner.n_samples()
    }
    #[getter]
    fn n_segments(&self) -> usize {
        self.inner.n_segments()
    }
    #[getter]
    fn n_phonemes(&self) -> usize {
        self.inner.n_phonemes()
    }

    fn __repr__(&self) -> String {
        format!(
            "Corpus(n_utterances={}, n_segments={}, n_samples={}, n_phonemes={})",
            self.inner.n_utterances(),
            self.inner.n_segments(),
            self.inner.n_samples(),
            self.inner.n_phonemes()
        )
    }
}
