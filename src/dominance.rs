//! Dominance D_i(τ) of MODEL.md §2, in log form:
//! ln D = ln α − θ |τ|^c, with (θ, c) = (θ_bw, c_bw) for τ ≤ 0 and (θ_fw, c_fw) for τ > 0.
//!
//! The core works with ln D because the normalisation of eq. 1 / eq. 3 is a log-sum-exp: when
//! θ|τ|^c is large, D underflows to 0 but ln D stays exact.
//!
//! The value kernels are written once over [`Lanes`] and inlined into their callers: the scalar
//! and AVX2 evaluators, the gradient's value pass and the physical-limit loop all run this code
//! (a generic `#[inline(always)]` function takes on the caller's AVX2 target feature, a closure
//! would not), and so do the unit tests below, with one lane.

use crate::vector_math::{exp_lanes, ln_lanes, Lanes};

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

/// The dominance parameters of one segment, both sides (MODEL.md §1–2), as the inner loops read
/// them: ln α rather than α. With the handover option, `theta_fw` and `c_fw` are those of the
/// next segment's phoneme (MODEL.md §2.1).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DominanceParams {
    pub log_alpha: f64,
    pub theta_bw: f64,
    pub theta_fw: f64,
    pub c_bw: f64,
    pub c_fw: f64,
    /// h·d_i, the half-width of the plateau of MODEL.md §2.1 (s); 0 for the centre dominance.
    pub plateau: f64,
}

impl DominanceParams {
    /// The reach r = max(|τ| − h d_i, 0) that replaces |τ| inside D (MODEL.md §2.1); |τ| itself,
    /// bit for bit, without a plateau. `RATE` is false when no rate-aware option is on for the
    /// whole call: the test then compiles away and today's model runs today's instructions.
    #[inline(always)]
    pub(crate) fn reach<V: Lanes, const RATE: bool>(&self, abs_tau: V) -> V {
        if !RATE || self.plateau == 0.0 {
            abs_tau
        } else {
            let zero = V::splat(0.0);
            let x = abs_tau.sub(V::splat(self.plateau));
            V::select(x.gt(zero), x, zero)
        }
    }

    /// sign(τ)·r: what the τ-derivative of ln D divides by ([`log_dominance_grad`]); τ itself
    /// without a plateau.
    #[inline(always)]
    pub fn signed_reach<const RATE: bool>(&self, tau: f64) -> f64 {
        if !RATE || self.plateau == 0.0 {
            tau
        } else {
            let r = self.reach::<f64, RATE>(tau.abs());
            if tau > 0.0 {
                r
            } else {
                -r
            }
        }
    }

    /// Whether c = 1 on both sides (the original model's exponent): |τ|^c is then |τ| on every
    /// lane and the value needs no transcendental function for the power (decided once per
    /// segment, not per lane).
    #[inline(always)]
    fn linear(&self) -> bool {
        self.c_bw == 1.0 && self.c_fw == 1.0
    }

    /// θ and c of each lane's side (`bw`: τ ≤ 0).
    #[inline(always)]
    fn theta<V: Lanes>(&self, bw: V::Mask) -> V {
        V::select(bw, V::splat(self.theta_bw), V::splat(self.theta_fw))
    }

    #[inline(always)]
    fn c<V: Lanes>(&self, bw: V::Mask) -> V {
        V::select(bw, V::splat(self.c_bw), V::splat(self.c_fw))
    }
}

/// The side mask of τ: true on the lanes where τ ≤ 0 ([`Side::Backward`]).
#[inline(always)]
pub(crate) fn backward<V: Lanes>(tau: V) -> V::Mask {
    tau.le(V::splat(0.0))
}

/// |τ|^c as exp(c ln|τ|) given ln|τ|, and exactly |τ| on the lanes where c = 1. At τ = 0,
/// ln 0 = −∞ gives exp(−∞) = 0 = |τ|^c for every c > 0.
#[inline(always)]
fn power<V: Lanes>(c: V, abs_tau: V, ln_abs_tau: V) -> V {
    V::select(c.eq(V::splat(1.0)), abs_tau, exp_lanes(c.mul(ln_abs_tau)))
}

/// ln D on the lanes of |τ| = `abs_tau`, with the pieces its derivatives reuse. r is |τ| for the
/// centre dominance, the reach max(|τ| − h d_i, 0) with a plateau.
#[derive(Clone, Copy)]
pub(crate) struct LogDominance<V> {
    /// ln D = ln α − θ r^c.
    pub log_d: V,
    /// r^c (0 at r = 0, since c > 0).
    pub power: V,
    /// ln r, taken as 0 at r = 0 (where it only ever multiplies r^c = 0).
    pub ln_abs_tau: V,
}

