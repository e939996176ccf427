//! `coartic._core`: the thin PyO3 face of the core (docs/ARCHITECTURE.md lists the signatures).
//!
//! Input arrays must be NumPy arrays of the documented dtype (float64, int64 for indices, bool for
//! masks). C-contiguous input is read in place; any other layout (strided, Fortran order,
//! broadcast) is copied once into C order. Outputs are handed to NumPy without a copy. Every
//! computation runs with the GIL released. Invalid input raises TypeError (wrong type or dtype) or
//! `CoarticError` (a ValueError subclass: wrong shape, or any error of the core, whose message names
//! the utterance, segment, phoneme or parameter at fault, with those as attributes); a buffer whose
//! size is a product of input sizes (a Jacobian, a batch) or a copy that does not fit in memory
//! raises MemoryError naming the sizes. Nothing panics or aborts across the boundary.

use std::borrow::Cow;

use numpy::ndarray::{Array2, Array3};
use numpy::{
    BorrowError, Element, IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayDyn, PyArrayMethods,
    PyReadonlyArrayDyn, PyReadwriteArrayDyn, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyMemoryError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyType};

use crate::alloc::{product, try_filled, try_with_capacity};
use crate::error::ErrorFields;
use crate::geometry::{self, GeometryError, N_CHANNELS, N_MARKERS};
use crate::{Dominance, ModelError, Variant, N_PARAMS};

/// `coartic._core.CoarticError`, made at import: a subclass of the package's base
/// `coartic.errors.CoarticError` and of ValueError, so that `except ValueError` and
/// `except coartic.errors.CoarticError` both catch it.
static CORE_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

const CORE_ERROR_DOC: &str = "Invalid input to the model core. The message names the place at \
fault; the attributes utterance, segment (within its utterance), phoneme (row of the parameter \
matrix), parameter, value, sample and walker give it as indices counted from 0 (None where they \
do not apply; messages count utterances and segments from 1), reason says what is wrong.";

fn core_error_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    let ty = CORE_ERROR.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let base = py.import("coartic.errors")?.getattr("CoarticError")?;
        let attrs = PyDict::new(py);
        attrs.set_item("__module__", "coartic._core")?;
        attrs.set_item("__doc__", CORE_ERROR_DOC)?;
        let bases = (base, py.get_type::<PyValueError>());
        let ty = py
            .get_type::<PyType>()
            .call1(("CoarticError", bases, attrs))?;
        Ok(ty.cast_into::<PyType>()?.unbind())
    })?;
    Ok(ty.bind(py))
}

/// A `CoarticError` with `message` and the attributes of `fields`.
fn coartic_error(message: String, fields: Option<ErrorFields>) -> PyErr {
    Python::attach(|py| {
        let make = || -> PyResult<PyErr> {
            let err = core_error_type(py)?.call1((message.clone(),))?;
            if let Some(f) = fields {
                err.setattr("utterance", f.utterance)?;
                err.setattr("segment", f.segment)?;
                err.setattr("phoneme", f.phoneme)?;
                err.setattr("parameter", f.parameter)?;
                err.setattr("value", f.value)?;
                err.setattr("sample", f.sample)?;
                err.setattr("walker", f.walker)?;
                err.setattr("reason", f.reason)?;
            }
            Ok(PyErr::from_value(err))
        };
        // Only if coartic.errors cannot be imported: still an error, still a ValueError.
        make().unwrap_or_else(|_| PyValueError::new_err(message.clone()))
    })
}

/// An invalid argument found by the binding itself (shape, sign): a `CoarticError` too.
fn value_error(message: String) -> PyErr {
    coartic_error(message, None)
}

/// The core's error as `CoarticError` with its fields as attributes, or MemoryError.
fn model_err(e: ModelError) -> PyErr {
    if e.is_out_of_memory() {
        return PyMemoryError::new_err(e.to_string());
    }
    coartic_error(e.to_string(), Some(e.fields()))
}

fn geometry_err(e: GeometryError) -> PyErr {
    value_error(e.to_string())
}

