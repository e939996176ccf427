//! The per-phoneme parameter columns (docs/ARCHITECTURE.md), the model options, and the check of a
//! parameter set against the mathematical domains of MODEL.md §1.

use crate::error::ModelError;
use crate::resistance::Resistance;
use crate::shape::Shape;
use std::fmt;
use std::str::FromStr;

/// Number of per-phoneme parameters: the width of the parameter matrix.
pub const N_PARAMS: usize = 10;

/// The per-phoneme parameters, in column order of the parameter matrix, of the Jacobian and of
/// the CSV table (docs/ARCHITECTURE.md). Symbols follow MODEL.md §1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(usize)]
pub enum Param {
    /// T: the value the channel moves towards.
    Target = 0,
    /// α: dominance magnitude, > 0.
    Alpha = 1,
    /// θ_bw: backward dominance rate (s^-c), > 0.
    ThetaBw = 2,
    /// θ_fw: forward dominance rate (s^-c), > 0.
    ThetaFw = 3,
    /// c_bw: backward activation exponent, > 0.
    CBw = 4,
    /// c_fw: forward activation exponent, > 0.
    CFw = 5,
    /// k_R: resistance in [0, 1].
    KR = 6,
    /// σ: shape amplitude.
    Sigma = 7,
    /// ψ: shape rate (s^-2), ≥ 0.
    Psi = 8,
    /// δ: target lag (s).
    Delta = 9,
}

impl Param {
    /// All parameters in column order.
    pub const ALL: [Param; N_PARAMS] = [
        Param::Target,
        Param::Alpha,
        Param::ThetaBw,
        Param::ThetaFw,
        Param::CBw,
        Param::CFw,
        Param::KR,
        Param::Sigma,
        Param::Psi,
        Param::Delta,
    ];

    /// Column index (0..10).
    #[inline]
    pub fn index(self) -> usize {
        self as usize
    }

    /// The name used in code, JSON and CSV (`target`, `alpha`, …, `delta`).
    pub fn name(self) -> &'static str {
        match self {
            Param::Target => "target",
            Param::Alpha => "alpha",
            Param::ThetaBw => "theta_bw",
            Param::ThetaFw => "theta_fw",
            Param::CBw => "c_bw",
            Param::CFw => "c_fw",
            Param::KR => "k_r",
            Param::Sigma => "sigma",
            Param::Psi => "psi",
            Param::Delta => "delta",
        }
    }
}

impl fmt::Display for Param {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Which model is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Variant {
    /// Cohen & Massaro, MODEL.md eq. 1: S ≡ R ≡ 1; k_R, σ, ψ and β are ignored (derivatives 0).
    Original,
    /// Cosi & Perin, MODEL.md eq. 3, with the resistance of §3.1 and the shape of §3.2.
    #[default]
    Modified,
}

impl Variant {
    /// The resistance closed form this variant uses.
    pub fn resistance(self) -> Resistance {
        match self {
            Variant::Original => Resistance::None,
            Variant::Modified => Resistance::Cutoff,
        }
    }

    /// The shape closed form this variant uses.
    pub fn shape(self) -> Shape {
        match self {
            Variant::Original => Shape::None,
            Variant::Modified => Shape::Gaussian,
        }
    }

    /// `"original"` or `"modified"`.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Original => "original",
            Variant::Modified => "modified",
        }
    }
}

impl fmt::Display for Variant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Error of [`Variant::from_str`]: the unknown name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown model variant {0:?}: expected \"original\" or \"modified\"")]
pub struct UnknownVariant(pub String);

impl FromStr for Variant {
    type Err = UnknownVariant;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "original" => Ok(Variant::Original),
            "modified" => Ok(Variant::Modified),
            other => Err(UnknownVariant(other.to_string())),
        }
    }
}

/// How a segment's dominance depends on the distance τ to its target time (MODEL.md §2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Dominance {
    /// MODEL.md §2: D decays from the target time, ln D = ln α − θ |τ|^c.
    #[default]
    Centre,
    /// MODEL.md §2.1: D is flat (= α) within h·d_i of the target time (d_i the segment's
    /// duration, h the plateau fraction) and decays beyond, ln D = ln α − θ r^c with
    /// r = max(|τ| − h d_i, 0): a longer (slower) segment holds its target longer, while the
    /// transitions keep their time scale in seconds.
    Plateau,
}

impl Dominance {
    /// `"centre"` or `"plateau"`.
    pub fn name(self) -> &'static str {
        match self {
            Dominance::Centre => "centre",
            Dominance::Plateau => "plateau",
        }
    }
}

impl fmt::Display for Dominance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Error of [`Dominance::from_str`]: the unknown name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown dominance {0:?}: expected \"centre\" or \"plateau\"")]
pub struct UnknownDominance(pub String);

