//! One utterance: F together with its exact derivatives with respect to every per-phoneme
//! parameter and β (MODEL.md §4).
//!
//! With P_i = R_i D_i / Σ_j R_j D_j and V_i = T_i S_i, F = Σ P_i V_i and
//! ∂F/∂(ln R_i D_i) = P_i (V_i − F). Every parameter acts through ln D_i, ln R_i or S_i of its
//! own segments, except k_R and δ, which also act through the extents Δ± of the neighbours
//! (§3.1) and, for δ, the target time t_i; those go through the reverse-mode derivative of the
//! extent recursion ([`Resistance::extents_adjoint`]), O(N) per sample.

use crate::dominance::{log_dominance, log_dominance_grad, LogDominance, Side};
use crate::model::Prepared;
use crate::params::{Param, N_PARAMS};
use crate::resistance::{LogResistance, Resistance};
use crate::shape::{Shape, ShapeValue};

/// The state of one (sample, segment) pair between the value pass and the derivative pass.
#[derive(Clone, Copy, Debug)]
struct Pair {
    active: bool,
    tau: f64,
    log_w: f64,
    /// Normalised weight P_i.
    p: f64,
    ld: LogDominance,
    lr: LogResistance,
    sv: ShapeValue,
}

impl Default for Pair {
    fn default() -> Self {
        Pair {
            active: false,
            tau: 0.0,
            log_w: f64::NEG_INFINITY,
            p: 0.0,
            ld: LogDominance::default(),
            lr: LogResistance::default(),
            sv: ShapeValue {
                s: 1.0,
                d_sigma: 0.0,
                d_psi: 0.0,
                d_tau: 0.0,
            },
        }
    }
}

/// Derivatives per segment of one utterance (or their weighted sum over samples).
///
/// Before [`SegmentGrads::finish`], `d[i][Delta]` holds ∂/∂t_i through τ only, `d[i][KR]` is 0,
/// and `g_fwd/g_bwd` hold ∂/∂Δ±_i; after it, `d[i]` is the total derivative with respect to the
/// parameters of segment i's phoneme (through this segment's occurrence).
#[derive(Clone, Debug, Default)]
pub(crate) struct SegmentGrads {
    pub d: Vec<[f64; N_PARAMS]>,
    pub g_fwd: Vec<f64>,
    pub g_bwd: Vec<f64>,
    d_k: Vec<f64>,
    d_t: Vec<f64>,
    /// ∂/∂β.
    pub beta: f64,
}

impl SegmentGrads {
    /// Zeroes and sizes the accumulators for `n` segments.
    pub fn reset(&mut self, n: usize) {
        if self.d.len() == n {
            // The common case (every sample of an utterance): zero in place.
            self.d.fill([0.0; N_PARAMS]);
            self.g_fwd.fill(0.0);
            self.g_bwd.fill(0.0);
        } else {
            self.d.clear();
            self.d.resize(n, [0.0; N_PARAMS]);
            self.g_fwd.clear();
            self.g_fwd.resize(n, 0.0);
            self.g_bwd.clear();
            self.g_bwd.resize(n, 0.0);
            self.d_k.resize(n, 0.0);
            self.d_t.resize(n, 0.0);
        }
        self.beta = 0.0;
    }

    /// Propagates ∂/∂Δ± and ∂/∂t_i to k_R and δ (linear, so it may run once on a weighted sum).
    pub fn finish(&mut self, prep: &Prepared, res: Resistance) {
        let n = self.d.len();
        for i in 0..n {
            self.d_t[i] = self.d[i][Param::Delta.index()];
            self.d_k[i] = 0.0;
        }
        res.extents_adjoint(
            &prep.k,
            &prep.ext_fwd,
            &prep.ext_bwd,
            &self.g_fwd,
            &self.g_bwd,
            &mut self.d_k,
            &mut self.d_t,
        );
        for i in 0..n {
            self.d[i][Param::KR.index()] = self.d_k[i];
            self.d[i][Param::Delta.index()] = if prep.free[i] { self.d_t[i] } else { 0.0 };
        }
    }
}

/// Per-worker scratch for the derivative passes.
#[derive(Clone, Debug, Default)]
pub(crate) struct GradScratch {
    pairs: Vec<Pair>,
    value: f64,
}

