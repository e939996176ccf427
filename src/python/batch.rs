//! Walker batches (MCMC): the trajectories, SSE and per-utterance residual sums of W parameter
//! sets at once.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::alloc::{product, try_filled};
use crate::N_PARAMS;

use super::arrays::{array, check_shape, data};
use super::corpus::Corpus;
use super::errors::{model_err, value_error};
use super::model::{ModelOptions, Observations};

/// A zeroed W × n output of a batch, allocated fallibly (the sizes named when it does not fit).
pub(super) fn batch_output(n_walkers: usize, n: usize, of: &str) -> PyResult<Vec<f64>> {
    let what = || crate::corpus::batch_what(n_walkers, n, of);
    let len = product::<f64>(n_walkers, n, what).map_err(model_err)?;
    try_filled(len, 0.0, what).map_err(model_err)
}

/// params[W, n_phonemes, 10] and betas[W] of W walkers.
pub(super) fn batch_of<'py>(
    params: &Bound<'py, PyAny>,
    betas: &Bound<'py, PyAny>,
    corpus: &Corpus,
) -> PyResult<(
    PyReadonlyArrayDyn<'py, f64>,
    PyReadonlyArrayDyn<'py, f64>,
    usize,
)> {
    let p = array::<f64>(params, "params", "float64")?;
    check_shape(
        &p,
        "params",
        &[None, Some(corpus.inner.n_phonemes()), Some(N_PARAMS)],
        "[walkers, n_phonemes of the corpus, 10 parameters]",
    )?;
    let n_walkers = p.shape()[0];
    let b = array::<f64>(betas, "betas", "float64")?;
    check_shape(
        &b,
        "betas",
        &[Some(n_walkers)],
        "one beta per walker (params.shape[0])",
    )?;
    Ok((p, b, n_walkers))
}

/// The trajectories of W parameter sets: ndarray[W, n_samples].
#[pyfunction]
pub(super) fn evaluate_batch<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    betas: &Bound<'py, PyAny>,
    options: &ModelOptions,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (p, b, n_walkers) = batch_of(params, betas, corpus)?;
    let (p, b) = (data(&p, "params")?, data(&b, "betas")?);
    let n = corpus.inner.n_samples();
    let mut out = batch_output(n_walkers, n, "samples")?;
    py.detach(|| crate::evaluate_batch(&corpus.inner, &p, &b, &options.inner, &mut out))
        .map_err(model_err)?;
    let out =
        Array2::from_shape_vec((n_walkers, n), out).map_err(|e| value_error(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// The SSE of W parameter sets: ndarray[W]; an invalid walker gets +inf.
#[pyfunction]
pub(super) fn sse_batch<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    betas: &Bound<'py, PyAny>,
    options: &ModelOptions,
    observed: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let (p, b, n_walkers) = batch_of(params, betas, corpus)?;
    let (p, b) = (data(&p, "params")?, data(&b, "betas")?);
    let obs = Observations::of(observed, weights, corpus)?;
    let (y, w) = obs.slices()?;
    let mut out = vec![0.0; n_walkers];
    py.detach(|| crate::sse_batch(&corpus.inner, &p, &b, &options.inner, &y, &w, &mut out))
        .map_err(model_err)?;
    Ok(out.into_pyarray(py))
}

/// (SSE per walker, residual sums per walker and utterance).
type SseAndSums<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>);

/// The SSE and each utterance's weighted residual sum Σ w (y − F) of W parameter sets:
/// (ndarray[W], ndarray[W, n_utterances]); an invalid walker gets +inf and NaN sums.
#[pyfunction]
pub(super) fn residual_sums_batch<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    betas: &Bound<'py, PyAny>,
    options: &ModelOptions,
    observed: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
) -> PyResult<SseAndSums<'py>> {
    let (p, b, n_walkers) = batch_of(params, betas, corpus)?;
    let (p, b) = (data(&p, "params")?, data(&b, "betas")?);
    let obs = Observations::of(observed, weights, corpus)?;
    let (y, w) = obs.slices()?;
    let nu = corpus.inner.n_utterances();
    let mut sums = batch_output(n_walkers, nu, "utterances")?;
    let mut sse = vec![0.0; n_walkers];
    py.detach(|| {
        crate::residual_sums_batch(
            &corpus.inner,
            &p,
            &b,
            &options.inner,
            &y,
            &w,
            &mut sse,
            &mut sums,
        )
    })
    .map_err(model_err)?;
    let sums =
        Array2::from_shape_vec((n_walkers, nu), sums).map_err(|e| value_error(e.to_string()))?;
    Ok((sse.into_pyarray(py), sums.into_pyarray(py)))
}