impl FromStr for Dominance {
    type Err = UnknownDominance;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "centre" => Ok(Dominance::Centre),
            "plateau" => Ok(Dominance::Plateau),
            other => Err(UnknownDominance(other.to_string())),
        }
    }
}

/// Per-channel options that are not fitted per phoneme (MODEL.md §1, §2.1, §3.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelOptions {
    /// Original (eq. 1) or modified (eq. 3).
    pub variant: Variant,
    /// a in t_i = s_i + a·(e_i − s_i) + δ, in [0, 1]; default 0.5.
    pub apex_fraction: f64,
    /// Λ, the extent at the utterance edges (s), > 0; default 1.0.
    pub edge_extent: f64,
    /// Centre (default, MODEL.md §2) or plateau dominance (§2.1).
    pub dominance: Dominance,
    /// h of the plateau dominance, in [0, 1] (fixed, not fitted); default 0.5. Unused with
    /// [`Dominance::Centre`].
    pub plateau_fraction: f64,
    /// MODEL.md §2.1: the forward side of a segment's dominance (τ > 0) takes θ_fw and c_fw from
    /// the phoneme of the next segment (the last segment of an utterance keeps its own), so θ_fw
    /// of a phoneme is how fast it takes over from what precedes it. Default false.
    pub handover: bool,
}

impl Default for ModelOptions {
    fn default() -> Self {
        ModelOptions {
            variant: Variant::Modified,
            apex_fraction: 0.5,
            edge_extent: 1.0,
            dominance: Dominance::Centre,
            plateau_fraction: 0.5,
            handover: false,
        }
    }
}

impl ModelOptions {
    /// Checks a ∈ [0, 1], Λ finite and > 0, and h ∈ [0, 1].
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.plateau_fraction.is_finite() && (0.0..=1.0).contains(&self.plateau_fraction)) {
            return Err(ModelError::BadGlobal {
                name: "plateau_fraction",
                value: self.plateau_fraction,
                domain: "in [0, 1]",
            });
        }
        if !(self.apex_fraction.is_finite() && (0.0..=1.0).contains(&self.apex_fraction)) {
            return Err(ModelError::BadGlobal {
                name: "apex_fraction",
                value: self.apex_fraction,
                domain: "in [0, 1]",
            });
        }
        if !(self.edge_extent.is_finite() && self.edge_extent > 0.0) {
            return Err(ModelError::BadGlobal {
                name: "edge_extent",
                value: self.edge_extent,
                domain: "finite and > 0",
            });
        }
        Ok(())
    }
}

/// Checks a parameter matrix (`n_phonemes` rows of [`N_PARAMS`], row-major) and β against the
/// domains of MODEL.md §1: every used value finite, α > 0, θ > 0, c > 0, k_R ∈ [0, 1], ψ ≥ 0,
/// β ≥ 0, and the options (a ∈ [0, 1], Λ > 0). With [`Variant::Original`], k_R, σ, ψ and β are
/// not part of the model and are not checked.
///
/// The bounds used for fitting (c ∈ [0.5, 3], σ ∈ [−0.5, 0.5], …) are narrower; they are the
/// fitter's business, not the model's.
pub fn validate_params(
    params: &[f64],
    n_phonemes: usize,
    beta: f64,
    opts: &ModelOptions,
) -> Result<(), ModelError> {
    opts.validate()?;
    let expected = n_phonemes * N_PARAMS;
    if params.len() != expected {
        return Err(ModelError::LengthMismatch {
            what: "params (n_phonemes * 10)",
            got: params.len(),
            expected,
        });
    }
    let modified = opts.variant == Variant::Modified;
    if modified && !(beta.is_finite() && beta >= 0.0) {
        return Err(ModelError::BadGlobal {
            name: "beta",
            value: beta,
            domain: "finite and >= 0",
        });
    }
    for (phoneme, row) in params.chunks_exact(N_PARAMS).enumerate() {
        for param in Param::ALL {
            let value = row[param.index()];
            let used = modified || !matches!(param, Param::KR | Param::Sigma | Param::Psi);
            if !used {
                continue;
            }
            if !value.is_finite() {
                return Err(ModelError::NonFiniteParameter {
                    phoneme,
                    param,
                    value,
                });
            }
            let domain = match param {
                Param::Alpha | Param::ThetaBw | Param::ThetaFw | Param::CBw | Param::CFw
                    if value <= 0.0 =>
                {
                    Some("> 0")
                }
                Param::KR if !(0.0..=1.0).contains(&value) => Some("[0, 1]"),
                Param::Psi if value < 0.0 => Some(">= 0"),
                _ => None,
            };
            if let Some(domain) = domain {
                return Err(ModelError::ParameterOutOfDomain {
                    phoneme,
                    param,
                    value,
                    domain,
                });
            }
        }
    }
    Ok(())
}