impl GradScratch {
    /// Value pass at one time: F, keeping every pair's pieces for [`GradScratch::accumulate`].
    /// `None` if every weight vanishes.
    pub fn value_at(
        &mut self,
        prep: &Prepared,
        time: f64,
        beta: f64,
        res: Resistance,
        shape: Shape,
    ) -> Option<f64> {
        let n = prep.seg.len();
        self.pairs.resize(n, Pair::default());
        let mut max_lw = f64::NEG_INFINITY;
        for (s, pair) in prep.seg.iter().zip(self.pairs.iter_mut()) {
            let tau = time - s.t;
            let a = tau.abs();
            let (theta, c, ext) = match Side::of(tau) {
                Side::Backward => (s.theta_bw, s.c_bw, s.ext_bwd),
                Side::Forward => (s.theta_fw, s.c_fw, s.ext_fwd),
            };
            pair.tau = tau;
            match res.log_value_grad(a, ext, beta) {
                None => {
                    pair.active = false;
                }
                Some(lr) => {
                    let ld = log_dominance(s.log_alpha, theta, c, a);
                    let lw = lr.log_r + ld.log_d;
                    pair.active = lw != f64::NEG_INFINITY;
                    pair.ld = ld;
                    pair.lr = lr;
                    pair.log_w = lw;
                    if lw > max_lw {
                        max_lw = lw;
                    }
                }
            }
        }
        if max_lw == f64::NEG_INFINITY {
            return None;
        }
        let mut num = 0.0;
        let mut den = 0.0;
        for (s, pair) in prep.seg.iter().zip(self.pairs.iter_mut()) {
            if !pair.active {
                continue;
            }
            let w = (pair.log_w - max_lw).exp();
            if w == 0.0 {
                // Underflowed: contributes nothing, and its derivative factors may be huge.
                pair.active = false;
                continue;
            }
            pair.p = w;
            pair.sv = shape.value_grad(pair.tau, s.sigma, s.psi);
            num += w * s.target * pair.sv.s;
            den += w;
        }
        let inv_den = 1.0 / den;
        for pair in self.pairs.iter_mut().filter(|p| p.active) {
            pair.p *= inv_den;
        }
        // num / den, not num × (1/den): the same rounding as `Prepared::value_at`, so the
        // values returned with the Jacobian equal those of `evaluate` bit for bit.
        self.value = num / den;
        Some(self.value)
    }

    /// Adds `scale` × ∂F/∂(every parameter) at the last [`GradScratch::value_at`] to `grads`.
    pub fn accumulate(&self, prep: &Prepared, scale: f64, grads: &mut SegmentGrads) {
        let f = self.value;
        for (i, (s, pair)) in prep.seg.iter().zip(self.pairs.iter()).enumerate() {
            if !pair.active {
                continue;
            }
            let sp = scale * pair.p;
            // ∂F/∂(ln w_i), scaled.
            let a = sp * (s.target * pair.sv.s - f);
            let side = Side::of(pair.tau);
            let (theta, c) = match side {
                Side::Backward => (s.theta_bw, s.c_bw),
                Side::Forward => (s.theta_fw, s.c_fw),
            };
            let dg = log_dominance_grad(s.inv_alpha, theta, c, pair.tau, &pair.ld);
            let sign = if pair.tau > 0.0 {
                1.0
            } else if pair.tau < 0.0 {
                -1.0
            } else {
                0.0
            };
            let d = &mut grads.d[i];
            d[Param::Target.index()] += sp * pair.sv.s;
            d[Param::Alpha.index()] += a * dg.d_alpha;
            let (ti, ci) = match side {
                Side::Backward => (Param::ThetaBw.index(), Param::CBw.index()),
                Side::Forward => (Param::ThetaFw.index(), Param::CFw.index()),
            };
            d[ti] += a * dg.d_theta;
            d[ci] += a * dg.d_c;
            d[Param::Sigma.index()] += sp * s.target * pair.sv.d_sigma;
            d[Param::Psi.index()] += sp * s.target * pair.sv.d_psi;
            // τ = t − t_i, so ∂/∂t_i = −∂/∂τ.
            let d_log_w_d_tau = dg.d_tau + pair.lr.d_abs_tau * sign;
            d[Param::Delta.index()] -= a * d_log_w_d_tau + sp * s.target * pair.sv.d_tau;
            match side {
                Side::Backward => grads.g_bwd[i] += a * pair.lr.d_extent,
                Side::Forward => grads.g_fwd[i] += a * pair.lr.d_extent,
            }
            grads.beta += a * pair.lr.d_beta;
        }
    }
}
