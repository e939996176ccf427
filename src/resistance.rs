//! Resistance R_i(τ) of MODEL.md §3.1: the cut-off ρ(u) = exp(−β u / (1 − u)) for 0 ≤ u < 1,
//! 0 for u ≥ 1, with u = |τ| / Δ±_i, and the extents Δ⁺/Δ⁻ from the k_R recursion.
//!
//! The closed form sits behind [`Resistance`] so that another one (a published formula 4 of
//! Cosi & Perin, or a variant under test) is one more enum arm, not a change to the evaluator.
//! The value is written once over [`Lanes`] ([`cutoff_log_value`], inlined into the evaluator,
//! the gradient's value pass and the unit tests); the derivatives are scalar ([`cutoff_grad`]),
//! as the gradient's derivative pass is.

use crate::vector_math::Lanes;

/// The resistance closed form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Resistance {
    /// R ≡ 1 (MODEL.md eq. 1, the original model).
    None,
    /// MODEL.md §3.1: ρ(u) = exp(−β u/(1−u)) below the extent, 0 beyond it.
    Cutoff,
}

/// ln R at one (sample, segment) pair and its partial derivatives.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LogResistance {
    /// ln R (≤ 0).
    pub log_r: f64,
    /// ∂ ln R / ∂Δ (the extent of the side the sample is on).
    pub d_extent: f64,
    /// ∂ ln R / ∂|τ|.
    pub d_abs_tau: f64,
    /// ∂ ln R / ∂β.
    pub d_beta: f64,
}

/// ln R of the cut-off on some lanes, with u = |τ|/Δ for the derivatives.
#[derive(Clone, Copy)]
pub(crate) struct CutoffValue<V> {
    /// ln ρ(u) = −β u/(1 − u); 0 at τ = 0, −∞ where u ≥ 1 (R = 0: the pair is skipped).
    pub log_r: V,
    pub u: V,
}

impl<V: Lanes> CutoffValue<V> {
    /// q = 1/(1 − u), for [`cutoff_grad`].
    #[inline(always)]
    pub fn q(&self) -> V {
        let one = V::splat(1.0);
        one.div(one.sub(self.u))
    }
}

/// ln R of MODEL.md §3.1 on the lanes of |τ| = `abs_tau` against the extent Δ of each lane's side
/// (+∞ where R ≡ 1 on that side: u = 0).
///
/// u is |τ|/Δ by division, not by a reciprocal: at the next target of a k_R = 1 phoneme,
/// |τ| and Δ are the same difference t_{i+1} − t_i and u must be exactly 1. One division for
/// ln ρ (the vectorised evaluator is bounded by the divider).
#[inline(always)]
pub(crate) fn cutoff_log_value<V: Lanes>(abs_tau: V, extent: V, beta: f64) -> CutoffValue<V> {
    let s = V::splat;
    let zero = s(0.0);
    let one = s(1.0);
    let u = abs_tau.div(extent);
    let v = s(-beta).mul(u).div(one.sub(u));
    let log_r = V::select(
        abs_tau.eq(zero),
        zero,
        V::select(u.ge(one), s(f64::NEG_INFINITY), v),
    );
    CutoffValue { log_r, u }
}

/// The derivatives of ln R for the cut-off given u = |τ|/Δ < 1 and q = 1/(1 − u), 0 < |τ| (the
/// gradient's value pass keeps them from [`cutoff_log_value`]); `log_r` is left 0. `None` where
/// 1 − u is so small that q² overflows: ρ is 0 to machine precision there.
#[inline(always)]
pub(crate) fn cutoff_grad(u: f64, q: f64, inv_extent: f64, beta: f64) -> Option<LogResistance> {
    let d_u = -beta * q * q;
    if !d_u.is_finite() {
        return None;
    }
    Some(LogResistance {
        log_r: 0.0,
        // u = |τ|/Δ: ∂u/∂Δ = −u/Δ, ∂u/∂|τ| = 1/Δ.
        d_extent: -d_u * u * inv_extent,
        d_abs_tau: d_u * inv_extent,
        d_beta: -u * q,
    })
}

impl Resistance {
    /// Whether R is identically 1 (no extents needed, no k_R or β dependence).
    #[inline(always)]
    pub fn is_none(self) -> bool {
        matches!(self, Resistance::None)
    }

