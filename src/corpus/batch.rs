//! The walkers × corpus batches of MCMC: F, SSE, and SSE with per-utterance residual sums for
//! W parameter sets at once, parallel over walkers.

use super::evaluate::evaluate_unchecked;
use super::{check_len, validate_observations, Corpus};
use crate::alloc::product;
use crate::error::ModelError;
use crate::model::Prepared;
use crate::params::{validate_params, ModelOptions, N_PARAMS};
use rayon::prelude::*;

/// "the output of a batch: W walkers × n samples", for [`ModelError::OutOfMemory`].
pub fn batch_what(walkers: usize, n: usize, of: &str) -> String {
    format!("the output of a batch ({walkers} walkers × {n} {of})")
}

fn check_batch(corpus: &Corpus, params_batch: &[f64], betas: &[f64]) -> Result<usize, ModelError> {
    let per = corpus.n_phonemes * N_PARAMS;
    let w = betas.len();
    check_len(
        "params_batch (n_walkers * n_phonemes * 10, n_walkers = len(betas))",
        params_batch.len(),
        w.saturating_mul(per),
    )?;
    Ok(per)
}

/// F for W parameter sets at once (MCMC walkers): `params_batch` is W stacked parameter matrices,
/// `betas` their β, `out` is W × n_samples (row-major). Parallel over walkers and utterances.
/// An invalid walker is an error naming it ([`ModelError::InWalker`]).
pub fn evaluate_batch(
    corpus: &Corpus,
    params_batch: &[f64],
    betas: &[f64],
    opts: &ModelOptions,
    out: &mut [f64],
) -> Result<(), ModelError> {
    let per = check_batch(corpus, params_batch, betas)?;
    let ns = corpus.n_samples();
    let expected = product::<f64>(betas.len(), ns, || batch_what(betas.len(), ns, "samples"))?;
    check_len("out (n_walkers * n_samples)", out.len(), expected)?;
    for (walker, &beta) in betas.iter().enumerate() {
        validate_params(
            &params_batch[walker * per..(walker + 1) * per],
            corpus.n_phonemes,
            beta,
            opts,
        )
        .map_err(|e| ModelError::InWalker {
            walker,
            source: Box::new(e),
        })?;
    }
    if ns == 0 {
        return Ok(());
    }
    out.par_chunks_mut(ns)
        .enumerate()
        .map(|(walker, o)| {
            evaluate_unchecked(
                corpus,
                &params_batch[walker * per..(walker + 1) * per],
                betas[walker],
                opts,
                o,
            )
            .map_err(|e| ModelError::InWalker {
                walker,
                source: Box::new(e),
            })
        })
        .collect()
}

/// SSE on validated parameters, without storing F; when `per_utterance` is given (one slot per
/// utterance), each utterance's weighted residual sum Σ w (y − F) goes into it as well.
fn sse_unchecked(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    observed: &[f64],
    weights: &[f64],
    mut per_utterance: Option<&mut [f64]>,
) -> Option<f64> {
    let res = opts.variant.resistance();
    let shape = opts.variant.shape();
    let want_sums = per_utterance.is_some();
    let parts = corpus.map_chunks(|chunk| -> Option<(f64, Vec<f64>)> {
        let mut prep = Prepared::default();
        let mut f = Vec::new();
        let mut sse = 0.0;
        let mut sums = Vec::with_capacity(if want_sums { chunk.len() } else { 0 });
        for u in chunk {
            let samples = corpus.samples(u);
            let mut sum = 0.0;
            if !samples.is_empty() {
                corpus.prepare(&mut prep, u, params, opts);
                f.resize(samples.len(), 0.0);
                let (w, y) = (&weights[samples.clone()], &observed[samples.clone()]);
                // A degenerate sample only matters where it is weighted.
                prep.evaluate_with(
                    &corpus.sample_times[samples],
                    beta,
                    res,
                    shape,
                    &mut f,
                    |n| if w[n] == 0.0 { Ok(()) } else { Err(()) },
                )
                .ok()?;
                for ((&w, &y), &f) in w.iter().zip(y).zip(&f) {
                    if w != 0.0 {
                        let r = y - f;
                        sse += w * r * r;
                        sum += w * r;
                    }
                }
            }
            if want_sums {
                sums.push(sum);
            }
        }
        Some((sse, sums))
    });
    let mut sse = 0.0;
    let mut at = 0;
    for part in parts {
        let (part_sse, sums) = part?;
        sse += part_sse;
        if let Some(out) = per_utterance.as_deref_mut() {
            out[at..at + sums.len()].copy_from_slice(&sums);
            at += sums.len();
        }
    }
    Some(sse)
}

/// SSE = Σ w (y − F)² for W parameter sets at once (the MCMC fast path). A walker whose
/// parameters are invalid (outside their domain, non-finite) or degenerate gets +∞, not an
/// error; `observed`/`weights` and the array lengths are still checked.
pub fn sse_batch(
    corpus: &Corpus,
    params_batch: &[f64],
    betas: &[f64],
    opts: &ModelOptions,
    observed: &[f64],
    weights: &[f64],
    out: &mut [f64],
) -> Result<(), ModelError> {
    opts.validate()?;
    let per = check_batch(corpus, params_batch, betas)?;
    validate_observations(corpus, observed, weights)?;
    check_len("out (n_walkers)", out.len(), betas.len())?;
    out.par_iter_mut().enumerate().for_each(|(walker, o)| {
        let params = &params_batch[walker * per..(walker + 1) * per];
        let beta = betas[walker];
        *o = match validate_params(params, corpus.n_phonemes, beta, opts) {
            Ok(()) => sse_unchecked(corpus, params, beta, opts, observed, weights, None)
                .unwrap_or(f64::INFINITY),
            Err(_) => f64::INFINITY,
        };
    });
    Ok(())
}

/// [`sse_batch`] plus each utterance's weighted residual sum Σ w (y − F) per walker, into `sums`
/// (W × n_utterances, row-major): what a likelihood with a random offset per utterance needs. A
/// walker whose parameters are invalid or degenerate gets SSE +∞ and NaN sums.
#[allow(clippy::too_many_arguments)]
pub fn residual_sums_batch(
    corpus: &Corpus,
    params_batch: &[f64],
    betas: &[f64],
    opts: &ModelOptions,
    observed: &[f64],
    weights: &[f64],
    sse: &mut [f64],
    sums: &mut [f64],
) -> Result<(), ModelError> {
    opts.validate()?;
    let per = check_batch(corpus, params_batch, betas)?;
    validate_observations(corpus, observed, weights)?;
    check_len("sse (n_walkers)", sse.len(), betas.len())?;
    let nu = corpus.n_utterances();
    let expected = product::<f64>(betas.len(), nu, || {
        batch_what(betas.len(), nu, "utterances")
    })?;
    check_len("sums (n_walkers * n_utterances)", sums.len(), expected)?;
    if nu == 0 {
        sse.fill(0.0);
        return Ok(());
    }
    sse.par_iter_mut()
        .zip(sums.par_chunks_mut(nu))
        .enumerate()
        .for_each(|(walker, (o, row))| {
            let params = &params_batch[walker * per..(walker + 1) * per];
            let beta = betas[walker];
            let value = match validate_params(params, corpus.n_phonemes, beta, opts) {
                Ok(()) => sse_unchecked(
                    corpus,
                    params,
                    beta,
                    opts,
                    observed,
                    weights,
                    Some(&mut *row),
                ),
                Err(_) => None,
            };
            *o = value.unwrap_or(f64::INFINITY);
            if value.is_none() {
                row.fill(f64::NAN);
            }
        });
    Ok(())
}
