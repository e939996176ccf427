//! coartic: the Cohen–Massaro coarticulation model (MODEL.md eq. 1) and its modification by
//! Cosi & Perin (eq. 3, with the resistance of §3.1 and the shape of §3.2), evaluated exactly,
//! with exact analytic gradients, over whole corpora at once.
//!
//! The pure core has no Python in it (`cargo test` runs it); the PyO3 binding lives in
//! `src/python/` behind the `python` feature.
//!
//! Entry points: build a [`Corpus`] (CSR layout of docs/ARCHITECTURE.md), then [`evaluate`],
//! [`jacobian`], [`sse_gradient`], or the walker batches [`evaluate_batch`] and [`sse_batch`].

pub mod corpus;
pub mod dominance;
pub mod error;
pub mod geometry;
pub mod gradient;
pub mod model;
pub mod params;
#[cfg(feature = "python")]
mod python;
pub mod resistance;
pub mod shape;
pub mod targets;

pub use corpus::{
    evaluate, evaluate_batch, jacobian, physical_limit_loop, sse_batch, sse_gradient, Corpus,
    SparseJacobian,
};
pub use error::ModelError;
pub use params::{validate_params, ModelOptions, Param, UnknownVariant, Variant, N_PARAMS};
pub use resistance::Resistance;
pub use shape::Shape;
