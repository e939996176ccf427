//! One model over a corpus: `ModelOptions`, the trajectories, the Jacobian, the SSE gradient and
//! the benchmark's yardstick; the parameter matrix and the observations they read.

use std::borrow::Cow;

use numpy::{IntoPyArray, PyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use crate::alloc::try_filled;
use crate::{Dominance, Variant, N_PARAMS};

use super::arrays::{array, as_i64, check_shape, data, out_buffer};
use super::corpus::Corpus;
use super::errors::{model_err, value_error};

/// Variant and per-channel constants that are not fitted per phoneme.
#[pyclass(module = "coartic._core", frozen)]
pub struct ModelOptions {
    pub(super) inner: crate::ModelOptions,
}

#[pymethods]
impl ModelOptions {
    #[new]
    #[pyo3(signature = (variant = "modified", apex_fraction = 0.5, edge_extent = 1.0, *,
                        dominance = "centre", plateau_fraction = 0.5, handover = false))]
    fn new(
        variant: &str,
        apex_fraction: f64,
        edge_extent: f64,
        dominance: &str,
        plateau_fraction: f64,
        handover: bool,
    ) -> PyResult<Self> {
        let variant: Variant = variant
            .parse()
            .map_err(|e: crate::params::UnknownVariant| value_error(format!("variant: {e}")))?;
        let dominance: Dominance = dominance
            .parse()
            .map_err(|e: crate::params::UnknownDominance| value_error(format!("dominance: {e}")))?;
        let inner = crate::ModelOptions {
            variant,
            apex_fraction,
            edge_extent,
            dominance,
            plateau_fraction,
            handover,
        };
        inner.validate().map_err(model_err)?;
        Ok(ModelOptions { inner })
    }

    #[getter]
    fn variant(&self) -> &'static str {
        self.inner.variant.name()
    }
    #[getter]
    fn apex_fraction(&self) -> f64 {
        self.inner.apex_fraction
    }
    #[getter]
    fn edge_extent(&self) -> f64 {
        self.inner.edge_extent
    }
    #[getter]
    fn dominance(&self) -> &'static str {
        self.inner.dominance.name()
    }
    #[getter]
    fn plateau_fraction(&self) -> f64 {
        self.inner.plateau_fraction
    }
    #[getter]
    fn handover(&self) -> bool {
        self.inner.handover
    }

    fn __repr__(&self) -> String {
        let o = &self.inner;
        let mut s = format!(
            "ModelOptions(variant={:?}, apex_fraction={:?}, edge_extent={:?}",
            o.variant.name(),
            o.apex_fraction,
            o.edge_extent
        );
        // The rate-aware options only when they differ from the default (today's model).
        if o.dominance != Dominance::Centre {
            s += &format!(
                ", dominance={:?}, plateau_fraction={:?}",
                o.dominance.name(),
                o.plateau_fraction
            );
        }
        if o.handover {
            s += ", handover=True";
        }
        s + ")"
    }
}

/// The [n_phonemes, 10] parameter matrix of one model.
pub(super) fn params_of<'py>(
    obj: &Bound<'py, PyAny>,
    corpus: &Corpus,
) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    let a = array::<f64>(obj, "params", "float64")?;
    check_shape(
        &a,
        "params",
        &[Some(corpus.inner.n_phonemes()), Some(N_PARAMS)],
        "[n_phonemes of the corpus, 10 parameters]",
    )?;
    Ok(a)
}

/// (observed, weights) as slices.
pub(super) type ObservedWeights<'a> = (Cow<'a, [f64]>, Cow<'a, [f64]>);

/// observed and weights, one per sample of the corpus: the data of the SSE and the batches,
/// checked and read once here.
pub(super) struct Observations<'py> {
    pub(super) observed: PyReadonlyArrayDyn<'py, f64>,
    pub(super) weights: PyReadonlyArrayDyn<'py, f64>,
}

impl<'py> Observations<'py> {
    pub(super) fn of(
        observed: &Bound<'py, PyAny>,
        weights: &Bound<'py, PyAny>,
        corpus: &Corpus,
    ) -> PyResult<Self> {
        let one = |obj: &Bound<'py, PyAny>, name: &str| -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
            let a = array::<f64>(obj, name, "float64")?;
            check_shape(
                &a,
                name,
                &[Some(corpus.inner.n_samples())],
                "[n_samples of the corpus]",
            )?;
            Ok(a)
        };
        Ok(Observations {
            observed: one(observed, "observed")?,
            weights: one(weights, "weights")?,
        })
    }

    /// (observed, weights) as slices, without a copy when C-contiguous.
    pub(super) fn slices(&self) -> PyResult<ObservedWeights<'_>> {
        Ok((
            data(&self.observed, "observed")?,
            data(&self.weights, "weights")?,
        ))
    }
}

