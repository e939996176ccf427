//! Many utterances at once: the [`Corpus`] (CSR layout of docs/ARCHITECTURE.md, validated once)
//! and the batch entry points — evaluation, sparse Jacobian, SSE with its gradient, and the
//! walkers × corpus batches for MCMC — parallel with rayon over chunks of utterances.

use crate::alloc::{product, try_filled, try_with_capacity};
use crate::error::ModelError;
use crate::gradient::{GradScratch, UtteranceGrads};
use crate::model::{Prepared, LANES};
use crate::params::{validate_params, ModelOptions, N_PARAMS};
use rayon::prelude::*;
use std::mem::MaybeUninit;
use std::ops::Range;

/// Work per parallel task, in (sample, segment) pairs: big enough to amortise rayon's scheduling,
/// small enough to balance ~600 utterances over a few cores.
const CHUNK_PAIRS: usize = 8192;

/// Many utterances in compressed-sparse-row form (docs/ARCHITECTURE.md, "Corpus layout"):
/// segments of utterance u are `seg_offsets[u]..seg_offsets[u+1]`, its samples
/// `sample_offsets[u]..sample_offsets[u+1]`. Validated once by [`Corpus::new`]; every evaluation
/// then trusts it.
#[derive(Clone, Debug)]
pub struct Corpus {
    seg_offsets: Vec<usize>,
    seg_phoneme: Vec<usize>,
    seg_start: Vec<f64>,
    seg_end: Vec<f64>,
    sample_offsets: Vec<usize>,
    sample_times: Vec<f64>,
    n_phonemes: usize,
    /// Sorted distinct phonemes of each utterance (CSR by `uniq_offsets`): the Jacobian columns
    /// an utterance's rows touch.
    uniq_offsets: Vec<usize>,
    uniq_phonemes: Vec<usize>,
    /// For each segment, the position of its phoneme in its utterance's distinct list.
    seg_local: Vec<usize>,
    /// Utterance ranges of the parallel tasks.
    chunks: Vec<Range<usize>>,
    total_pairs: usize,
    max_segments: usize,
    /// Row pointers of the Jacobian (its pattern depends only on the corpus).
    jac_indptr: Vec<usize>,
}

fn check_offsets(what: &'static str, offsets: &[usize], len: usize) -> Result<(), ModelError> {
    if offsets.is_empty() {
        return Err(ModelError::LengthMismatch {
            what,
            got: 0,
            expected: 1,
        });
    }
    if offsets[0] != 0 {
        return Err(ModelError::BadOffsets {
            what,
            index: 0,
            value: offsets[0],
            reason: "must start at 0",
        });
    }
    for (i, w) in offsets.windows(2).enumerate() {
        if w[1] < w[0] {
            return Err(ModelError::BadOffsets {
                what,
                index: i + 1,
                value: w[1],
                reason: "offsets must be non-decreasing",
            });
        }
    }
    let last = offsets.len() - 1;
    if offsets[last] != len {
        return Err(ModelError::BadOffsets {
            what,
            index: last,
            value: offsets[last],
            reason: "the last offset must equal the length of the array it indexes",
        });
    }
    Ok(())
}

