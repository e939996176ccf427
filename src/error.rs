//! Every way the input to the core can be wrong, each carrying the index at fault so that the
//! Python binding can raise a `ValueError` that names the utterance, segment, phoneme, parameter
//! or sample.

use crate::params::Param;
use thiserror::Error;

/// An invalid input to the model core (or a numerically degenerate model).
///
/// Array names in the messages (`seg_offsets`, `sample_times`, …) are the argument names of
/// `coartic._core.Corpus` (docs/ARCHITECTURE.md), so a Python user can find the culprit.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ModelError {
    /// Two arrays that must agree in length do not.
    #[error("length mismatch: {what} has length {got}, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    /// An offsets array (`seg_offsets`, `sample_offsets`) does not start at 0, decreases, or does
    /// not end at the length of the array it indexes.
    #[error("{what}[{index}] = {value} is invalid: {reason}")]
    BadOffsets {
        what: &'static str,
        index: usize,
        value: usize,
        reason: &'static str,
    },
    /// An utterance has samples but no segments to evaluate them against.
    #[error("utterance {utterance} has {n_samples} samples but no segments")]
    NoSegments { utterance: usize, n_samples: usize },
    /// A segment with end ≤ start.
    #[error(
        "utterance {utterance}, segment {segment} (global index {global}): end {end} is not after start {start}"
    )]
    EmptySegment {
        utterance: usize,
        segment: usize,
        global: usize,
        start: f64,
        end: f64,
    },
    /// A segment that starts before the previous one ends (unsorted or overlapping).
    #[error(
        "utterance {utterance}, segment {segment} (global index {global}): starts at {start}, before the previous segment ends at {previous_end} (segments must be sorted and must not overlap)"
    )]
    OverlappingSegments {
        utterance: usize,
        segment: usize,
        global: usize,
        start: f64,
        previous_end: f64,
    },
    /// `seg_phoneme` names a row that the parameter matrix does not have.
    #[error(
        "utterance {utterance}, segment {segment} (global index {global}): phoneme index {phoneme} is not below n_phonemes = {n_phonemes}"
    )]
    PhonemeOutOfRange {
        utterance: usize,
        segment: usize,
        global: usize,
        phoneme: usize,
        n_phonemes: usize,
    },
    /// NaN or ±inf in a time array (`seg_start`, `seg_end`, `sample_times`).
    #[error("{what}[{index}] = {value} is not finite")]
    NonFiniteTime {
        what: &'static str,
        index: usize,
        value: f64,
    },
    /// A per-phoneme parameter is NaN or ±inf.
    #[error("phoneme {phoneme}, parameter {param}: value {value} is not finite")]
    NonFiniteParameter {
        phoneme: usize,
        param: Param,
        value: f64,
    },
    /// A per-phoneme parameter lies outside its mathematical domain (MODEL.md §1).
    #[error("phoneme {phoneme}, parameter {param}: value {value} is outside its domain {domain}")]
    ParameterOutOfDomain {
        phoneme: usize,
        param: Param,
        value: f64,
        domain: &'static str,
    },
    /// A global (`beta`, `edge_extent`, `apex_fraction`) is non-finite or outside its domain.
    #[error("{name} = {value} is invalid: must be {domain}")]
    BadGlobal {
        name: &'static str,
        value: f64,
        domain: &'static str,
    },
    /// A weight is NaN, infinite or negative.
    #[error("weights[{sample}] = {value} is invalid: weights must be finite and >= 0")]
    BadWeight { sample: usize, value: f64 },
    /// An observed value is NaN or infinite where its weight is not 0.
    #[error("observed[{sample}] = {value} is not finite but its weight is {weight} (give it weight 0 to mask it)")]
    NonFiniteObserved {
        sample: usize,
        value: f64,
        weight: f64,
    },
    /// Every segment's weight R·D is exactly zero or −∞ in the log domain at a sample (only with
    /// absurd parameters, e.g. θ·|τ|^c overflowing to +∞).
    #[error("utterance {utterance}, sample {sample}: every segment has zero weight (θ·|τ|^c overflows); the model is undefined there")]
    Degenerate { utterance: usize, sample: usize },
    /// The parameter set of one walker of a batch is invalid.
    #[error("walker {walker}: {source}")]
    InWalker {
        walker: usize,
        #[source]
        source: Box<ModelError>,
    },
}