/// The trajectory at every sample of the corpus: ndarray[n_samples].
#[pyfunction]
pub(super) fn evaluate<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    beta: f64,
    options: &ModelOptions,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let p = params_of(params, corpus)?;
    let p = data(&p, "params")?;
    let mut out = vec![0.0; corpus.inner.n_samples()];
    py.detach(|| crate::evaluate(&corpus.inner, &p, beta, &options.inner, &mut out))
        .map_err(model_err)?;
    Ok(out.into_pyarray(py))
}

pub(super) type JacobianTuple<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Values and the CSR Jacobian (n_samples × (n_phonemes·10 + 1), last column β).
#[pyfunction]
pub(super) fn jacobian<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    beta: f64,
    options: &ModelOptions,
) -> PyResult<JacobianTuple<'py>> {
    let p = params_of(params, corpus)?;
    let p = data(&p, "params")?;
    let mut values = vec![0.0; corpus.inner.n_samples()];
    let jac = py
        .detach(|| crate::jacobian(&corpus.inner, &p, beta, &options.inner, &mut values))
        .map_err(model_err)?;
    Ok((
        values.into_pyarray(py),
        as_i64(jac.indptr).into_pyarray(py),
        as_i64(jac.indices).into_pyarray(py),
        jac.data.into_pyarray(py),
    ))
}

/// Values and the Jacobian's entries only (the pattern is `Corpus.jacobian_pattern()`), written
/// into `values_out` [n_samples] and `data_out` [jacobian_nnz] when given (nothing allocated: a
/// fitting loop reuses them) or into new arrays. Returns the two arrays filled (the very objects
/// passed). On error the buffers hold partial results.
#[pyfunction]
#[pyo3(signature = (corpus, params, beta, options, values_out = None, data_out = None))]
pub(super) fn jacobian_values<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    beta: f64,
    options: &ModelOptions,
    values_out: Option<Bound<'py, PyAny>>,
    data_out: Option<Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let (n, nnz) = (corpus.inner.n_samples(), corpus.inner.jacobian_nnz());
    // New arrays through Rust's fallible allocation (NumPy's own failure would surface as a
    // panic in rust-numpy).
    let fresh = |len: usize| -> PyResult<Bound<'py, PyAny>> {
        let v = try_filled(len, 0.0, || corpus.inner.jacobian_what("values")).map_err(model_err)?;
        Ok(v.into_pyarray(py).into_any())
    };
    let values_out = match values_out {
        Some(v) => v,
        None => fresh(n)?,
    };
    let data_out = match data_out {
        Some(d) => d,
        None => fresh(nnz)?,
    };
    let p = params_of(params, corpus)?;
    let mut v = out_buffer(&values_out, "values_out", n, "[n_samples of the corpus]")?;
    let mut d = out_buffer(&data_out, "data_out", nnz, "[corpus.jacobian_nnz]")?;
    let p = data(&p, "params")?;
    let as_slice = |e| value_error(format!("output buffer: {e}"));
    let (vs, ds) = (
        v.as_slice_mut().map_err(as_slice)?,
        d.as_slice_mut().map_err(as_slice)?,
    );
    py.detach(|| crate::jacobian_values(&corpus.inner, &p, beta, &options.inner, vs, ds))
        .map_err(model_err)?;
    drop((v, d));
    Ok((values_out, data_out))
}

/// (SSE, dSSE/dparams flattened [n_phonemes·10], dSSE/dβ) with SSE = Σ w (y − F)².
#[pyfunction]
pub(super) fn sse_gradient<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    beta: f64,
    options: &ModelOptions,
    observed: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
) -> PyResult<(f64, Bound<'py, PyArray1<f64>>, f64)> {
    let p = params_of(params, corpus)?;
    let p = data(&p, "params")?;
    let obs = Observations::of(observed, weights, corpus)?;
    let (y, w) = obs.slices()?;
    let mut grad = vec![0.0; corpus.inner.n_phonemes() * N_PARAMS];
    let (sse, dbeta) = py
        .detach(|| crate::sse_gradient(&corpus.inner, &p, beta, &options.inner, &y, &w, &mut grad))
        .map_err(model_err)?;
    Ok((sse, grad.into_pyarray(py), dbeta))
}

/// The benchmark's yardstick: a loop of only the exponentials and powers the model needs for this
/// corpus (the physical limit on this machine). Returns a checksum so the loop is not optimised away.
#[pyfunction]
pub(super) fn physical_limit_loop(
    py: Python<'_>,
    corpus: &Corpus,
    params: &Bound<'_, PyAny>,
    options: &ModelOptions,
) -> PyResult<f64> {
    let p = params_of(params, corpus)?;
    let p = data(&p, "params")?;
    Ok(py.detach(|| crate::physical_limit_loop(&corpus.inner, &p, &options.inner)))
}
