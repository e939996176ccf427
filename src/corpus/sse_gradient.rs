//! SSE = Σ w (y − F)² with its exact gradient, without building the Jacobian.

use super::{blocks, check_len, validate_observations, Corpus};
use crate::alloc::try_filled;
use crate::error::ModelError;
use crate::gradient::{GradScratch, UtteranceGrads};
use crate::model::Prepared;
use crate::params::{validate_params, ModelOptions, N_PARAMS};

/// SSE = Σ w (y − F)² (MODEL.md §5) and its exact gradient with respect to the flattened
/// parameter matrix (into `grad_out`, length n_phonemes × 10) and β (returned), without building
/// the Jacobian: per-segment derivative sums weighted by −2 w (y − F) are pushed through the
/// extent recursion once per utterance. Samples with weight 0 are skipped (their observed value
/// may be NaN).
#[allow(clippy::too_many_arguments)]
pub fn sse_gradient(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    observed: &[f64],
    weights: &[f64],
    grad_out: &mut [f64],
) -> Result<(f64, f64), ModelError> {
    validate_params(params, corpus.n_phonemes, beta, opts)?;
    validate_observations(corpus, observed, weights)?;
    check_len(
        "grad_out (n_phonemes * 10)",
        grad_out.len(),
        corpus.n_phonemes * N_PARAMS,
    )?;
    let res = opts.variant.resistance();
    let shape = opts.variant.shape();
    let n_grad = grad_out.len();
    let parts = corpus.map_chunks(|chunk| -> Result<(f64, f64, Vec<f64>), ModelError> {
        let mut prep = Prepared::default();
        let mut scratch = GradScratch::default();
        let mut grads = UtteranceGrads::default();
        let mut grad = try_filled(n_grad, 0.0, || {
            format!(
                "the SSE gradient of one task ({} phonemes × 10)",
                corpus.n_phonemes
            )
        })?;
        let mut sse = 0.0;
        let mut d_beta = 0.0;
        for u in chunk {
            let samples = corpus.samples(u);
            if samples.clone().all(|n| weights[n] == 0.0) {
                continue;
            }
            corpus.prepare(&mut prep, u, params, opts);
            let segs = corpus.segments(u);
            let local = &corpus.seg_local[segs.clone()];
            let distinct = corpus.distinct(u);
            grads.reset(segs.len(), distinct.len());
            for block in blocks(samples) {
                let block_weights = &weights[block.clone()];
                if block_weights.iter().all(|&w| w == 0.0) {
                    continue;
                }
                let degenerate =
                    scratch.values_at(&prep, &corpus.sample_times[block.clone()], beta, res, shape);
                for (lane, (n, &w)) in block.zip(block_weights).enumerate() {
                    if w == 0.0 {
                        continue;
                    }
                    if degenerate & (1 << lane) != 0 {
                        return Err(ModelError::Degenerate {
                            utterance: u,
                            sample: n,
                        });
                    }
                    let r = observed[n] - scratch.value(lane);
                    sse += w * r * r;
                    scratch.accumulate(
                        &prep,
                        lane,
                        -2.0 * w * r,
                        beta,
                        res,
                        shape,
                        local,
                        &mut grads,
                    );
                }
            }
            grads.finish(&prep, res, local);
            for (l, &p) in distinct.iter().enumerate() {
                let from = &grads.row[l * N_PARAMS..(l + 1) * N_PARAMS];
                for (g, dk) in grad[p * N_PARAMS..(p + 1) * N_PARAMS].iter_mut().zip(from) {
                    *g += dk;
                }
            }
            d_beta += grads.beta();
        }
        Ok((sse, d_beta, grad))
    });
    grad_out.fill(0.0);
    let mut sse = 0.0;
    let mut d_beta = 0.0;
    for part in parts {
        let (s, b, g) = part?;
        sse += s;
        d_beta += b;
        for (o, v) in grad_out.iter_mut().zip(&g) {
            *o += v;
        }
    }
    Ok((sse, d_beta))
}
