//! One utterance: the per-utterance precomputation (target times, extents, per-segment log α)
//! and the evaluation of F(t) at its samples, MODEL.md eq. 1 / eq. 3, normalised in the log
//! domain (log-sum-exp over segments) so that underflowing dominance never gives 0/0.

use crate::dominance::{
    backward, log_dominance, log_dominance_value, DominanceParams, LogDominance,
};
use crate::params::{Dominance, ModelOptions, Param, N_PARAMS};
use crate::resistance::{cutoff_log_value, CutoffValue, Resistance};
use crate::shape::{gaussian_exp, gaussian_shape, Shape};
use crate::targets::target_time;
use crate::vector_math::{exp_lanes, Lanes};
#[cfg(target_arch = "x86_64")]
use crate::vector_math::{simd_enabled, F64x4};

/// Lanes of the widest evaluation path (AVX2: four f64); the per-segment scratch holds this many
/// values per segment whatever path runs.
pub(crate) const LANES: usize = 4;

/// Everything about one segment that the inner loop reads, laid out together.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct SegmentModel {
    /// Target time t_i.
    pub t: f64,
    pub target: f64,
    /// 1/α, for ∂ ln D/∂α.
    pub inv_alpha: f64,
    /// ln α, θ and c of both sides.
    pub dom: DominanceParams,
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

/// What a value pass keeps of each (segment, lane) for a derivative pass, at the position `o` of
/// the segment-major scratch ([`LANES`] per segment). The evaluator keeps nothing (`()`: every
/// hook compiles away); the derivative passes' scratch keeps the pieces
/// ([`crate::gradient::GradScratch`]). Hooks are inlined into the caller, so they run under its
/// AVX2 target feature.
pub(crate) trait KeepPieces {
    /// Whether pieces are kept: then ln|τ| is taken even where c = 1 (∂/∂c needs it), exp(−ψτ²)
    /// even where σ = 0 (∂S/∂σ), and the pass leaves the normalised weights P_i in its `log_w`.
    const KEEP: bool;
    #[inline(always)]
    fn tau<V: Lanes>(&mut self, _o: usize, _tau: V) {}
    #[inline(always)]
    fn cutoff<V: Lanes>(&mut self, _o: usize, _value: &CutoffValue<V>) {}
    #[inline(always)]
    fn dominance<V: Lanes>(&mut self, _o: usize, _value: &LogDominance<V>) {}
    #[inline(always)]
    fn shape_exp<V: Lanes>(&mut self, _o: usize, _e: V) {}
}

impl KeepPieces for () {
    const KEEP: bool = false;
}

/// The value pass, written once for the evaluator and the derivative passes: F at the lanes of
/// `time` (eq. 1 or eq. 3) and the lanes where every segment's weight is zero (degenerate: F
/// undefined there). `log_w` is per-(segment, lane) scratch, segment-major with [`LANES`] per
/// segment, these lanes starting at `at`: ln(R·D) during the pass (−∞ where the pair is
/// skipped); with `K::KEEP`, the normalised weights P_i after it (0 where the pair is skipped or
/// its weight underflowed). The same operation sequence per lane whatever the lane count and
/// whatever is kept, so every instantiation agrees bit for bit.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(crate) fn value_pass<V: Lanes, const RATE: bool, K: KeepPieces>(
    seg: &[SegmentModel],
    time: V,
    beta: f64,
    res: Resistance,
    shape: Shape,
    log_w: &mut [f64],
    at: usize,
    keep: &mut K,
) -> (V, V::Mask) {
    let s = V::splat;
    let zero = s(0.0);
    let one = s(1.0);
    let neg_inf = s(f64::NEG_INFINITY);
    let mut max_lw = neg_inf;
    for (i, g) in seg.iter().enumerate() {
        let o = i * LANES + at;
        let tau = time.sub(s(g.t));
        keep.tau(o, tau);
        let a = tau.abs();
        let bw = backward(tau);
        let lr = match res {
            Resistance::None => zero,
            Resistance::Cutoff => {
                // The side's extent selected inside this arm: hoisted above the match, the mask
                // stays live across the branches and costs a conversion per pair.
                let ext = V::select(bw, s(g.ext_bwd), s(g.ext_fwd));
                let cv = cutoff_log_value(a, ext, beta);
                keep.cutoff(o, &cv);
                cv.log_r
            }
        };
        let active = lr.ne(neg_inf);
        if !V::any(active) {
            // Every lane beyond the extent: no transcendental function for this segment.
            neg_inf.store(&mut log_w[o..]);
            continue;
        }
        let ld = if K::KEEP {
            let ld = log_dominance::<V, RATE>(&g.dom, bw, a);
            keep.dominance(o, &ld);
            ld.log_d
        } else {
            log_dominance_value::<V, RATE>(&g.dom, bw, a)
        };
        let lw = V::select(active, lr.add(ld), neg_inf);
        max_lw = V::select(lw.gt(max_lw), lw, max_lw);
        lw.store(&mut log_w[o..]);
    }
    let degenerate = max_lw.eq(neg_inf);
    let mut num = zero;
    let mut den = zero;
    for (i, g) in seg.iter().enumerate() {
        let o = i * LANES + at;
        let lw = V::load(&log_w[o..]);
        let active = lw.ne(neg_inf);
        if !V::any(active) {
            if K::KEEP {
                zero.store(&mut log_w[o..]);
            }
            continue;
        }
        let w = exp_lanes(lw.sub(max_lw));
        let sv = match shape {
            Shape::Gaussian if K::KEEP => {
                let e = gaussian_exp(g.psi, time.sub(s(g.t)));
                keep.shape_exp(o, e);
                if g.sigma != 0.0 {
                    gaussian_shape(g.sigma, e)
                } else {
                    one
                }
            }
            _ => shape.value(time.sub(s(g.t)), g.sigma, g.psi),
        };
        num = V::select(active, num.add(w.mul(s(g.target)).mul(sv)), num);
        den = V::select(active, den.add(w), den);
        if K::KEEP {
            V::select(active, w, zero).store(&mut log_w[o..]);
        }
    }
    if K::KEEP {
        let inv_den = V::select(degenerate, zero, one.div(den));
        for i in 0..seg.len() {
            let o = i * LANES + at;
            V::load(&log_w[o..]).mul(inv_den).store(&mut log_w[o..]);
        }
    }
    (num.div(den), degenerate)
}

