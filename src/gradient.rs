//! One utterance: F together with its exact derivatives with respect to every per-phoneme
//! parameter and β (MODEL.md §4).
//!
//! With P_i = R_i D_i / Σ_j R_j D_j and V_i = T_i S_i, F = Σ P_i V_i and
//! ∂F/∂(ln R_i D_i) = P_i (V_i − F). Every parameter acts through ln D_i, ln R_i or S_i of its
//! own segments, except k_R and δ, which also act through the extents Δ± of the neighbours
//! (§3.1) and, for δ, the target time t_i; those go through the reverse-mode derivative of the
//! extent recursion ([`Resistance::extents_adjoint`]), O(N) per sample.

use crate::dominance::{log_dominance_grad, LogDominance, Side};
use crate::model::{value_pass, KeepPieces, Prepared, LANES};
use crate::params::{Param, N_PARAMS};
use crate::resistance::{cutoff_grad, CutoffValue, LogResistance, Resistance};
use crate::shape::Shape;
use crate::vector_math::Lanes;
#[cfg(target_arch = "x86_64")]
use crate::vector_math::{simd_enabled, F64x4};

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

/// The pieces of the value pass that the scalar derivative pass needs, per (segment, lane),
/// segment-major with [`LANES`] per segment, so no transcendental function is computed twice.
#[derive(Clone, Debug, Default)]
struct Pieces {
    /// τ.
    tau: Vec<f64>,
    /// ln|τ|, 0 at τ = 0 (where it only multiplies |τ|^c = 0).
    ln_abs_tau: Vec<f64>,
    /// |τ|^c.
    power: Vec<f64>,
    /// u = |τ|/Δ and q = 1/(1 − u) of the sample's side (cut-off resistance only).
    u: Vec<f64>,
    q: Vec<f64>,
    /// exp(−ψ τ²) (Gaussian shape only).
    shape_exp: Vec<f64>,
}

impl KeepPieces for Pieces {
    const KEEP: bool = true;
    #[inline(always)]
    fn tau<V: Lanes>(&mut self, o: usize, tau: V) {
        tau.store(&mut self.tau[o..]);
    }
    #[inline(always)]
    fn cutoff<V: Lanes>(&mut self, o: usize, value: &CutoffValue<V>) {
        value.u.store(&mut self.u[o..]);
        value.q().store(&mut self.q[o..]);
    }
    #[inline(always)]
    fn dominance<V: Lanes>(&mut self, o: usize, value: &LogDominance<V>) {
        value.ln_abs_tau.store(&mut self.ln_abs_tau[o..]);
        value.power.store(&mut self.power[o..]);
    }
    #[inline(always)]
    fn shape_exp<V: Lanes>(&mut self, o: usize, e: V) {
        e.store(&mut self.shape_exp[o..]);
    }
}

/// Per-worker scratch for the derivative passes: the value pass ([`value_pass`], the evaluator's
/// own, so the values agree bit for bit) runs [`LANES`] samples at a time and keeps the
/// [`Pieces`] the scalar derivative pass needs.
#[derive(Clone, Debug, Default)]
pub(crate) struct GradScratch {
    pieces: Pieces,
    /// The normalised weight P_i per (segment, lane); 0 where the pair is skipped (beyond the
    /// extent) or its weight underflowed (its derivative factors may be huge).
    p: Vec<f64>,
    /// F at each lane of the last block.
    values: [f64; LANES],
}

