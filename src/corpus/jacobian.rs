//! The exact sparse Jacobian ∂F/∂(params, β) with the values, and its corpus-fixed pattern.

use super::{blocks, check_len, output_buffer, split_at_ends, Corpus};
use crate::alloc::try_with_capacity;
use crate::error::ModelError;
use crate::gradient::{GradScratch, UtteranceGrads};
use crate::model::Prepared;
use crate::params::{validate_params, ModelOptions, N_PARAMS};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::ops::Range;

/// A Jacobian in compressed-sparse-row form: row n is sample n, column `p * 10 + k` is parameter
/// k ([`crate::Param`] order) of phoneme p, the last column (`n_phonemes * 10`) is β. Column
/// indices are sorted within a row; a row stores every parameter of every distinct phoneme of
/// its utterance (explicit zeros included), so the pattern depends only on the corpus.
#[derive(Clone, Debug, PartialEq)]
pub struct SparseJacobian {
    /// Number of rows: the corpus's samples.
    pub n_rows: usize,
    /// Number of columns: n_phonemes × 10 + 1 (β last).
    pub n_cols: usize,
    /// Row pointers (length n_rows + 1): row n is `indices/data[indptr[n]..indptr[n + 1]]`.
    pub indptr: Vec<usize>,
    /// Column of each stored entry, sorted within each row.
    pub indices: Vec<usize>,
    /// Value of each stored entry.
    pub data: Vec<f64>,
}

/// The slices of one parallel task's rows: values, column indices, Jacobian data.
type JacobianPieces<'a> = (
    (&'a mut [f64], Option<&'a mut [MaybeUninit<usize>]>),
    &'a mut [MaybeUninit<f64>],
);

/// Values F (into `values_out`) and the exact Jacobian ∂F/∂(params, β) at every sample
/// (MODEL.md §4). A phoneme occurring several times in an utterance gets the sum of its
/// occurrences' derivatives. k_R and δ act through the neighbours' extents and the target
/// times; their columns include that. At τ = 0 exactly the derivative of |τ| is taken as 0
/// (see [`crate::dominance::LogDominanceGrad::d_tau`]).
pub fn jacobian(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    values_out: &mut [f64],
) -> Result<SparseJacobian, ModelError> {
    validate_params(params, corpus.n_phonemes, beta, opts)?;
    check_len(
        "values_out (n_samples)",
        values_out.len(),
        corpus.n_samples(),
    )?;
    let nnz = corpus.jacobian_nnz();
    let mut indices: Vec<usize> = output_buffer(nnz, || corpus.jacobian_what("column indices"))?;
    let mut data: Vec<f64> = output_buffer(nnz, || corpus.jacobian_what("values"))?;
    let indptr = corpus.jac_indptr.clone();
    fill_jacobian(
        corpus,
        params,
        beta,
        opts,
        values_out,
        Some(&mut indices.spare_capacity_mut()[..nnz]),
        &mut data.spare_capacity_mut()[..nnz],
    )?;
    // SAFETY: the rows of all chunks tile 0..nnz (indptr is built from the same row counts the
    // workers write), every worker wrote every element of its rows, and all succeeded.
    unsafe {
        indices.set_len(nnz);
        data.set_len(nnz);
    }
    Ok(SparseJacobian {
        n_rows: corpus.n_samples(),
        n_cols: corpus.n_phonemes * N_PARAMS + 1,
        indptr,
        indices,
        data,
    })
}

/// The Jacobian's values only, into a caller's buffer, for repeated calls (optimisers): the
/// sparsity pattern depends only on the corpus ([`Corpus::jacobian_indptr`],
/// [`Corpus::jacobian_indices`], equal to those [`jacobian`] returns), so reusing `data_out`
/// saves allocating and first-touching tens of MB per call. `data_out` has
/// [`Corpus::jacobian_nnz`] entries.
pub fn jacobian_values(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    values_out: &mut [f64],
    data_out: &mut [f64],
) -> Result<(), ModelError> {
    validate_params(params, corpus.n_phonemes, beta, opts)?;
    check_len(
        "values_out (n_samples)",
        values_out.len(),
        corpus.n_samples(),
    )?;
    check_len(
        "data_out (Jacobian nnz)",
        data_out.len(),
        corpus.jacobian_nnz(),
    )?;
    // SAFETY: f64 has no invalid bit patterns and no drop; the workers only write initialised
    // values through this view.
    let data = unsafe { &mut *(data_out as *mut [f64] as *mut [MaybeUninit<f64>]) };
    fill_jacobian(corpus, params, beta, opts, values_out, None, data)
}

