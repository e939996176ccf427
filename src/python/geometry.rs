//! Marker geometry: the channels of a face-marker set, markers in the head frame.

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;

use crate::geometry::{self, N_CHANNELS, N_MARKERS};

use super::arrays::{array, check_shape, count, data};
use super::errors::{geometry_err, value_error};

/// The channels ULO, LLO, ULP, LLP, LR, JO, LA of every frame: ndarray[F, 7].
#[pyfunction]
pub(super) fn marker_channels<'py>(
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
pub(super) fn head_frame<'py>(
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