/// Borrow `obj` as a read-only NumPy array of `T`, or raise TypeError naming the argument.
fn array<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    dtype: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<T>>() {
        // A view at an odd byte offset (np.frombuffer(..., offset=1)) must not become a Rust
        // reference: NumPy's copy() gives an aligned one.
        let a = if (a.data() as usize) % std::mem::align_of::<T>() == 0 {
            a.clone()
        } else {
            a.call_method0("copy")?.cast_into::<PyArrayDyn<T>>()?
        };
        return a
            .try_readonly()
            .map_err(|e| value_error(format!("argument '{name}': {e}")));
    }
    Err(PyTypeError::new_err(format!(
        "argument '{name}' must be a numpy.ndarray of dtype {dtype}, got {} \
         (convert with numpy.asarray(..., dtype=numpy.{dtype}))",
        what_is(obj)?
    )))
}

/// What `obj` is, for a TypeError: "an array of dtype float32", "list".
fn what_is(obj: &Bound<'_, PyAny>) -> PyResult<String> {
    Ok(match obj.cast::<PyUntypedArray>() {
        Ok(a) => format!("an array of dtype {}", a.dtype()),
        Err(_) => format!("{}", obj.get_type().name()?),
    })
}

/// A caller's output buffer, filled in place: a writeable, aligned, C-contiguous float64 array of
/// shape (len,) that shares no memory with another argument of the call. Anything else is refused
/// (TypeError for the type or dtype, ValueError otherwise): a silent copy would leave the
/// caller's array unfilled.
fn out_buffer<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    len: usize,
    meaning: &str,
) -> PyResult<PyReadwriteArrayDyn<'py, f64>> {
    let Ok(a) = obj.cast::<PyArrayDyn<f64>>() else {
        return Err(PyTypeError::new_err(format!(
            "argument '{name}' must be a numpy.ndarray of dtype float64 to fill in place, got \
             {}; pass numpy.empty({len})",
            what_is(obj)?
        )));
    };
    shape_ok(name, a.shape(), &[Some(len)], meaning)?;
    let refuse = |why: &str| {
        Err(value_error(format!(
            "argument '{name}' {why}; pass numpy.empty({len}) (float64, C-contiguous, writeable)"
        )))
    };
    if !a.is_c_contiguous() {
        return refuse("is not C-contiguous (a strided view cannot be filled in place)");
    }
    if !a.is_aligned() {
        return refuse("is not aligned to 8 bytes");
    }
    match a.try_readwrite() {
        Ok(rw) => Ok(rw),
        Err(BorrowError::NotWriteable) => refuse("is read-only"),
        Err(_) => refuse(
            "shares memory with another argument of this call (params, values_out, data_out)",
        ),
    }
}

/// Check the shape: `expected[i] = None` accepts any length on axis i.
fn check_shape<T: Element>(
    a: &PyReadonlyArrayDyn<'_, T>,
    name: &str,
    expected: &[Option<usize>],
    meaning: &str,
) -> PyResult<()> {
    shape_ok(name, a.shape(), expected, meaning)
}

/// The shape test of [`check_shape`] on a bare shape.
fn shape_ok(
    name: &str,
    shape: &[usize],
    expected: &[Option<usize>],
    meaning: &str,
) -> PyResult<()> {
    let ok = shape.len() == expected.len()
        && shape
            .iter()
            .zip(expected)
            .all(|(&s, e)| e.is_none_or(|e| e == s));
    if ok {
        return Ok(());
    }
    let got = tuple(shape.iter().map(|s| s.to_string()).collect());
    let want = tuple(
        expected
            .iter()
            .map(|e| e.map_or_else(|| "*".to_string(), |v| v.to_string()))
            .collect(),
    );
    Err(value_error(format!(
        "argument '{name}' has shape {got}, expected {want} = {meaning}"
    )))
}

/// A shape written as NumPy prints it: (5,), (3, 10).
fn tuple(items: Vec<String>) -> String {
    match items.len() {
        1 => format!("({},)", items[0]),
        _ => format!("({})", items.join(", ")),
    }
}

/// The elements of argument `name` in C order: in place if C-contiguous, else one copy, allocated
/// fallibly: a broadcast view (`numpy.broadcast_to`) costs NumPy no memory however large its
/// shape, but its copy does (MemoryError naming the argument and the sizes, not an abort).
fn data<'a, T: Element + Copy>(
    a: &'a PyReadonlyArrayDyn<'_, T>,
    name: &str,
) -> PyResult<Cow<'a, [T]>> {
    if a.is_c_contiguous() {
        if let Ok(s) = a.as_slice() {
            return Ok(Cow::Borrowed(s));
        }
    }
    let view = a.as_array();
    let mut copy = try_with_capacity(view.len(), || {
        let shape = tuple(view.shape().iter().map(|s| s.to_string()).collect());
        format!("a C-ordered copy of argument '{name}' (shape {shape}, not C-contiguous)")
    })
    .map_err(model_err)?;
    copy.extend(view.iter().copied());
    Ok(Cow::Owned(copy))
}

