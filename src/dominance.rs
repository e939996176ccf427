//! Dominance D_i(τ) of MODEL.md §2, in log form:
//! ln D = ln α − θ |τ|^c, with (θ, c) = (θ_bw, c_bw) for τ ≤ 0 and (θ_fw, c_fw) for τ > 0.
//!
//! The core works with ln D because the normalisation of eq. 1 / eq. 3 is a log-sum-exp: when
//! θ|τ|^c is large, D underflows to 0 but ln D stays exact.

use crate::vector_math::{exp, ln};

/// Which side of its target time a sample lies on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// τ ≤ 0: before (or at) the target; uses θ_bw, c_bw and the backward extent Δ⁻.
    Backward,
    /// τ > 0: after the target; uses θ_fw, c_fw and the forward extent Δ⁺.
    Forward,
}

impl Side {
    /// The side of τ = t − t_i (τ = 0 counts as backward, as in MODEL.md §2).
    #[inline(always)]
    pub fn of(tau: f64) -> Side {
        if tau <= 0.0 {
            Side::Backward
        } else {
            Side::Forward
        }
    }
}

/// ln D at one (sample, segment) pair, with the pieces its derivatives reuse.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LogDominance {
    /// ln D = ln α − θ |τ|^c.
    pub log_d: f64,
    /// |τ|^c (0 at τ = 0, since c > 0).
    pub power: f64,
    /// ln |τ|, taken as 0 at τ = 0 (where it only ever multiplies |τ|^c = 0).
    pub ln_abs_tau: f64,
}

/// |τ|^c as exp(c ln|τ|) given ln|τ|, and exactly |τ| for c = 1 (the original model's exponent,
/// where the evaluator then needs no transcendental function for the power at all).
#[inline(always)]
fn power(c: f64, abs_tau: f64, ln_abs_tau: f64) -> f64 {
    if c == 1.0 {
        abs_tau
    } else {
        exp(c * ln_abs_tau)
    }
}

/// ln D for |τ| = `abs_tau` with the side's rate θ and exponent c (MODEL.md §2), with ln|τ|
/// kept for ∂/∂c.
///
/// |τ|^c is computed as exp(c ln|τ|) (exactly |τ| for c = 1): one logarithm per pair, shared
/// with ∂/∂c. Through the [`crate::vector_math`] kernels, like the vectorised evaluator, so
/// that both give the same bits.
#[inline(always)]
pub fn log_dominance(log_alpha: f64, theta: f64, c: f64, abs_tau: f64) -> LogDominance {
    if abs_tau > 0.0 {
        let ln_abs_tau = ln(abs_tau);
        let power = power(c, abs_tau, ln_abs_tau);
        LogDominance {
            log_d: log_alpha - theta * power,
            power,
            ln_abs_tau,
        }
    } else {
        LogDominance {
            log_d: log_alpha,
            power: 0.0,
            ln_abs_tau: 0.0,
        }
    }
}

/// ln D alone, bit for bit equal to [`log_dominance`]`.log_d`, skipping ln|τ| when c = 1.
#[inline(always)]
pub fn log_dominance_value(log_alpha: f64, theta: f64, c: f64, abs_tau: f64) -> f64 {
    if abs_tau > 0.0 {
        let power = if c == 1.0 {
            abs_tau
        } else {
            exp(c * ln(abs_tau))
        };
        log_alpha - theta * power
    } else {
        log_alpha
    }
}

/// Partial derivatives of ln D with respect to α, θ (of the side), c (of the side) and τ.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LogDominanceGrad {
    /// ∂ ln D / ∂α = 1/α.
    pub d_alpha: f64,
    /// ∂ ln D / ∂θ = −|τ|^c.
    pub d_theta: f64,
    /// ∂ ln D / ∂c = −θ |τ|^c ln|τ|: 0 at τ = 0 (MODEL.md §4), finite for every c > 0.
    pub d_c: f64,
    /// ∂ ln D / ∂τ = −θ c |τ|^c / τ. At τ = 0 the one-sided derivatives differ (a kink for
    /// c ≤ 1, infinite for c < 1); the core takes 0 there, the mean of the two sides when the
    /// sides are symmetric, so derivatives through t_i (δ) stay finite.
    pub d_tau: f64,
}

/// Derivatives of ln D given 1/α and the pieces |τ|^c and ln|τ| (0 at τ = 0) of the value, as
/// [`log_dominance`] returns them or as the vectorised value pass stores them.
#[inline(always)]
pub fn log_dominance_grad(
    inv_alpha: f64,
    theta: f64,
    c: f64,
    tau: f64,
    power: f64,
    ln_abs_tau: f64,
) -> LogDominanceGrad {
    let d_tau = if tau != 0.0 {
        -theta * c * power / tau
    } else {
        0.0
    };
    LogDominanceGrad {
        d_alpha: inv_alpha,
        d_theta: -power,
        d_c: -theta * power * ln_abs_tau,
        d_tau,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_matches_definition() {
        let ld = log_dominance(0.3f64.ln(), 20.0, 0.7, 0.05);
        let direct = (0.3 * (-20.0 * 0.05f64.powf(0.7)).exp()).ln();
        assert!((ld.log_d - direct).abs() < 1e-13);
    }

    #[test]
    fn value_only_form_is_bitwise_equal() {
        for &(c, a) in &[
            (1.0, 0.037),
            (0.73, 0.2),
            (2.4, 1e-5),
            (1.0, 0.0),
            (0.5, 0.0),
        ] {
            let full = log_dominance(0.2, 33.0, c, a).log_d;
            assert_eq!(
                full.to_bits(),
                log_dominance_value(0.2, 33.0, c, a).to_bits()
            );
        }
        assert_eq!(log_dominance(0.0, 10.0, 1.0, 0.25).power, 0.25);
    }

    #[test]
    fn finite_at_zero_with_c_below_one() {
        let ld = log_dominance(0.0, 20.0, 0.5, 0.0);
        let g = log_dominance_grad(1.0, 20.0, 0.5, 0.0, ld.power, ld.ln_abs_tau);
        assert_eq!(ld.log_d, 0.0);
        assert_eq!(g.d_c, 0.0);
        assert_eq!(g.d_tau, 0.0);
        assert!(g.d_theta == 0.0);
    }

    #[test]
    fn tau_derivative_matches_difference() {
        for &tau in &[-0.07, 0.03] {
            let (theta, c) = (15.0, 1.7);
            let f = |t: f64| log_dominance(0.0, theta, c, t.abs()).log_d;
            let h = 1e-6;
            let fd = (f(tau + h) - f(tau - h)) / (2.0 * h);
            let ld = log_dominance(0.0, theta, c, tau.abs());
            let g = log_dominance_grad(1.0, theta, c, tau, ld.power, ld.ln_abs_tau);
            assert!(
                (g.d_tau - fd).abs() < 1e-6 * fd.abs().max(1.0),
                "{} vs {}",
                g.d_tau,
                fd
            );
        }
    }
}
