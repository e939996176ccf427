//! Many utterances at once: the [`Corpus`] (CSR layout of docs/ARCHITECTURE.md, validated once,
//! with the checks every entry point shares) and, one file per job, the batch entry points:
//! evaluation (`evaluate`), the sparse Jacobian (`jacobian`), SSE with its gradient
//! (`sse_gradient`) and the walkers × corpus batches for MCMC (`batch`), parallel with rayon over
//! chunks of utterances.

mod batch;
mod evaluate;
mod jacobian;
mod sse_gradient;

pub use batch::{batch_what, evaluate_batch, residual_sums_batch, sse_batch};
pub use evaluate::{evaluate, physical_limit_loop};
pub use jacobian::{jacobian, jacobian_values, SparseJacobian};
pub use sse_gradient::sse_gradient;

use crate::alloc::try_with_capacity;
use crate::error::ModelError;
use crate::model::{Prepared, LANES};
use crate::params::{ModelOptions, N_PARAMS};
use rayon::prelude::*;
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