impl GradScratch {
    /// Value pass at up to [`LANES`] times (a short block is padded with its last time): F at
    /// each, kept for [`GradScratch::value`] and [`GradScratch::accumulate`]. Returns the bits
    /// (lane j at bit j) of the lanes where every weight vanishes (F undefined there).
    pub fn values_at(
        &mut self,
        prep: &Prepared,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
    ) -> u32 {
        let m = times.len();
        debug_assert!((1..=LANES).contains(&m));
        let len = prep.seg.len() * LANES;
        let k = &mut self.pieces;
        for v in [
            &mut k.tau,
            &mut k.ln_abs_tau,
            &mut k.power,
            &mut self.p,
            &mut k.u,
            &mut k.q,
            &mut k.shape_exp,
        ] {
            v.resize(len, 0.0);
        }
        let mut t = [times[m - 1]; LANES];
        t[..m].copy_from_slice(times);
        #[cfg(target_arch = "x86_64")]
        if simd_enabled() {
            // SAFETY: AVX2 was detected at run time.
            let bits = unsafe {
                if prep.rate_aware {
                    self.values_avx2::<true>(prep, &t, beta, res, shape)
                } else {
                    self.values_avx2::<false>(prep, &t, beta, res, shape)
                }
            };
            return bits & ((1 << m) - 1);
        }
        let mut degenerate = 0;
        for (j, &time) in t[..m].iter().enumerate() {
            degenerate |= if prep.rate_aware {
                self.lanes_at::<f64, true>(prep, time, j, beta, res, shape)
            } else {
                self.lanes_at::<f64, false>(prep, time, j, beta, res, shape)
            } << j;
        }
        degenerate
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn values_avx2<const RATE: bool>(
        &mut self,
        prep: &Prepared,
        t: &[f64; LANES],
        beta: f64,
        res: Resistance,
        shape: Shape,
    ) -> u32 {
        self.lanes_at::<F64x4, RATE>(prep, F64x4::load(t), 0, beta, res, shape)
    }

    /// The value pass for the lanes `at..at + V::N`, keeping F and the pieces.
    #[inline(always)]
    fn lanes_at<V: Lanes, const RATE: bool>(
        &mut self,
        prep: &Prepared,
        time: V,
        at: usize,
        beta: f64,
        res: Resistance,
        shape: Shape,
    ) -> u32 {
        let (f, degenerate) = value_pass::<V, RATE, Pieces>(
            &prep.seg,
            time,
            beta,
            res,
            shape,
            &mut self.p,
            at,
            &mut self.pieces,
        );
        f.store(&mut self.values[at..]);
        V::bits(degenerate)
    }

    /// F at lane `lane` of the last [`GradScratch::values_at`] (num / den, the rounding of
    /// [`Prepared::evaluate`], so equal to it bit for bit).
    pub fn value(&self, lane: usize) -> f64 {
        self.values[lane]
    }

    /// Adds `scale` × ∂F/∂(every parameter) at lane `lane` of the last
    /// [`GradScratch::values_at`] to `grads`; `local[i]` is the distinct-phoneme position of
    /// segment i. The lane must not be degenerate.
    #[allow(clippy::too_many_arguments)]
    pub fn accumulate(
        &self,
        prep: &Prepared,
        lane: usize,
        scale: f64,
        beta: f64,
        res: Resistance,
        shape: Shape,
        local: &[usize],
        grads: &mut UtteranceGrads,
    ) {
        if prep.rate_aware {
            self.accumulate_with::<true>(prep, lane, scale, beta, res, shape, local, grads)
        } else {
            self.accumulate_with::<false>(prep, lane, scale, beta, res, shape, local, grads)
        }
    }

    /// [`GradScratch::accumulate`] with the rate-aware options (MODEL.md §2.1) compiled in or out.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn accumulate_with<const RATE: bool>(
        &self,
        prep: &Prepared,
        lane: usize,
        scale: f64,
        beta: f64,
        res: Resistance,
        shape: Shape,
        local: &[usize],
        grads: &mut UtteranceGrads,
    ) {
        let width = grads.row.len();
        let f = self.values[lane];
        for (i, s) in prep.seg.iter().enumerate() {
            let o = i * LANES + lane;
            let p = self.p[o];
            if p == 0.0 {
                continue;
            }
            let tau = self.pieces.tau[o];
            let side = Side::of(tau);
            let (theta, c, inv_ext) = match side {
                Side::Backward => (s.dom.theta_bw, s.dom.c_bw, s.inv_bwd),
                Side::Forward => (s.dom.theta_fw, s.dom.c_fw, s.inv_fwd),
            };
            let lr = if res.is_none() || tau == 0.0 {
                LogResistance::default()
            } else {
                match cutoff_grad(self.pieces.u[o], self.pieces.q[o], inv_ext, beta) {
                    Some(lr) => lr,
                    None => continue,
                }
            };
            let sv = shape.value_grad_from_exp(tau, s.sigma, s.psi, self.pieces.shape_exp[o]);
            let sp = scale * p;
            // ∂F/∂(ln w_i), scaled.
            let a = sp * (s.target * sv.s - f);
            let dg = log_dominance_grad(
                s.inv_alpha,
                theta,
                c,
                s.dom.signed_reach::<RATE>(tau),
                self.pieces.power[o],
                self.pieces.ln_abs_tau[o],
            );
            let sign = if tau > 0.0 {
                1.0
            } else if tau < 0.0 {
                -1.0
            } else {
                0.0
            };
            let l = local[i] * N_PARAMS;
            // The side's θ and c belong to the segment's phoneme, except the forward ones with
            // the handover option: those of the next segment's phoneme (prep.fw).
            let (l_side, ti, ci) = match side {
                Side::Backward => (l, Param::ThetaBw.index(), Param::CBw.index()),
                Side::Forward if RATE => (
                    local[prep.fw[i]] * N_PARAMS,
                    Param::ThetaFw.index(),
                    Param::CFw.index(),
                ),
                Side::Forward => (l, Param::ThetaFw.index(), Param::CFw.index()),
            };
            let d = &mut grads.row[l..l + N_PARAMS];
            d[Param::Target.index()] += sp * sv.s;
            d[Param::Alpha.index()] += a * dg.d_alpha;
            if RATE {
                grads.row[l_side + ti] += a * dg.d_theta;
                grads.row[l_side + ci] += a * dg.d_c;
            } else {
                d[ti] += a * dg.d_theta;
                d[ci] += a * dg.d_c;
            }
            let d = &mut grads.row[l..l + N_PARAMS];
            d[Param::Sigma.index()] += sp * s.target * sv.d_sigma;
            d[Param::Psi.index()] += sp * s.target * sv.d_psi;
            // τ = t − t_i, so ∂/∂t_i = −∂/∂τ.
            let d_log_w_d_tau = dg.d_tau + lr.d_abs_tau * sign;
            grads.d_t[i] -= a * d_log_w_d_tau + sp * s.target * sv.d_tau;
            match side {
                Side::Backward => grads.g_bwd[i] += a * lr.d_extent,
                Side::Forward => grads.g_fwd[i] += a * lr.d_extent,
            }
            grads.row[width - 1] += a * lr.d_beta;
        }
    }
}
