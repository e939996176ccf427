//! Every way the input to the core can be wrong, each carrying the index at fault so that the
//! Python binding can raise a `ValueError` that names the utterance, segment, phoneme, parameter
//! or sample, with those as attributes ([`ModelError::fields`]).
//!
//! Numbering: the fields are indices counted from 0 (as in the arrays given); the messages count
//! utterances and segments from 1, as label files and the rest of coartic do, and name array
//! elements by their index (`seg_start[7]`, `weights[3]`). A phoneme is a row of the parameter
//! matrix, a walker a row of a batch, a sample an element of `sample_times`: indices, from 0.

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
    #[error("utterance {} (counted from 1) has {n_samples} samples but no segments", utterance + 1)]
    NoSegments { utterance: usize, n_samples: usize },
    /// A segment with end ≤ start.
    #[error(
        "utterance {}, segment {} (counted from 1; seg_start[{global}]): end {end} is not after start {start}",
        utterance + 1,
        segment + 1
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
        "utterance {}, segment {} (counted from 1; seg_start[{global}]): starts at {start}, before the previous segment ends at {previous_end} (segments must be sorted and must not overlap)",
        utterance + 1,
        segment + 1
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
        "utterance {}, segment {} (counted from 1; seg_phoneme[{global}]): phoneme index {phoneme} is not below n_phonemes = {n_phonemes}",
        utterance + 1,
        segment + 1
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
    #[error("utterance {} (counted from 1), sample_times[{sample}]: every segment has zero weight (θ·|τ|^c overflows); the model is undefined there", utterance + 1)]
    Degenerate { utterance: usize, sample: usize },
    /// A buffer whose size is a product of input sizes (the Jacobian of a long utterance, a batch
    /// of many walkers) cannot be allocated. Raised as `MemoryError` in Python: the input is
    /// valid, the machine is too small for it.
    #[error(
        "cannot allocate {what}: {elements} values of {element_bytes} bytes = {:.1} GiB",
        (*elements as f64) * (*element_bytes as f64) / (1u64 << 30) as f64
    )]
    OutOfMemory {
        /// What the buffer is and the sizes it is the product of.
        what: String,
        /// Number of elements (u128: the product of the sizes may overflow usize).
        elements: u128,
        element_bytes: usize,
    },
    /// The parameter set of one walker of a batch is invalid.
    #[error("walker {walker}: {source}")]
    InWalker {
        walker: usize,
        #[source]
        source: Box<ModelError>,
    },
}

/// The parts of a [`ModelError`] that the Python binding gives as attributes (every index
/// counted from 0; `None` where it does not apply).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorFields {
    pub utterance: Option<usize>,
    /// Within its utterance.
    pub segment: Option<usize>,
    /// Row of the parameter matrix.
    pub phoneme: Option<usize>,
    /// A parameter name or a global (`beta`, `apex_fraction`, `edge_extent`).
    pub parameter: Option<&'static str>,
    pub value: Option<f64>,
    pub sample: Option<usize>,
    pub walker: Option<usize>,
    /// What is wrong, in a few words, without the place or the value.
    pub reason: String,
}