fn check_finite(what: &'static str, values: &[f64]) -> Result<(), ModelError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(ModelError::NonFiniteTime {
            what,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

impl Corpus {
    /// Builds and validates a corpus. Errors name the array and the utterance / segment / sample
    /// at fault: mismatched lengths, offsets not starting at 0, decreasing or not ending at the
    /// array length, non-finite times, segments with end ≤ start, unsorted or overlapping
    /// segments, phoneme index ≥ `n_phonemes`, an utterance with samples but no segments.
    /// Sample times may lie outside the segments (the model extends beyond them); an utterance
    /// with no samples is fine.
    pub fn new(
        seg_offsets: Vec<usize>,
        seg_phoneme: Vec<usize>,
        seg_start: Vec<f64>,
        seg_end: Vec<f64>,
        sample_offsets: Vec<usize>,
        sample_times: Vec<f64>,
        n_phonemes: usize,
    ) -> Result<Corpus, ModelError> {
        let n_seg = seg_phoneme.len();
        for (what, got) in [("seg_start", seg_start.len()), ("seg_end", seg_end.len())] {
            if got != n_seg {
                return Err(ModelError::LengthMismatch {
                    what,
                    got,
                    expected: n_seg,
                });
            }
        }
        if sample_offsets.len() != seg_offsets.len() {
            return Err(ModelError::LengthMismatch {
                what: "sample_offsets (n_utterances + 1, as seg_offsets)",
                got: sample_offsets.len(),
                expected: seg_offsets.len(),
            });
        }
        check_offsets("seg_offsets", &seg_offsets, n_seg)?;
        check_offsets("sample_offsets", &sample_offsets, sample_times.len())?;
        check_finite("seg_start", &seg_start)?;
        check_finite("seg_end", &seg_end)?;
        check_finite("sample_times", &sample_times)?;
        if n_phonemes
            .checked_mul(N_PARAMS)
            .and_then(|n| n.checked_add(1))
            .is_none()
        {
            return Err(ModelError::BadGlobal {
                name: "n_phonemes",
                value: n_phonemes as f64,
                domain: "small enough that n_phonemes * 10 + 1 columns can be indexed",
            });
        }
        let n_utt = seg_offsets.len() - 1;
        let mut uniq_offsets = Vec::with_capacity(n_utt + 1);
        uniq_offsets.push(0);
        let mut uniq_phonemes = Vec::new();
        let mut seg_local = vec![0usize; n_seg];
        let mut chunks = Vec::new();
        let mut chunk_start = 0;
        let mut chunk_pairs = 0;
        let mut total_pairs = 0;
        let mut max_segments = 0;
        for u in 0..n_utt {
            let segs = seg_offsets[u]..seg_offsets[u + 1];
            let n_samples = sample_offsets[u + 1] - sample_offsets[u];
            if segs.is_empty() && n_samples > 0 {
                return Err(ModelError::NoSegments {
                    utterance: u,
                    n_samples,
                });
            }
            for g in segs.clone() {
                let segment = g - segs.start;
                if seg_end[g] <= seg_start[g] {
                    return Err(ModelError::EmptySegment {
                        utterance: u,
                        segment,
                        global: g,
                        start: seg_start[g],
                        end: seg_end[g],
                    });
                }
                if segment > 0 && seg_start[g] < seg_end[g - 1] {
                    return Err(ModelError::OverlappingSegments {
                        utterance: u,
                        segment,
                        global: g,
                        start: seg_start[g],
                        previous_end: seg_end[g - 1],
                    });
                }
                if seg_phoneme[g] >= n_phonemes {
                    return Err(ModelError::PhonemeOutOfRange {
                        utterance: u,
                        segment,
                        global: g,
                        phoneme: seg_phoneme[g],
                        n_phonemes,
                    });
                }
            }
            let first = uniq_phonemes.len();
            let mut distinct: Vec<usize> = seg_phoneme[segs.clone()].to_vec();
            distinct.sort_unstable();
            distinct.dedup();
            for g in segs.clone() {
                seg_local[g] = distinct.binary_search(&seg_phoneme[g]).unwrap_or(0);
            }
            uniq_phonemes.extend_from_slice(&distinct);
            uniq_offsets.push(first + distinct.len());
            max_segments = max_segments.max(segs.len());
            let pairs = n_samples * segs.len() + segs.len();
            total_pairs += pairs;
            chunk_pairs += pairs;
            if chunk_pairs >= CHUNK_PAIRS {
                chunks.push(chunk_start..u + 1);
                chunk_start = u + 1;
                chunk_pairs = 0;
            }
        }
        if chunk_start < n_utt {
            chunks.push(chunk_start..n_utt);
        }
        let mut jac_indptr = Vec::with_capacity(sample_times.len() + 1);
        jac_indptr.push(0usize);
        for u in 0..n_utt {
            let row_nnz = (uniq_offsets[u + 1] - uniq_offsets[u]) * N_PARAMS + 1;
            for _ in sample_offsets[u]..sample_offsets[u + 1] {
                let last = jac_indptr[jac_indptr.len() - 1];
                // The number of stored entries could only overflow far beyond any memory; the
                // Jacobian's allocation then fails with the sizes named (jacobian_nnz saturates).
                jac_indptr.push(last.saturating_add(row_nnz));
            }
        }
        Ok(Corpus {
            seg_offsets,
            seg_phoneme,
            seg_start,
            seg_end,
            sample_offsets,
            sample_times,
            n_phonemes,
            uniq_offsets,
            uniq_phonemes,
            seg_local,
            chunks,
            total_pairs,
            max_segments,
            jac_indptr,
        })
    }

    /// Number of utterances.
    pub fn n_utterances(&self) -> usize {
        self.seg_offsets.len() - 1
    }
    /// Number of samples over all utterances (rows of the Jacobian).
    pub fn n_samples(&self) -> usize {
        self.sample_times.len()
    }
    /// Number of segments over all utterances.
    pub fn n_segments(&self) -> usize {
        self.seg_phoneme.len()
    }
    /// Number of rows of the parameter matrix.
    pub fn n_phonemes(&self) -> usize {
        self.n_phonemes
    }
    /// The segment offsets (length n_utterances + 1).
    pub fn seg_offsets(&self) -> &[usize] {
        &self.seg_offsets
    }
    /// Phoneme (parameter row) of each segment.
    pub fn seg_phoneme(&self) -> &[usize] {
        &self.seg_phoneme
    }
    /// Segment start times (s).
    pub fn seg_start(&self) -> &[f64] {
        &self.seg_start
    }
    /// Segment end times (s).
    pub fn seg_end(&self) -> &[f64] {
        &self.seg_end
    }
    /// The sample offsets (length n_utterances + 1).
    pub fn sample_offsets(&self) -> &[usize] {
        &self.sample_offsets
    }
    /// Sample times (s).
    pub fn sample_times(&self) -> &[f64] {
        &self.sample_times
    }

    fn segments(&self, u: usize) -> Range<usize> {
        self.seg_offsets[u]..self.seg_offsets[u + 1]
    }
    fn samples(&self, u: usize) -> Range<usize> {
        self.sample_offsets[u]..self.sample_offsets[u + 1]
    }
    fn distinct(&self, u: usize) -> &[usize] {
        &self.uniq_phonemes[self.uniq_offsets[u]..self.uniq_offsets[u + 1]]
    }
    /// Non-zeros per Jacobian row of utterance u: every parameter of every distinct phoneme, and β.
    fn row_nnz(&self, u: usize) -> usize {
        (self.uniq_offsets[u + 1] - self.uniq_offsets[u]) * N_PARAMS + 1
    }
    fn parallel(&self) -> bool {
        self.total_pairs >= 2 * CHUNK_PAIRS && self.chunks.len() > 1
    }
    fn prepare(&self, prep: &mut Prepared, u: usize, params: &[f64], opts: &ModelOptions) {
        let s = self.segments(u);
        prep.prepare(
            &self.seg_start[s.clone()],
            &self.seg_end[s.clone()],
            &self.seg_phoneme[s],
            params,
            opts,
        );
    }

    /// Runs `work` on every chunk (in parallel when the corpus is large) and collects the results.
    fn map_chunks<R: Send>(&self, work: impl Fn(Range<usize>) -> R + Sync) -> Vec<R> {
        if self.parallel() {
            self.chunks.par_iter().map(|c| work(c.clone())).collect()
        } else {
            self.chunks.iter().map(|c| work(c.clone())).collect()
        }
    }
}

/// Splits `data` into consecutive pieces ending at `ends` (absolute, non-decreasing positions).
fn split_at_ends<T>(
    mut data: &mut [T],
    start: usize,
    ends: impl Iterator<Item = usize>,
) -> Vec<&mut [T]> {
    let mut pos = start;
    let mut out = Vec::new();
    for end in ends {
        let (head, tail) = data.split_at_mut(end - pos);
        out.push(head);
        data = tail;
        pos = end;
    }
    out
}

/// An empty vector with room for `n` elements, for output written once in parallel. On Linux,
/// large buffers are advised to use transparent huge pages: first-touch page faults on tens of
/// MB of fresh 4 KiB pages otherwise cost more than computing the Jacobian that fills them.
fn output_buffer<T>(n: usize, what: impl FnOnce() -> String) -> Result<Vec<T>, ModelError> {
    let v: Vec<T> = try_with_capacity(n, what)?;
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = n * std::mem::size_of::<T>();
        if bytes >= 4 * HUGE {
            let start = v.as_ptr() as usize;
            let aligned = (start + HUGE - 1) & !(HUGE - 1);
            let end = (start + bytes) & !(HUGE - 1);
            if end > aligned {
                // SAFETY: the range lies inside the vector's own allocation; MADV_HUGEPAGE only
                // changes how the kernel backs it, and failure is harmless (ignored).
                unsafe {
                    libc::madvise(
                        aligned as *mut libc::c_void,
                        end - aligned,
                        libc::MADV_HUGEPAGE,
                    );
                }
            }
        }
    }
    Ok(v)
}

fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), ModelError> {
    if got != expected {
        Err(ModelError::LengthMismatch {
            what,
            got,
            expected,
        })
    } else {
        Ok(())
    }
}

/// Evaluates on validated input; the shared body of [`evaluate`] and the batches.
fn evaluate_unchecked(
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

/// The samples `samples` in consecutive blocks of at most [`LANES`], the unit of the derivative
/// passes' value pass.
fn blocks(samples: Range<usize>) -> impl Iterator<Item = Range<usize>> {
    samples
        .clone()
        .step_by(LANES)
        .map(move |k| k..(k + LANES).min(samples.end))
}

/// Checks `observed` and `weights` (one per sample): weights finite and ≥ 0, observed finite
/// wherever the weight is not 0 (NaN observed with weight 0 masks the sample).
fn validate_observations(
    corpus: &Corpus,
    observed: &[f64],
    weights: &[f64],
) -> Result<(), ModelError> {
    check_len("observed (n_samples)", observed.len(), corpus.n_samples())?;
    check_len("weights (n_samples)", weights.len(), corpus.n_samples())?;
    for (sample, (&y, &w)) in observed.iter().zip(weights).enumerate() {
        if !(w.is_finite() && w >= 0.0) {
            return Err(ModelError::BadWeight { sample, value: w });
        }
        if w != 0.0 && !y.is_finite() {
            return Err(ModelError::NonFiniteObserved {
                sample,
                value: y,
                weight: w,
            });
        }
    }
    Ok(())
}

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