/// Writes values, Jacobian entries and (if given) column indices of every row, in parallel over
/// chunks of utterances. On success every element of `indices` and `data` has been written.
fn fill_jacobian(
    corpus: &Corpus,
    params: &[f64],
    beta: f64,
    opts: &ModelOptions,
    values_out: &mut [f64],
    indices: Option<&mut [MaybeUninit<usize>]>,
    data: &mut [MaybeUninit<f64>],
) -> Result<(), ModelError> {
    let n_cols = corpus.n_phonemes * N_PARAMS + 1;
    let indptr = &corpus.jac_indptr;
    let res = opts.variant.resistance();
    let shape = opts.variant.shape();
    let chunk_ends = || corpus.chunks.iter().map(|c| corpus.sample_offsets[c.end]);
    let value_pieces = split_at_ends(values_out, 0, chunk_ends());
    let index_pieces: Vec<Option<&mut [MaybeUninit<usize>]>> = match indices {
        Some(idx) => split_at_ends(idx, 0, chunk_ends().map(|s| indptr[s]))
            .into_iter()
            .map(Some)
            .collect(),
        None => corpus.chunks.iter().map(|_| None).collect(),
    };
    let data_pieces = split_at_ends(data, 0, chunk_ends().map(|s| indptr[s]));
    let work = |(chunk, ((values, mut idx), dat)): (&Range<usize>, JacobianPieces)| -> Result<(), ModelError> {
        let mut prep = Prepared::default();
        let mut scratch = GradScratch::default();
        let mut grads = UtteranceGrads::default();
        let mut pattern: Vec<usize> = Vec::new();
        let base = corpus.sample_offsets[chunk.start];
        let nz_base = indptr[base];
        for u in chunk.clone() {
            let samples = corpus.samples(u);
            if samples.is_empty() {
                continue;
            }
            corpus.prepare(&mut prep, u, params, opts);
            let segs = corpus.segments(u);
            let distinct = corpus.distinct(u);
            let row_nnz = corpus.row_nnz(u);
            pattern.clear();
            for &p in distinct {
                pattern.extend((0..N_PARAMS).map(|k| p * N_PARAMS + k));
            }
            pattern.push(n_cols - 1);
            let local = &corpus.seg_local[segs.clone()];
            for block in blocks(samples) {
                let degenerate =
                    scratch.values_at(&prep, &corpus.sample_times[block.clone()], beta, res, shape);
                if degenerate != 0 {
                    return Err(ModelError::Degenerate {
                        utterance: u,
                        sample: block.start + degenerate.trailing_zeros() as usize,
                    });
                }
                for (lane, n) in block.enumerate() {
                    let row = indptr[n] - nz_base..indptr[n] - nz_base + row_nnz;
                    if let Some(idx) = idx.as_deref_mut() {
                        for (dst, &src) in idx[row.clone()].iter_mut().zip(&pattern) {
                            dst.write(src);
                        }
                    }
                    values[n - base] = scratch.value(lane);
                    // The derivatives are summed in a small buffer laid out like the row, then
                    // written once: the output is fresh memory, where a second pass costs more
                    // than the arithmetic.
                    grads.reset(segs.len(), distinct.len());
                    scratch.accumulate(&prep, lane, 1.0, beta, res, shape, local, &mut grads);
                    grads.finish(&prep, res, local);
                    for (dst, &src) in dat[row].iter_mut().zip(&grads.row) {
                        dst.write(src);
                    }
                }
            }
        }
        Ok(())
    };
    let pieces = value_pieces.into_iter().zip(index_pieces).zip(data_pieces);
    if corpus.parallel() {
        corpus
            .chunks
            .par_iter()
            .zip(pieces.collect::<Vec<_>>().into_par_iter())
            .map(work)
            .collect::<Result<(), ModelError>>()
    } else {
        corpus.chunks.iter().zip(pieces).try_for_each(work)
    }
}

impl Corpus {
    /// Row pointers of the Jacobian (length n_samples + 1), as [`jacobian`] returns them.
    pub fn jacobian_indptr(&self) -> &[usize] {
        &self.jac_indptr
    }

    /// Number of stored Jacobian entries (the length of `data_out` of [`jacobian_values`]).
    pub fn jacobian_nnz(&self) -> usize {
        self.jac_indptr[self.jac_indptr.len() - 1]
    }

    /// Column indices of the Jacobian, as [`jacobian`] returns them: every parameter of every
    /// distinct phoneme of the row's utterance, then β; sorted within each row.
    /// [`ModelError::OutOfMemory`] if they do not fit in memory.
    pub fn jacobian_indices(&self) -> Result<Vec<usize>, ModelError> {
        let n_cols = self.n_phonemes * N_PARAMS + 1;
        let mut out =
            try_with_capacity(self.jacobian_nnz(), || self.jacobian_what("column indices"))?;
        for u in 0..self.n_utterances() {
            for _ in self.samples(u) {
                for &p in self.distinct(u) {
                    out.extend((0..N_PARAMS).map(|k| p * N_PARAMS + k));
                }
                out.push(n_cols - 1);
            }
        }
        Ok(out)
    }

    /// "the Jacobian's {part}: n samples, up to k distinct phonemes × 10 + β per row", for
    /// [`ModelError::OutOfMemory`].
    pub fn jacobian_what(&self, part: &str) -> String {
        let widest = (0..self.n_utterances())
            .map(|u| self.uniq_offsets[u + 1] - self.uniq_offsets[u])
            .max()
            .unwrap_or(0);
        format!(
            "the Jacobian's {part} ({} samples; up to {widest} distinct phonemes in an \
             utterance, 10 parameters each, and beta per row)",
            self.n_samples()
        )
    }

    /// Largest number of segments in one utterance.
    pub fn max_segments(&self) -> usize {
        self.max_segments
    }
}