impl ModelError {
    /// The place, value and reason of the error as separate fields (what the message says).
    pub fn fields(&self) -> ErrorFields {
        use ModelError::*;
        let reason = |r: String| ErrorFields {
            reason: r,
            ..ErrorFields::default()
        };
        match self {
            LengthMismatch {
                what,
                got,
                expected,
            } => reason(format!("{what} has length {got}, expected {expected}")),
            BadOffsets {
                what,
                index,
                value,
                reason: why,
            } => ErrorFields {
                value: Some(*value as f64),
                ..reason(format!("{what}[{index}] is invalid: {why}"))
            },
            NoSegments { utterance, .. } => ErrorFields {
                utterance: Some(*utterance),
                ..reason("has samples but no segments".into())
            },
            EmptySegment {
                utterance,
                segment,
                end,
                ..
            } => ErrorFields {
                utterance: Some(*utterance),
                segment: Some(*segment),
                value: Some(*end),
                ..reason("end is not after start".into())
            },
            OverlappingSegments {
                utterance,
                segment,
                start,
                ..
            } => ErrorFields {
                utterance: Some(*utterance),
                segment: Some(*segment),
                value: Some(*start),
                ..reason("starts before the previous segment ends".into())
            },
            PhonemeOutOfRange {
                utterance,
                segment,
                phoneme,
                n_phonemes,
                ..
            } => ErrorFields {
                utterance: Some(*utterance),
                segment: Some(*segment),
                phoneme: Some(*phoneme),
                ..reason(format!(
                    "phoneme index is not below n_phonemes = {n_phonemes}"
                ))
            },
            NonFiniteTime { what, index, value } => ErrorFields {
                value: Some(*value),
                sample: (*what == "sample_times").then_some(*index),
                ..reason(format!("{what}[{index}] is not finite"))
            },
            NonFiniteParameter {
                phoneme,
                param,
                value,
            } => ErrorFields {
                phoneme: Some(*phoneme),
                parameter: Some(param.name()),
                value: Some(*value),
                ..reason("is not finite".into())
            },
            ParameterOutOfDomain {
                phoneme,
                param,
                value,
                domain,
            } => ErrorFields {
                phoneme: Some(*phoneme),
                parameter: Some(param.name()),
                value: Some(*value),
                ..reason(format!("is outside its domain {domain}"))
            },
            BadGlobal {
                name,
                value,
                domain,
            } => ErrorFields {
                parameter: Some(name),
                value: Some(*value),
                ..reason(format!("must be {domain}"))
            },
            BadWeight { sample, value } => ErrorFields {
                sample: Some(*sample),
                value: Some(*value),
                ..reason("weights must be finite and >= 0".into())
            },
            NonFiniteObserved { sample, value, .. } => ErrorFields {
                sample: Some(*sample),
                value: Some(*value),
                ..reason("observed value is not finite but its weight is not 0".into())
            },
            Degenerate { utterance, sample } => ErrorFields {
                utterance: Some(*utterance),
                sample: Some(*sample),
                ..reason("every segment has zero weight".into())
            },
            OutOfMemory { what, .. } => reason(format!("cannot allocate {what}")),
            InWalker { walker, source } => ErrorFields {
                walker: Some(*walker),
                ..source.fields()
            },
        }
    }

    /// Whether this is (or wraps) [`ModelError::OutOfMemory`].
    pub fn is_out_of_memory(&self) -> bool {
        match self {
            ModelError::OutOfMemory { .. } => true,
            ModelError::InWalker { source, .. } => source.is_out_of_memory(),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_count_from_one_fields_from_zero() {
        let e = ModelError::EmptySegment {
            utterance: 0,
            segment: 2,
            global: 2,
            start: 0.34,
            end: 0.33,
        };
        assert_eq!(
            e.to_string(),
            "utterance 1, segment 3 (counted from 1; seg_start[2]): end 0.33 is not after start 0.34"
        );
        let f = e.fields();
        assert_eq!(
            (f.utterance, f.segment, f.value),
            (Some(0), Some(2), Some(0.33))
        );
        assert_eq!(f.reason, "end is not after start");
        let e = ModelError::InWalker {
            walker: 4,
            source: Box::new(ModelError::ParameterOutOfDomain {
                phoneme: 1,
                param: Param::KR,
                value: 1.5,
                domain: "[0, 1]",
            }),
        };
        let f = e.fields();
        assert_eq!(
            (f.walker, f.phoneme, f.parameter, f.value),
            (Some(4), Some(1), Some("k_r"), Some(1.5))
        );
        assert_eq!(f.reason, "is outside its domain [0, 1]");
        assert!(!e.is_out_of_memory());
        let oom = ModelError::InWalker {
            walker: 0,
            source: Box::new(ModelError::OutOfMemory {
                what: "x".into(),
                elements: 1 << 40,
                element_bytes: 8,
            }),
        };
        assert!(oom.is_out_of_memory());
        assert!(oom
            .to_string()
            .ends_with("1099511627776 values of 8 bytes = 8192.0 GiB"));
    }
}
