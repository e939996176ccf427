//! Errors across the boundary: the core's `ModelError` and `GeometryError` as
//! `coartic._core.CoarticError` (a ValueError, the place at fault as attributes) or MemoryError.

use pyo3::exceptions::{PyMemoryError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyType};

use crate::error::ErrorFields;
use crate::geometry::GeometryError;
use crate::ModelError;

/// `coartic._core.CoarticError`, made at import: a subclass of the package's base
/// `coartic.errors.CoarticError` and of ValueError, so that `except ValueError` and
/// `except coartic.errors.CoarticError` both catch it.
static CORE_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

const CORE_ERROR_DOC: &str = "Invalid input to the model core. The message names the place at \
fault; the attributes utterance, segment (within its utterance), phoneme (row of the parameter \
matrix), parameter, value, sample and walker give it as indices counted from 0 (None where they \
do not apply; messages count utterances and segments from 1), reason says what is wrong.";

pub(super) fn core_error_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
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
pub(super) fn coartic_error(message: String, fields: Option<ErrorFields>) -> PyErr {
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
pub(super) fn value_error(message: String) -> PyErr {
    coartic_error(message, None)
}

/// The core's error as `CoarticError` with its fields as attributes, or MemoryError.
pub(super) fn model_err(e: ModelError) -> PyErr {
    if e.is_out_of_memory() {
        return PyMemoryError::new_err(e.to_string());
    }
    coartic_error(e.to_string(), Some(e.fields()))
}

pub(super) fn geometry_err(e: GeometryError) -> PyErr {
    value_error(e.to_string())
}