/// Per-utterance precomputation, reused from utterance to utterance by one worker so the inner
/// loops never allocate.
#[derive(Clone, Debug, Default)]
pub(crate) struct Prepared {
    pub seg: Vec<SegmentModel>,
    /// Whether δ moves t_i (∂t_i/∂δ = 1) or t_i is clamped (0).
    pub free: Vec<bool>,
    /// The segment whose phoneme gives segment i's forward θ_fw and c_fw: i + 1 with the
    /// handover option (MODEL.md §2.1; i for the last segment), else i. Their derivatives go to
    /// that phoneme's columns.
    pub fw: Vec<usize>,
    /// Whether a rate-aware option (MODEL.md §2.1) is on: the loops are instantiated twice, so
    /// that today's model (false) runs exactly today's instructions.
    pub rate_aware: bool,
    /// t_i, k_R and the extents as separate arrays for the recursion and its adjoint.
    pub t: Vec<f64>,
    pub k: Vec<f64>,
    pub ext_fwd: Vec<f64>,
    pub ext_bwd: Vec<f64>,
    /// Per-block scratch: ln(R·D) of each segment at each lane (segment-major, [`LANES`] per
    /// segment), −∞ where the pair is skipped.
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
        let plateau = match opts.dominance {
            Dominance::Centre => 0.0,
            Dominance::Plateau => opts.plateau_fraction,
        };
        self.rate_aware = plateau != 0.0 || opts.handover;
        self.seg.clear();
        self.free.clear();
        self.fw.clear();
        self.t.clear();
        self.k.clear();
        for i in 0..n {
            let row = &params[phonemes[i] * N_PARAMS..(phonemes[i] + 1) * N_PARAMS];
            let fw = if opts.handover && i + 1 < n { i + 1 } else { i };
            let fw_row = &params[phonemes[fw] * N_PARAMS..(phonemes[fw] + 1) * N_PARAMS];
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
                dom: DominanceParams {
                    log_alpha: alpha.ln(),
                    theta_bw: row[Param::ThetaBw.index()],
                    theta_fw: fw_row[Param::ThetaFw.index()],
                    c_bw: row[Param::CBw.index()],
                    c_fw: fw_row[Param::CFw.index()],
                    // h·d_i, from the acoustic segment (independent of every parameter).
                    plateau: plateau * (ends[i] - starts[i]),
                },
                sigma: row[Param::Sigma.index()],
                psi: row[Param::Psi.index()],
                ext_bwd: f64::INFINITY,
                ext_fwd: f64::INFINITY,
                inv_bwd: 0.0,
                inv_fwd: 0.0,
            });
            self.free.push(free);
            self.fw.push(fw);
            self.t.push(t);
            self.k.push(if res.is_none() {
                0.0
            } else {
                row[Param::KR.index()]
            });
        }
        self.ext_fwd.resize(n, 0.0);
        self.ext_bwd.resize(n, 0.0);
        self.log_w.resize(n * LANES, 0.0);
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

    /// Evaluates F at `times` into `out`, [`LANES`] samples at a time where AVX2 is available.
    /// A degenerate sample (every weight zero) gets NaN and is reported to `bad` with its local
    /// index, in order; `bad` decides whether that is an error.
    pub fn evaluate_with<E>(
        &mut self,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
        out: &mut [f64],
        bad: impl FnMut(usize) -> Result<(), E>,
    ) -> Result<(), E> {
        #[cfg(target_arch = "x86_64")]
        if simd_enabled() {
            // SAFETY: AVX2 was detected at run time.
            return unsafe {
                if self.rate_aware {
                    self.evaluate_avx2::<E, true>(times, beta, res, shape, out, bad)
                } else {
                    self.evaluate_avx2::<E, false>(times, beta, res, shape, out, bad)
                }
            };
        }
        if self.rate_aware {
            self.evaluate_lanes::<f64, E, true>(times, beta, res, shape, out, bad)
        } else {
            self.evaluate_lanes::<f64, E, false>(times, beta, res, shape, out, bad)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn evaluate_avx2<E, const RATE: bool>(
        &mut self,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
        out: &mut [f64],
        bad: impl FnMut(usize) -> Result<(), E>,
    ) -> Result<(), E> {
        self.evaluate_lanes::<F64x4, E, RATE>(times, beta, res, shape, out, bad)
    }

    #[inline(always)]
    fn evaluate_lanes<V: Lanes, E, const RATE: bool>(
        &mut self,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
        out: &mut [f64],
        mut bad: impl FnMut(usize) -> Result<(), E>,
    ) -> Result<(), E> {
        let n = times.len();
        let mut k = 0;
        while k < n {
            let m = V::N.min(n - k);
            // A short last block repeats its last time in the spare lanes (results dropped).
            let mut t = [times[k + m - 1]; LANES];
            t[..m].copy_from_slice(&times[k..k + m]);
            let (f, degenerate) = value_pass::<V, RATE, ()>(
                &self.seg,
                V::load(&t),
                beta,
                res,
                shape,
                &mut self.log_w,
                0,
                &mut (),
            );
            let mut v = [0.0; LANES];
            f.store(&mut v);
            let deg = V::bits(degenerate);
            for j in 0..m {
                if deg & (1 << j) != 0 {
                    out[k + j] = f64::NAN;
                    bad(k + j)?;
                } else {
                    out[k + j] = v[j];
                }
            }
            k += m;
        }
        Ok(())
    }

    /// Evaluates F at `times` into `out`; on failure returns the local index of the first
    /// sample where every weight vanished.
    pub fn evaluate(
        &mut self,
        times: &[f64],
        beta: f64,
        res: Resistance,
        shape: Shape,
        out: &mut [f64],
    ) -> Result<(), usize> {
        self.evaluate_with(times, beta, res, shape, out, Err)
    }

    /// The physical-limit loop for this utterance: the same (sample block, segment) pairs as
    /// [`Prepared::evaluate`] visits, with the same kernels and lane count, computing only the
    /// transcendental functions (ln|τ| and exp(c ln|τ|) where c ≠ 1, the weight exp, the shape
    /// exp where σ ≠ 0), summed into a checksum over the lanes inside the extent.
    pub fn limit_checksum(&self, times: &[f64], res: Resistance, shape: Shape) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if simd_enabled() {
            // SAFETY: AVX2 was detected at run time.
            return unsafe {
                if self.rate_aware {
                    self.limit_avx2::<true>(times, res, shape)
                } else {
                    self.limit_avx2::<false>(times, res, shape)
                }
            };
        }
        if self.rate_aware {
            self.limit_lanes::<f64, true>(times, res, shape)
        } else {
            self.limit_lanes::<f64, false>(times, res, shape)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn limit_avx2<const RATE: bool>(&self, times: &[f64], res: Resistance, shape: Shape) -> f64 {
        self.limit_lanes::<F64x4, RATE>(times, res, shape)
    }

    #[inline(always)]
    fn limit_lanes<V: Lanes, const RATE: bool>(
        &self,
        times: &[f64],
        res: Resistance,
        shape: Shape,
    ) -> f64 {
        let s = V::splat;
        let zero = s(0.0);
        let shaped = !matches!(shape, Shape::None);
        let mut total = 0.0;
        let mut k = 0;
        while k < times.len() {
            let m = V::N.min(times.len() - k);
            let mut t = [times[k + m - 1]; LANES];
            t[..m].copy_from_slice(&times[k..k + m]);
            let time = V::load(&t);
            let mut sum = zero;
            for g in &self.seg {
                let tau = time.sub(s(g.t));
                let a = tau.abs();
                let bw = backward(tau);
                // The pairs the evaluator keeps: R ≡ 1, or |τ| inside the side's extent.
                let inside = if res.is_none() {
                    a.eq(a)
                } else {
                    a.lt(V::select(bw, s(g.ext_bwd), s(g.ext_fwd)))
                };
                if !V::any(inside) {
                    continue;
                }
                let mut v = exp_lanes(log_dominance_value::<V, RATE>(&g.dom, bw, a));
                if shaped && g.sigma != 0.0 {
                    v = v.add(gaussian_exp(g.psi, tau));
                }
                sum = V::select(inside, sum.add(v), sum);
            }
            let mut lanes = [0.0; LANES];
            sum.store(&mut lanes);
            total += lanes[..m].iter().sum::<f64>();
            k += m;
        }
        total
    }
}
