//! F at every sample of the corpus, and the benchmark's physical-limit loop over the same pairs.

use super::{check_len, split_at_ends, Corpus};
use crate::error::ModelError;
use crate::model::Prepared;
use crate::params::{validate_params, ModelOptions};
use rayon::prelude::*;
use std::ops::Range;

/// Evaluates on validated input; the shared body of [`evaluate`] and the batches.
pub(super) fn evaluate_unchecked(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    out: &mut [f64],
) -> Result<(), ModelError> {
    let res = opts.variant.resistance();
    let shape = opts.variant.shape();
    let pieces = split_at_ends(
        out,
        0,
        corpus.chunks.iter().map(|c| corpus.sample_offsets[c.end]),
    );
    let work = |(chunk, piece): (&Range<usize>, &mut [f64])| -> Result<(), ModelError> {
        let mut prep = Prepared::default();
        let base = corpus.sample_offsets[chunk.start];
        for u in chunk.clone() {
            let samples = corpus.samples(u);
            if samples.is_empty() {
                continue;
            }
            corpus.prepare(&mut prep, u, params, opts);
            let local = samples.start - base..samples.end - base;
            prep.evaluate(
                &corpus.sample_times[samples.clone()],
                beta,
                res,
                shape,
                &mut piece[local],
            )
            .map_err(|n| ModelError::Degenerate {
                utterance: u,
                sample: samples.start + n,
            })?;
        }
        Ok(())
    };
    if corpus.parallel() {
        corpus
            .chunks
            .par_iter()
            .zip(pieces.into_par_iter())
            .map(work)
            .collect()
    } else {
        corpus.chunks.iter().zip(pieces).try_for_each(work)
    }
}

/// F at every sample of the corpus (MODEL.md eq. 3, or eq. 1 with [`crate::Variant::Original`]).
///
/// `params` is the `n_phonemes × 10` parameter matrix, row-major in the column order of
/// [`crate::Param`]; `out` has one value per sample, in corpus order.
pub fn evaluate(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    out: &mut [f64],
) -> Result<(), ModelError> {
    validate_params(params, corpus.n_phonemes, beta, opts)?;
    check_len("out (n_samples)", out.len(), corpus.n_samples())?;
    evaluate_unchecked(corpus, params, beta, opts, out)
}

/// The speed floor for the benchmark: a plain loop over exactly the (sample, segment) pairs that
/// [`evaluate`] visits (those inside the resistance extent), computing only the transcendental
/// functions the model needs there — ln|τ|, |τ|^c as exp(c ln|τ|), the weight exp, and the shape
/// exp where σ ≠ 0 — summed into a checksum; no normalisation. Parallel like [`evaluate`], with
/// the same kernels and lanes ([`crate::vector_math`]: four samples at a time with AVX2).
/// Returns NaN if the parameters are invalid.
pub fn physical_limit_loop(corpus: &Corpus, params: &[f64], opts: &ModelOptions) -> f64 {
    if validate_params(params, corpus.n_phonemes, 0.0, opts).is_err() {
        return f64::NAN;
    }
    let res = opts.variant.resistance();
    let shape = opts.variant.shape();
    corpus
        .map_chunks(|chunk| {
            let mut prep = Prepared::default();
            let mut sum = 0.0;
            for u in chunk {
                let samples = corpus.samples(u);
                if samples.is_empty() {
                    continue;
                }
                corpus.prepare(&mut prep, u, params, opts);
                sum += prep.limit_checksum(&corpus.sample_times[samples], res, shape);
            }
            sum
        })
        .into_iter()
        .sum()
}