    /// ln R and its derivatives at one pair; `None` where R = 0 (u ≥ 1), where ρ is C∞ and every
    /// derivative is 0. `inv_extent` is 1/Δ (0 for Δ = +∞), precomputed per segment. The
    /// composition of [`cutoff_log_value`] and [`cutoff_grad`] that the gradient makes.
    pub fn log_value_grad(
        self,
        abs_tau: f64,
        extent: f64,
        inv_extent: f64,
        beta: f64,
    ) -> Option<LogResistance> {
        match self {
            Resistance::None => Some(LogResistance::default()),
            Resistance::Cutoff => {
                let v = cutoff_log_value::<f64>(abs_tau, extent, beta);
                if abs_tau == 0.0 {
                    return Some(LogResistance::default());
                }
                if v.log_r == f64::NEG_INFINITY {
                    return None;
                }
                let mut lr = cutoff_grad(v.u, v.q(), inv_extent, beta)?;
                lr.log_r = v.log_r;
                Some(lr)
            }
        }
    }

    /// The extents of MODEL.md §3.1 for one utterance, from its target times `t` (sorted) and the
    /// resistance `k` of each segment's phoneme:
    /// Δ⁺_i = (t_{i+1} − t_i) + (1 − k_{i+1}) Δ⁺_{i+1}, Δ⁺_N = Λ;
    /// Δ⁻_i = (t_i − t_{i−1}) + (1 − k_{i−1}) Δ⁻_{i−1}, Δ⁻_1 = Λ.
    /// With [`Resistance::None`] every extent is +∞.
    pub fn extents(self, t: &[f64], k: &[f64], edge: f64, fwd: &mut [f64], bwd: &mut [f64]) {
        let n = t.len();
        debug_assert!(k.len() == n && fwd.len() == n && bwd.len() == n);
        if n == 0 {
            return;
        }
        match self {
            Resistance::None => {
                fwd.fill(f64::INFINITY);
                bwd.fill(f64::INFINITY);
            }
            Resistance::Cutoff => {
                fwd[n - 1] = edge;
                for i in (0..n - 1).rev() {
                    fwd[i] = (t[i + 1] - t[i]) + (1.0 - k[i + 1]) * fwd[i + 1];
                }
                bwd[0] = edge;
                for i in 1..n {
                    bwd[i] = (t[i] - t[i - 1]) + (1.0 - k[i - 1]) * bwd[i - 1];
                }
            }
        }
    }

