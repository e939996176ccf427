//! One utterance: the per-utterance precomputation (target times, extents, per-segment log α)
//! and the evaluation of F(t) at its samples, MODEL.md eq. 1 / eq. 3, normalised in the log
//! domain (log-sum-exp over segments) so that underflowing dominance never gives 0/0.

use crate::dominance::log_dominance_value;
use crate::params::{ModelOptions, Param, N_PARAMS};
use crate::resistance::Resistance;
use crate::shape::Shape;
use crate::targets::target_time;

/// Everything about one segment that the inner loop reads, laid out together.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SegmentModel {
    /// Target time t_i.
    pub t: f64,
    pub target: f64,
    /// 1/α, for ∂ ln D/∂α.
    pub inv_alpha: f64,
    pub log_alpha: f64,
    pub theta_bw: f64,
    pub theta_fw: f64,
    pub c_bw: f64,
    pub c_fw: f64,
    pub sigma: f64,
    pub psi: f64,
    /// Δ⁻_i and Δ⁺_i; +∞ where R ≡ 1 on that side (backward of the first segment, forward of
    /// the last, every side in the original model), which makes u = 0 and every derivative
    /// through the extent vanish.
    pub ext_bwd: f64,
    pub ext_fwd: f64,
    /// 1/Δ⁻_i and 1/Δ⁺_i (0 where Δ = +∞), for the derivatives.
    pub inv_bwd: f64,
    pub inv_fwd: f64,
}

/// Per-utterance precomputation, reused from utterance to utterance by one worker so the inner
/// loops never allocate.
#[derive(Clone, Debug, Default)]
pub(crate) struct Prepared {
    pub seg: Vec<SegmentModel>,
    /// Whether δ moves t_i (∂t_i/∂δ = 1) or t_i is clamped (0).
    pub free: Vec<bool>,
    /// t_i, k_R and the extents as separate arrays for the recursion and its adjoint.
    pub t: Vec<f64>,
    pub k: Vec<f64>,
    pub ext_fwd: Vec<f64>,
    pub ext_bwd: Vec<f64>,
    /// Per-sample scratch: ln(R·D) of each segment, −∞ where the pair is skipped.
    pub log_w: Vec<f64>,
}

impl Prepared {
    /// Fills the precomputation for the segments `starts/ends/phonemes` of one utterance.
    /// `params` is the full (validated) parameter matrix.
    pub fn prepare(
        &mut self,
        starts: &[f64],
        ends: &[f64],
        phonemes: &[usize],
        params: &[f64],
        opts: &ModelOptions,
    ) {
        let n = starts.len();
        let res = opts.variant.resistance();
        self.seg.clear();
        self.free.clear();
        self.t.clear();
        self.k.clear();
        for i in 0..n {
            let row = &params[phonemes[i] * N_PARAMS..(phonemes[i] + 1) * N_PARAMS];
            let (t, free) = target_time(
                starts[i],
                ends[i],
                opts.apex_fraction,
                row[Param::Delta.index()],
            );
            let alpha = row[Param::Alpha.index()];
            self.seg.push(SegmentModel {
                t,
                target: row[Param::Target.index()],
                inv_alpha: 1.0 / alpha,
                log_alpha: alpha.ln(),
                theta_bw: row[Param::ThetaBw.index()],
                theta_fw: row[Param::ThetaFw.index()],
                c_bw: row[Param::CBw.index()],
                c_fw: row[Param::CFw.index()],
                sigma: row[Param::Sigma.index()],
                psi: row[Param::Psi.index()],
                ext_bwd: f64::INFINITY,
                ext_fwd: f64::INFINITY,
                inv_bwd: 0.0,
                inv_fwd: 0.0,
            });
            self.free.push(free);
            self.t.push(t);
            self.k.push(if res.is_none() {
                0.0
            } else {
                row[Param::KR.index()]
            });
        }
        self.ext_fwd.resize(n, 0.0);
        self.ext_bwd.resize(n, 0.0);
        self.log_w.resize(n, 0.0);
        res.extents(
            &self.t,
            &self.k,
            opts.edge_extent,
            &mut self.ext_fwd,
            &mut self.ext_bwd,
        );
        if !res.is_none() {
            for i in 0..n {
                let s = &mut self.seg[i];
                if i > 0 {
                    s.ext_bwd = self.ext_bwd[i];
                    s.inv_bwd = 1.0 / s.ext_bwd;
                }
                if i + 1 < n {
                    s.ext_fwd = self.ext_fwd[i];
                    s.inv_fwd = 1.0 / s.ext_fwd;
                }
            }
        }
    }

    /// F at one time (eq. 1 or eq. 3); `None` only if every segment's weight is zero.
    #[inline]
    pub fn value_at(&mut self, time: f64, beta: f64, res: Resistance, shape: Shape) -> Option<f64> {
        let mut max_lw = f64::NEG_INFINITY;
        for (s, lw_out) in self.seg.iter().zip(self.log_w.iter_mut()) {
            let tau = time - s.t;
            let a = tau.abs();
            let (theta, c, ext) = if tau <= 0.0 {
                (s.theta_bw, s.c_bw, s.ext_bwd)
            } else {
                (s.theta_fw, s.c_fw, s.ext_fwd)
            };
            // R first: a pair beyond its extent costs no transcendental at all.
            let mut lw = res.log_value(a, ext, beta);
            if lw != f64::NEG_INFINITY {
                lw += log_dominance_value(s.log_alpha, theta, c, a);
                if lw > max_lw {
                    max_lw = lw;
                }
            }
            *lw_out = lw;
        }
        if max_lw == f64::NEG_INFINITY {
            return None;
        }
        let mut num = 0.0;
        let mut den = 0.0;
        for (s, &lw) in self.seg.iter().zip(self.log_w.iter()) {
            if lw == f64::NEG_INFINITY {
                continue;
            }
            let w = (lw - max_lw).exp();
            num += w * s.target * shape.value(time - s.t, s.sigma, s.psi);
            den += w;
        }
        Some(num / den)
    }

    /// Evaluates F at `times` into `out`; on failure returns the local index of the sample
    /// where every weight vanished.
    pub fn evaluate(
        &mut self,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
        out: &mut [f64],
    ) -> Result<(), usize> {
        for (n, (&time, o)) in times.iter().zip(out.iter_mut()).enumerate() {
            *o = self.value_at(time, beta, res, shape).ok_or(n)?;
        }
        Ok(())
    }

    /// The physical-limit loop for this utterance: the same (sample, segment) pairs as
    /// [`Prepared::value_at`], only the transcendental functions (ln|τ|, exp(c ln|τ|), the
    /// weight exp, the shape exp where σ ≠ 0; the power needs none where c = 1), summed into a
    /// checksum.
    pub fn limit_checksum(&self, times: &[f64], res: Resistance, shape: Shape) -> f64 {
        let mut sum = 0.0;
        let shaped = !matches!(shape, Shape::None);
        for &time in times {
            for s in &self.seg {
                let tau = time - s.t;
                let a = tau.abs();
                let (theta, c, ext) = if tau <= 0.0 {
                    (s.theta_bw, s.c_bw, s.ext_bwd)
                } else {
                    (s.theta_fw, s.c_fw, s.ext_fwd)
                };
                if !res.is_none() && a >= ext {
                    continue;
                }
                // Like the evaluator: no ln/exp for the power where c = 1.
                let power = if c == 1.0 { a } else { (c * a.ln()).exp() };
                sum += (s.log_alpha - theta * power).exp();
                if shaped && s.sigma != 0.0 {
                    sum += (-s.psi * tau * tau).exp();
                }
            }
        }
        sum
    }
}
