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

mod arrays;
mod batch;
mod corpus;
mod errors;
mod geometry;
mod model;

use pyo3::prelude::*;

use crate::N_PARAMS;

/// The Rust core of coartic: the Cohen–Massaro / Cosi–Perin model over a corpus (evaluate,
/// Jacobian, SSE gradient, walker batches) and marker geometry. NumPy float64/int64 arrays in
/// and out; C-contiguous input is read without a copy; the GIL is released while computing.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<corpus::Corpus>()?;
    m.add_class::<model::ModelOptions>()?;
    m.add("CoarticError", errors::core_error_type(m.py())?)?;
    m.add_function(wrap_pyfunction!(model::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(model::jacobian, m)?)?;
    m.add_function(wrap_pyfunction!(model::jacobian_values, m)?)?;
    m.add_function(wrap_pyfunction!(model::sse_gradient, m)?)?;
    m.add_function(wrap_pyfunction!(batch::evaluate_batch, m)?)?;
    m.add_function(wrap_pyfunction!(batch::sse_batch, m)?)?;
    m.add_function(wrap_pyfunction!(batch::residual_sums_batch, m)?)?;
    m.add_function(wrap_pyfunction!(model::physical_limit_loop, m)?)?;
    m.add_function(wrap_pyfunction!(geometry::marker_channels, m)?)?;
    m.add_function(wrap_pyfunction!(geometry::head_frame, m)?)?;
    m.add("N_PARAMS", N_PARAMS)?;
    m.add("MARKER_NAMES", crate::geometry::MARKER_NAMES.to_vec())?;
    m.add("CHANNEL_NAMES", crate::geometry::CHANNEL_NAMES.to_vec())?;
    Ok(())
}
