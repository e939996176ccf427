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

/// Derivatives of F (or of a weighted sum over samples) for one utterance, laid out like a
/// Jacobian row: parameter k of the l-th distinct phoneme of the utterance at `l * 10 + k`, β
/// last. A phoneme occurring in several segments gets the sum of its occurrences.
///
/// Before [`UtteranceGrads::finish`] the k_R and δ entries are incomplete: the per-segment
/// ∂/∂t_i (through τ) and ∂/∂Δ±_i are kept aside and pushed through the extent recursion there.
#[derive(Clone, Debug, Default)]
pub(crate) struct UtteranceGrads {
    pub row: Vec<f64>,
    d_t: Vec<f64>,
    g_fwd: Vec<f64>,
    g_bwd: Vec<f64>,
    d_k: Vec<f64>,
}

impl UtteranceGrads {
    /// Zeroes the accumulators for `n_segments` segments over `n_distinct` phonemes.
    pub fn reset(&mut self, n_segments: usize, n_distinct: usize) {
        let width = n_distinct * N_PARAMS + 1;
        if self.row.len() == width && self.d_t.len() == n_segments {
            // The common case (every sample of an utterance): zero in place.
            self.row.fill(0.0);
            self.d_t.fill(0.0);
            self.g_fwd.fill(0.0);
            self.g_bwd.fill(0.0);
        } else {
            self.row.clear();
            self.row.resize(width, 0.0);
            for v in [
                &mut self.d_t,
                &mut self.g_fwd,
                &mut self.g_bwd,
                &mut self.d_k,
            ] {
                v.clear();
                v.resize(n_segments, 0.0);
            }
        }
    }

    /// ∂/∂β.
    pub fn beta(&self) -> f64 {
        self.row[self.row.len() - 1]
    }

    /// Propagates ∂/∂Δ± and ∂/∂t_i to k_R and δ (linear, so it may run once on a weighted sum
    /// over samples). `local[i]` is the distinct-phoneme position of segment i.
    pub fn finish(&mut self, prep: &Prepared, res: Resistance, local: &[usize]) {
        self.d_k.fill(0.0);
        res.extents_adjoint(
            &prep.k,
            &prep.ext_fwd,
            &prep.ext_bwd,
            &self.g_fwd,
            &self.g_bwd,
            &mut self.d_k,
            &mut self.d_t,
        );
        for (i, &l) in local.iter().enumerate() {
            self.row[l * N_PARAMS + Param::KR.index()] += self.d_k[i];
            if prep.free[i] {
                self.row[l * N_PARAMS + Param::Delta.index()] += self.d_t[i];
            }
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
            let (theta, c, ext, inv) = match Side::of(tau) {
                Side::Backward => (s.theta_bw, s.c_bw, s.ext_bwd, s.inv_bwd),
                Side::Forward => (s.theta_fw, s.c_fw, s.ext_fwd, s.inv_fwd),
            };
            pair.tau = tau;
            match res.log_value_grad(a, ext, inv, beta) {
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
            let w = crate::vector_math::exp(pair.log_w - max_lw);
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
        // num / den, not num × (1/den): the same rounding as `Prepared::lanes_at`, so the
        // values returned with the Jacobian equal those of `evaluate` bit for bit.
        self.value = num / den;
        Some(self.value)
    }

    /// Adds `scale` × ∂F/∂(every parameter) at the last [`GradScratch::value_at`] to `grads`;
    /// `local[i]` is the distinct-phoneme position of segment i.
    pub fn accumulate(
        &self,
        prep: &Prepared,
        scale: f64,
        local: &[usize],
        grads: &mut UtteranceGrads,
    ) {
        let width = grads.row.len();
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
            let l = local[i] * N_PARAMS;
            let d = &mut grads.row[l..l + N_PARAMS];
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
            grads.d_t[i] -= a * d_log_w_d_tau + sp * s.target * pair.sv.d_tau;
            match side {
                Side::Backward => grads.g_bwd[i] += a * pair.lr.d_extent,
                Side::Forward => grads.g_fwd[i] += a * pair.lr.d_extent,
            }
            grads.row[width - 1] += a * pair.lr.d_beta;
        }
    }
}