fn f64_vec(
    obj: &Bound<'_, PyAny>,
    name: &str,
    len: Option<usize>,
    meaning: &str,
) -> PyResult<Vec<f64>> {
    let a = array::<f64>(obj, name, "float64")?;
    check_shape(&a, name, &[len], meaning)?;
    Ok(data(&a, name)?.into_owned())
}

/// A non-negative integer argument; a negative one is a ValueError naming it.
fn count(value: i64, name: &str) -> PyResult<usize> {
    usize::try_from(value)
        .map_err(|_| value_error(format!("argument '{name}' = {value} must be >= 0")))
}

fn index_vec(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<usize>> {
    let a = array::<i64>(obj, name, "int64")?;
    check_shape(&a, name, &[None], "one index per entry")?;
    data(&a, name)?
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            usize::try_from(v).map_err(|_| value_error(format!("{name}[{i}] = {v} is negative")))
        })
        .collect()
}

/// The Jacobian's CSR (indptr, indices), int64.
type Pattern = (Py<PyArray1<i64>>, Py<PyArray1<i64>>);
type BoundPattern<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>);

/// Many utterances in CSR form, validated once (docs/ARCHITECTURE.md, "Corpus layout").
#[pyclass(module = "coartic._core", frozen)]
pub struct Corpus {
    inner: crate::Corpus,
    /// The Jacobian's (indptr, indices), read-only, built on first request: it depends only on
    /// the corpus, so a fitting loop asks once and refills only the values.
    pattern: PyOnceLock<Pattern>,
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

/// Variant and per-channel constants that are not fitted per phoneme.
#[pyclass(module = "coartic._core", frozen)]
pub struct ModelOptions {
    inner: crate::ModelOptions,
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
fn params_of<'py>(
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
type ObservedWeights<'a> = (Cow<'a, [f64]>, Cow<'a, [f64]>);

/// observed and weights, one per sample of the corpus: the data of the SSE and the batches,
/// checked and read once here.
struct Observations<'py> {
    observed: PyReadonlyArrayDyn<'py, f64>,
    weights: PyReadonlyArrayDyn<'py, f64>,
}

impl<'py> Observations<'py> {
    fn of(
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
    fn slices(&self) -> PyResult<ObservedWeights<'_>> {
        Ok((
            data(&self.observed, "observed")?,
            data(&self.weights, "weights")?,
        ))
    }
}

/// A zeroed W × n output of a batch, allocated fallibly (the sizes named when it does not fit).
fn batch_output(n_walkers: usize, n: usize, of: &str) -> PyResult<Vec<f64>> {
    let what = || crate::corpus::batch_what(n_walkers, n, of);
    let len = product::<f64>(n_walkers, n, what).map_err(model_err)?;
    try_filled(len, 0.0, what).map_err(model_err)
}

/// The trajectory at every sample of the corpus: ndarray[n_samples].
#[pyfunction]
fn evaluate<'py>(
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

/// SciPy indexes with signed integers. Same size and alignment, so the collect reuses the
/// allocation; an index beyond i64 would need more memory than exists.
fn as_i64(v: Vec<usize>) -> Vec<i64> {
    v.into_iter().map(|x| x as i64).collect()
}

type JacobianTuple<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

/// Values and the CSR Jacobian (n_samples × (n_phonemes·10 + 1), last column β).
#[pyfunction]
fn jacobian<'py>(
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
fn jacobian_values<'py>(
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
fn sse_gradient<'py>(
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

/// params[W, n_phonemes, 10] and betas[W] of W walkers.
fn batch_of<'py>(
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
fn evaluate_batch<'py>(
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
fn sse_batch<'py>(
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

/// The SSE and each utterance's weighted residual sum Σ w (y − F) of W parameter sets:
/// (ndarray[W], ndarray[W, n_utterances]); an invalid walker gets +inf and NaN sums.
#[pyfunction]
fn residual_sums_batch<'py>(
    py: Python<'py>,
    corpus: &Corpus,
    params: &Bound<'py, PyAny>,
    betas: &Bound<'py, PyAny>,
    options: &ModelOptions,
    observed: &Bound<'py, PyAny>,
    weights: &Bound<'py, PyAny>,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray2<f64>>)> {
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

/// The benchmark's yardstick: a loop of only the exponentials and powers the model needs for this
/// corpus (the physical limit on this machine). Returns a checksum so the loop is not optimised away.
#[pyfunction]
fn physical_limit_loop(
    py: Python<'_>,
    corpus: &Corpus,
    params: &Bound<'_, PyAny>,
    options: &ModelOptions,
) -> PyResult<f64> {
    let p = params_of(params, corpus)?;
    let p = data(&p, "params")?;
    Ok(py.detach(|| crate::physical_limit_loop(&corpus.inner, &p, &options.inner)))
}

/// The channels ULO, LLO, ULP, LLP, LR, JO, LA of every frame: ndarray[F, 7].
#[pyfunction]
fn marker_channels<'py>(
    py: Python<'py>,
    markers: &Bound<'py, PyAny>,
    rest: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let m = array::<f64>(markers, "markers", "float64")?;
    check_shape(
        &m,
        "markers",
        &[None, Some(N_MARKERS), Some(3)],
        "[frames, 8 markers NOSE, EAR_L, EAR_R, UL, LL, LC_L, LC_R, CHIN, xyz]",
    )?;
    let n_frames = m.shape()[0];
    let r = array::<bool>(rest, "rest", "bool")?;
    check_shape(
        &r,
        "rest",
        &[Some(n_frames)],
        "one flag per frame (markers.shape[0])",
    )?;
    let (m, r) = (data(&m, "markers")?, data(&r, "rest")?);
    let mut out = vec![0.0; n_frames * N_CHANNELS];
    py.detach(|| geometry::marker_channels(&m, n_frames, &r, &mut out))
        .map_err(geometry_err)?;
    let out = Array2::from_shape_vec((n_frames, N_CHANNELS), out)
        .map_err(|e| value_error(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// Every marker expressed in the head frame of its frame: ndarray[F, M, 3].
#[pyfunction]
fn head_frame<'py>(
    py: Python<'py>,
    markers: &Bound<'py, PyAny>,
    nose: i64,
    ear_l: i64,
    ear_r: i64,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let (nose, ear_l, ear_r) = (
        count(nose, "nose")?,
        count(ear_l, "ear_l")?,
        count(ear_r, "ear_r")?,
    );
    let m = array::<f64>(markers, "markers", "float64")?;
    check_shape(
        &m,
        "markers",
        &[None, None, Some(3)],
        "[frames, markers, xyz]",
    )?;
    let (n_frames, n_markers) = (m.shape()[0], m.shape()[1]);
    let m = data(&m, "markers")?;
    let mut out = vec![0.0; m.len()];
    py.detach(|| geometry::head_frame(&m, n_frames, n_markers, nose, ear_l, ear_r, &mut out))
        .map_err(geometry_err)?;
    let out = Array3::from_shape_vec((n_frames, n_markers, 3), out)
        .map_err(|e| value_error(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// The Rust core of coartic: the Cohen–Massaro / Cosi–Perin model over a corpus (evaluate,
/// Jacobian, SSE gradient, walker batches) and marker geometry. NumPy float64/int64 arrays in
/// and out; C-contiguous input is read without a copy; the GIL is released while computing.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Corpus>()?;
    m.add_class::<ModelOptions>()?;
    m.add("CoarticError", core_error_type(m.py())?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(jacobian, m)?)?;
    m.add_function(wrap_pyfunction!(jacobian_values, m)?)?;
    m.add_function(wrap_pyfunction!(sse_gradient, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_batch, m)?)?;
    m.add_function(wrap_pyfunction!(sse_batch, m)?)?;
    m.add_function(wrap_pyfunction!(residual_sums_batch, m)?)?;
    m.add_function(wrap_pyfunction!(physical_limit_loop, m)?)?;
    m.add_function(wrap_pyfunction!(marker_channels, m)?)?;
    m.add_function(wrap_pyfunction!(head_frame, m)?)?;
    m.add("N_PARAMS", N_PARAMS)?;
    m.add("MARKER_NAMES", geometry::MARKER_NAMES.to_vec())?;
    m.add("CHANNEL_NAMES", geometry::CHANNEL_NAMES.to_vec())?;
    Ok(())
}
