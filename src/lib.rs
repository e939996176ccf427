//! coartic: the Cohen–Massaro coarticulation model (MODEL.md eq. 1) and its modification by
//! Cosi & Perin (eq. 3, with the resistance of §3.1 and the shape of §3.2), evaluated exactly,
//! with exact analytic gradients, over whole corpora at once.
//!
//! The pure core has no Python in it (`cargo test` runs it); the PyO3 binding lives in
//! `src/python/` behind the `python` feature.
//!
//! Entry points: build a [`Corpus`] (CSR layout of docs/ARCHITECTURE.md), then [`evaluate`],
//! [`jacobian`], [`sse_gradient`], or the walker batches [`evaluate_batch`], [`sse_batch`] and [`residual_sums_batch`].
//!
//! Numerical conventions (MODEL.md §4):
//! - F is normalised in the log domain (log-sum-exp over segments): no 0/0 where every
//!   dominance underflows; a pair beyond its resistance extent (ρ = 0) is skipped.
//! - u = |τ|/Δ by division, so next to a k_R = 1 phoneme the cut-off falls exactly on its target
//!   and F(t_i) = T_i S_i(0) to the last bit.
//! - At τ = 0 exactly, ∂/∂c has no ln|τ| term (it multiplies |τ|^c = 0) and the derivative of
//!   |τ| through t_i (hence δ) is taken as 0: F has a kink there (one-sided slopes differ; for
//!   c < 1 they are infinite).
//! - ∂t_i/∂δ is 1 while the target time stays inside its segment, 0 where it is clamped.
//! - The values returned with the Jacobian equal those of [`evaluate`] bit for bit.

pub mod alloc;
pub mod corpus;
pub mod dominance;
pub mod error;
pub mod geometry;
mod gradient;
mod model;
pub mod params;
#[cfg(feature = "python")]
mod python;
pub mod resistance;
pub mod shape;
pub mod targets;
pub mod vector_math;

pub use corpus::{
    evaluate, evaluate_batch, jacobian, jacobian_values, physical_limit_loop, residual_sums_batch,
    sse_batch, sse_gradient, Corpus, SparseJacobian,
};
pub use error::ModelError;
pub use params::{
    validate_params, Dominance, ModelOptions, Param, UnknownDominance, UnknownVariant, Variant,
    N_PARAMS,
};
pub use resistance::Resistance;
pub use shape::Shape;