    /// Reverse-mode derivative of the extents: given g⁺_i = ∂L/∂Δ⁺_i and g⁻_i = ∂L/∂Δ⁻_i (partial,
    /// holding the other extents fixed), adds the total ∂L/∂k_i to `d_k` and ∂L/∂t_i to `d_t`.
    /// O(N): the recursion is differentiated, not the N² matrix of ∂Δ/∂k.
    #[allow(clippy::too_many_arguments)]
    pub fn extents_adjoint(
        self,
        k: &[f64],
        fwd: &[f64],
        bwd: &[f64],
        g_fwd: &[f64],
        g_bwd: &[f64],
        d_k: &mut [f64],
        d_t: &mut [f64],
    ) {
        if self.is_none() {
            return;
        }
        let n = k.len();
        if n < 2 {
            return;
        }
        // Δ⁺_{i−1} contains (1 − k_i) Δ⁺_i, so the total adjoint flows forward in i.
        let mut acc = g_fwd[0];
        d_k[1] -= acc * fwd[1];
        d_t[1] += acc;
        d_t[0] -= acc;
        for i in 1..n - 1 {
            acc = g_fwd[i] + (1.0 - k[i]) * acc;
            d_k[i + 1] -= acc * fwd[i + 1];
            d_t[i + 1] += acc;
            d_t[i] -= acc;
        }
        let mut acc = g_bwd[n - 1];
        d_k[n - 2] -= acc * bwd[n - 2];
        d_t[n - 1] += acc;
        d_t[n - 2] -= acc;
        for i in (1..n - 1).rev() {
            acc = g_bwd[i] + (1.0 - k[i]) * acc;
            d_k[i - 1] -= acc * bwd[i - 1];
            d_t[i] += acc;
            d_t[i - 1] -= acc;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ln R at one pair, both sides with the same extent.
    fn lv(r: Resistance, abs_tau: f64, extent: f64, beta: f64) -> f64 {
        match r {
            Resistance::None => 0.0,
            Resistance::Cutoff => cutoff_log_value::<f64>(abs_tau, extent, beta).log_r,
        }
    }

    #[test]
    fn rho_is_exponential_near_zero_and_zero_beyond() {
        let r = Resistance::Cutoff;
        assert_eq!(lv(r, 0.0, 0.1, 2.0), 0.0);
        assert_eq!(lv(r, 0.1, 0.1, 2.0), f64::NEG_INFINITY);
        assert_eq!(lv(r, 0.2, 0.1, 2.0), f64::NEG_INFINITY);
        let v = lv(r, 0.05, 0.1, 2.0);
        assert!((v - (-2.0 * 0.5 / 0.5)).abs() < 1e-15);
        assert!(r.log_value_grad(0.1, 0.1, 10.0, 2.0).is_none());
        // No resistance on this side (Δ = +∞), and a zero extent.
        assert_eq!(lv(r, 0.3, f64::INFINITY, 2.0), 0.0);
        let g = r.log_value_grad(0.3, f64::INFINITY, 0.0, 2.0).unwrap();
        assert_eq!((g.d_extent, g.d_abs_tau, g.d_beta), (0.0, 0.0, 0.0));
        assert_eq!(lv(r, 0.01, 0.0, 2.0), f64::NEG_INFINITY);
        assert_eq!(lv(r, 0.0, 0.0, 2.0), 0.0);
    }

    #[test]
    fn extents_follow_recursion() {
        let t = [0.1, 0.3, 0.4, 0.7];
        let k = [0.2, 1.0, 0.5, 0.0];
        let mut f = [0.0; 4];
        let mut b = [0.0; 4];
        Resistance::Cutoff.extents(&t, &k, 1.0, &mut f, &mut b);
        assert!((f[3] - 1.0).abs() < 1e-15);
        assert!((f[2] - (0.3 + 1.0)).abs() < 1e-15);
        assert!((f[1] - (0.1 + 0.5 * 1.3)).abs() < 1e-15);
        assert!((f[0] - 0.2).abs() < 1e-15, "k = 1 next: extent is the gap");
        assert!((b[0] - 1.0).abs() < 1e-15);
        assert!((b[1] - (0.2 + 0.8)).abs() < 1e-15);
        assert!((b[2] - 0.1).abs() < 1e-15);
        assert!((b[3] - (0.3 + 0.5 * 0.1)).abs() < 1e-15);
    }

    #[test]
    fn adjoint_matches_differences() {
        let t = [0.1, 0.3, 0.4, 0.7, 0.75];
        let k = [0.2, 0.9, 0.5, 0.1, 0.6];
        let gf = [0.3, -1.0, 0.7, 2.0, 0.0];
        let gb = [0.0, 0.4, -0.2, 1.1, 0.5];
        let loss = |t: &[f64], k: &[f64]| {
            let mut f = [0.0; 5];
            let mut b = [0.0; 5];
            Resistance::Cutoff.extents(t, k, 1.3, &mut f, &mut b);
            (0..5).map(|i| gf[i] * f[i] + gb[i] * b[i]).sum::<f64>()
        };
        let mut f = [0.0; 5];
        let mut b = [0.0; 5];
        Resistance::Cutoff.extents(&t, &k, 1.3, &mut f, &mut b);
        let mut dk = [0.0; 5];
        let mut dt = [0.0; 5];
        Resistance::Cutoff.extents_adjoint(&k, &f, &b, &gf, &gb, &mut dk, &mut dt);
        let h = 1e-6;
        for j in 0..5 {
            let (mut kp, mut km) = (k, k);
            kp[j] += h;
            km[j] -= h;
            let fd = (loss(&t, &kp) - loss(&t, &km)) / (2.0 * h);
            assert!((fd - dk[j]).abs() < 1e-8, "k{j}: {fd} vs {}", dk[j]);
            let (mut tp, mut tm) = (t, t);
            tp[j] += h;
            tm[j] -= h;
            let fd = (loss(&tp, &k) - loss(&tm, &k)) / (2.0 * h);
            assert!((fd - dt[j]).abs() < 1e-8, "t{j}: {fd} vs {}", dt[j]);
        }
    }
}
