//! NumPy arguments: borrowed read-only (a copy only when not C-contiguous), caller's output
//! buffers checked before use, shapes checked and named in the message, integer arguments.

use std::borrow::Cow;

use numpy::{
    BorrowError, Element, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyReadwriteArrayDyn,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;

use crate::alloc::try_with_capacity;

use super::errors::{model_err, value_error};

/// Borrow `obj` as a read-only NumPy array of `T`, or raise TypeError naming the argument.
pub(super) fn array<'py, T: Element>(
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
pub(super) fn what_is(obj: &Bound<'_, PyAny>) -> PyResult<String> {
    Ok(match obj.cast::<PyUntypedArray>() {
        Ok(a) => format!("an array of dtype {}", a.dtype()),
        Err(_) => format!("{}", obj.get_type().name()?),
    })
}

/// A caller's output buffer, filled in place: a writeable, aligned, C-contiguous float64 array of
/// shape (len,) that shares no memory with another argument of the call. Anything else is refused
/// (TypeError for the type or dtype, ValueError otherwise): a silent copy would leave the
/// caller's array unfilled.
pub(super) fn out_buffer<'py>(
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
pub(super) fn check_shape<T: Element>(
    a: &PyReadonlyArrayDyn<'_, T>,
    name: &str,
    expected: &[Option<usize>],
    meaning: &str,
) -> PyResult<()> {
    shape_ok(name, a.shape(), expected, meaning)
}

/// The shape test of [`check_shape`] on a bare shape.
pub(super) fn shape_ok(
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
pub(super) fn tuple(items: Vec<String>) -> String {
    match items.len() {
        1 => format!("({},)", items[0]),
        _ => format!("({})", items.join(", ")),
    }
}

/// The elements of argument `name` in C order: in place if C-contiguous, else one copy, allocated
/// fallibly: a broadcast view (`numpy.broadcast_to`) costs NumPy no memory however large its
/// shape, but its copy does (MemoryError naming the argument and the sizes, not an abort).
pub(super) fn data<'a, T: Element + Copy>(
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

pub(super) fn f64_vec(
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
pub(super) fn count(value: i64, name: &str) -> PyResult<usize> {
    usize::try_from(value)
        .map_err(|_| value_error(format!("argument '{name}' = {value} must be >= 0")))
}

pub(super) fn index_vec(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<usize>> {
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

/// SciPy indexes with signed integers. Same size and alignment, so the collect reuses the
/// allocation; an index beyond i64 would need more memory than exists.
pub(super) fn as_i64(v: Vec<usize>) -> Vec<i64> {
    v.into_iter().map(|x| x as i64).collect()
}