/// ln D for |τ| = `abs_tau` with each lane's side (`bw`: τ ≤ 0) rate θ and exponent c (MODEL.md
/// §2), with |τ|^c and ln|τ| kept for the derivatives ([`log_dominance_grad`]).
///
/// |τ|^c is computed as exp(c ln|τ|) (exactly |τ| for c = 1): one logarithm per pair, shared
/// with ∂/∂c, which needs ln|τ| even where c = 1. Bit for bit equal to
/// [`log_dominance_value`] on `log_d`.
#[inline(always)]
pub(crate) fn log_dominance<V: Lanes, const RATE: bool>(
    d: &DominanceParams,
    bw: V::Mask,
    abs_tau: V,
) -> LogDominance<V> {
    let s = V::splat;
    let r = d.reach::<V, RATE>(abs_tau);
    let theta = d.theta::<V>(bw);
    let ln_r = ln_lanes(r);
    let power = if d.linear() {
        r
    } else {
        power(d.c::<V>(bw), r, ln_r)
    };
    LogDominance {
        log_d: s(d.log_alpha).sub(theta.mul(power)),
        power,
        ln_abs_tau: V::select(r.eq(s(0.0)), s(0.0), ln_r),
    }
}

/// ln D alone (the evaluator's and the physical-limit loop's kernel): the same operations as
/// [`log_dominance`], skipping ln|τ| where c = 1 on both sides.
#[inline(always)]
pub(crate) fn log_dominance_value<V: Lanes, const RATE: bool>(
    d: &DominanceParams,
    bw: V::Mask,
    abs_tau: V,
) -> V {
    let r = d.reach::<V, RATE>(abs_tau);
    let theta = d.theta::<V>(bw);
    let power = if d.linear() {
        r
    } else {
        power(d.c::<V>(bw), r, ln_lanes(r))
    };
    V::splat(d.log_alpha).sub(theta.mul(power))
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

/// Derivatives of ln D given 1/α and the pieces r^c and ln r (0 at r = 0) of the value, as
/// [`log_dominance`] returns them (the gradient's value pass stores them per lane), and
/// sign(τ)·r ([`DominanceParams::signed_reach`]; τ itself for the centre dominance). Within the
/// plateau (r = 0) ∂/∂τ is 0, as at τ = 0 without one.
#[inline(always)]
pub fn log_dominance_grad(
    inv_alpha: f64,
    theta: f64,
    c: f64,
    signed_reach: f64,
    power: f64,
    ln_abs_tau: f64,
) -> LogDominanceGrad {
    let d_tau = if signed_reach != 0.0 {
        -theta * c * power / signed_reach
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

    /// The same θ and c on both sides (one lane: the side does not matter).
    fn sym(log_alpha: f64, theta: f64, c: f64) -> DominanceParams {
        DominanceParams {
            log_alpha,
            theta_bw: theta,
            theta_fw: theta,
            c_bw: c,
            c_fw: c,
            plateau: 0.0,
        }
    }

    fn ld(log_alpha: f64, theta: f64, c: f64, abs_tau: f64) -> LogDominance<f64> {
        log_dominance::<f64, true>(&sym(log_alpha, theta, c), true, abs_tau)
    }

    #[test]
    fn value_matches_definition() {
        let v = ld(0.3f64.ln(), 20.0, 0.7, 0.05);
        let direct = (0.3 * (-20.0 * 0.05f64.powf(0.7)).exp()).ln();
        assert!((v.log_d - direct).abs() < 1e-13);
    }

    #[test]
    fn sides_take_their_own_rate_and_exponent() {
        let d = DominanceParams {
            log_alpha: 0.0,
            theta_bw: 10.0,
            theta_fw: 30.0,
            c_bw: 1.0,
            c_fw: 2.0,
            plateau: 0.0,
        };
        let tau = [-0.1, 0.1];
        let got = tau.map(|t| log_dominance_value::<f64, true>(&d, backward(t), t.abs()));
        assert!((got[0] - (-10.0 * 0.1)).abs() < 1e-15);
        assert!((got[1] - (-30.0 * 0.01)).abs() < 1e-15);
        assert!(backward(0.0) && !backward(1e-300));
    }

    #[test]
    fn value_only_form_is_bitwise_equal() {
        for &(c_bw, c_fw, a) in &[
            (1.0, 1.0, 0.037),
            (0.73, 0.73, 0.2),
            (2.4, 2.4, 1e-5),
            (1.0, 1.0, 0.0),
            (0.5, 0.5, 0.0),
            (1.0, 0.5, 0.3),
            (0.5, 1.0, 0.3),
        ] {
            let d = DominanceParams {
                log_alpha: 0.2,
                theta_bw: 33.0,
                theta_fw: 21.0,
                c_bw,
                c_fw,
                plateau: 0.0,
            };
            for bw in [true, false] {
                let full = log_dominance::<f64, true>(&d, bw, a).log_d;
                let value = log_dominance_value::<f64, true>(&d, bw, a);
                assert_eq!(full.to_bits(), value.to_bits());
            }
        }
        assert_eq!(ld(0.0, 10.0, 1.0, 0.25).power, 0.25);
    }

    #[test]
    fn finite_at_zero_with_c_below_one() {
        let v = ld(0.0, 20.0, 0.5, 0.0);
        let g = log_dominance_grad(1.0, 20.0, 0.5, 0.0, v.power, v.ln_abs_tau);
        assert_eq!(v.log_d, 0.0);
        assert_eq!((v.power, v.ln_abs_tau), (0.0, 0.0));
        assert_eq!(g.d_c, 0.0);
        assert_eq!(g.d_tau, 0.0);
        assert!(g.d_theta == 0.0);
    }

    #[test]
    fn tau_derivative_matches_difference() {
        for &tau in &[-0.07, 0.03] {
            let (theta, c) = (15.0, 1.7);
            let f = |t: f64| ld(0.0, theta, c, t.abs()).log_d;
            let h = 1e-6;
            let fd = (f(tau + h) - f(tau - h)) / (2.0 * h);
            let v = ld(0.0, theta, c, tau.abs());
            let g = log_dominance_grad(1.0, theta, c, tau, v.power, v.ln_abs_tau);
            assert!(
                (g.d_tau - fd).abs() < 1e-6 * fd.abs().max(1.0),
                "{} vs {}",
                g.d_tau,
                fd
            );
        }
    }

    #[test]
    fn theta_and_c_derivatives_match_differences() {
        let (la, theta, c, a) = (0.1, 12.0, 1.3, 0.08);
        let h = 1e-6;
        let v = ld(la, theta, c, a);
        let g = log_dominance_grad(1.0, theta, c, a, v.power, v.ln_abs_tau);
        let fd_theta = (ld(la, theta + h, c, a).log_d - ld(la, theta - h, c, a).log_d) / (2.0 * h);
        let fd_c = (ld(la, theta, c + h, a).log_d - ld(la, theta, c - h, a).log_d) / (2.0 * h);
        assert!(
            (g.d_theta - fd_theta).abs() < 1e-8,
            "{} vs {fd_theta}",
            g.d_theta
        );
        assert!((g.d_c - fd_c).abs() < 1e-7, "{} vs {fd_c}", g.d_c);
    }

    #[test]
    fn plateau_holds_alpha_then_decays_from_its_edge() {
        let d = DominanceParams {
            plateau: 0.05,
            ..sym(0.3, 20.0, 1.5)
        };
        for a in [0.0, 0.02, 0.05] {
            let v = log_dominance::<f64, true>(&d, true, a);
            assert_eq!((v.log_d, v.power, v.ln_abs_tau), (0.3, 0.0, 0.0));
            assert_eq!(d.signed_reach::<true>(a), 0.0);
        }
        let v = log_dominance::<f64, true>(&d, false, 0.09);
        assert!((v.log_d - (0.3 - 20.0 * 0.04f64.powf(1.5))).abs() < 1e-14);
        assert_eq!(
            v.log_d.to_bits(),
            log_dominance_value::<f64, true>(&d, false, 0.09).to_bits()
        );
        assert!((d.signed_reach::<true>(-0.09) + 0.04).abs() < 1e-16);
        // ∂/∂τ through the reach: −θ c r^(c−1) sign(τ).
        for tau in [-0.09, 0.08] {
            let f = |t: f64| log_dominance::<f64, true>(&d, t <= 0.0, t.abs()).log_d;
            let h = 1e-7;
            let fd = (f(tau + h) - f(tau - h)) / (2.0 * h);
            let v = log_dominance::<f64, true>(&d, tau <= 0.0, f64::abs(tau));
            let g = log_dominance_grad(
                1.0,
                20.0,
                1.5,
                d.signed_reach::<true>(tau),
                v.power,
                v.ln_abs_tau,
            );
            assert!((g.d_tau - fd).abs() < 1e-6, "{} vs {fd}", g.d_tau);
        }
        // Without a plateau the reach is |τ| and sign(τ)·r is τ, bit for bit.
        let c = sym(0.3, 20.0, 1.5);
        assert_eq!(c.reach::<f64, true>(0.0371).to_bits(), 0.0371f64.to_bits());
        assert_eq!(
            c.signed_reach::<true>(-0.0371).to_bits(),
            (-0.0371f64).to_bits()
        );
    }
}
