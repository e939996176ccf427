//! The corpus and walker batches agree with per-utterance, per-walker calls; the parallel path
//! (large corpora) agrees with the sequential one.

use crate::common::*;
use coartic::{
    evaluate_batch, jacobian, jacobian_values, residual_sums_batch, sse_batch, sse_gradient,
    Corpus, ModelError, ModelOptions, Param, N_PARAMS,
};
use proptest::prelude::*;

/// A corpus of many random utterances over shared phonemes (large enough to run in parallel),
/// including utterances without samples.
fn big_corpus(models: &[Model], n_phonemes: usize, samples: usize) -> (Corpus, Vec<Vec<f64>>) {
    let (mut so, mut sp, mut ss, mut se, mut to, mut tt) =
        (vec![0], vec![], vec![], vec![], vec![0], vec![]);
    let mut per = Vec::new();
    for (u, m) in models.iter().enumerate() {
        let times = if u % 17 == 5 {
            vec![]
        } else {
            m.times(samples)
        };
        for &(p, s, e) in &m.segs {
            sp.push(p % n_phonemes);
            ss.push(s);
            se.push(e);
        }
        tt.extend_from_slice(&times);
        so.push(sp.len());
        to.push(tt.len());
        per.push(times);
    }
    (
        Corpus::new(so, sp, ss, se, to, tt, n_phonemes).unwrap(),
        per,
    )
}

/// The first index where two vectors differ, with both values.
fn first_difference(a: &[f64], b: &[f64]) -> Option<(usize, f64, f64)> {
    if a.len() != b.len() {
        return Some((a.len().min(b.len()), f64::NAN, f64::NAN));
    }
    a.iter()
        .zip(b)
        .enumerate()
        .find(|(_, (x, y))| x != y)
        .map(|(i, (x, y))| (i, *x, *y))
}

fn one(
    m: &Model,
    rows: &[[f64; N_PARAMS]],
    times: &[f64],
    opts: &ModelOptions,
    beta: f64,
) -> Vec<f64> {
    let mut mm = m.clone();
    mm.segs.iter_mut().for_each(|s| s.0 %= rows.len());
    mm.rows = rows.to_vec();
    eval(&mm.corpus(times), &mm.params(), beta, opts)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    /// 300 utterances (parallel path): evaluate and the Jacobian equal per-utterance calls.
    #[test]
    fn corpus_equals_per_utterance(models in prop::collection::vec(model_strategy(7), 300), rows in prop::collection::vec(row_strategy(), 4)) {
        let opts = ModelOptions::default();
        let beta = 1.1;
        let (c, per) = big_corpus(&models, 4, 40);
        let params = flat(&rows);
        let all = eval(&c, &params, beta, &opts);
        let mut values = vec![0.0; c.n_samples()];
        let j = jacobian(&c, &params, beta, &opts, &mut values).unwrap();
        prop_assert!(first_difference(&values, &all).is_none(), "{:?}", first_difference(&values, &all));
        let mut row0 = 0;
        for (m, times) in models.iter().zip(&per) {
            let want = one(m, &rows, times, &opts, beta);
            let got = &all[row0..row0 + times.len()];
            prop_assert!(first_difference(got, &want).is_none(), "{:?}", first_difference(got, &want));
            // Jacobian rows of this utterance against the single-utterance Jacobian.
            if !times.is_empty() {
                let mut mm = m.clone();
                mm.segs.iter_mut().for_each(|s| s.0 %= 4);
                mm.rows = rows.clone();
                mm.beta = beta;
                mm.opts = opts;
                let (_, dj, n_cols) = jac(&mm, times);
                for r in 0..times.len() {
                    let g = row0 + r;
                    for k in j.indptr[g]..j.indptr[g + 1] {
                        prop_assert_eq!(j.data[k], dj[r * n_cols + j.indices[k]]);
                    }
                }
            }
            row0 += times.len();
        }
    }

    /// evaluate_batch / sse_batch equal per-walker evaluate / sse_gradient, and residual_sums_batch
    /// gives sse_batch's SSE and each utterance's Σ w (y − F) of evaluate_batch's F; an invalid
    /// walker makes evaluate_batch fail naming it, gets +inf from sse_batch and NaN sums.
    #[test]
    fn walker_batches_equal_single_calls(models in prop::collection::vec(model_strategy(6), 40), walkers in prop::collection::vec((prop::collection::vec(row_strategy(), 3), 0.0..3.0f64), 5)) {
        let opts = ModelOptions::default();
        let (c, per) = big_corpus(&models, 3, 25);
        let ns = c.n_samples();
        let batch: Vec<f64> = walkers.iter().flat_map(|(r, _)| flat(r)).collect();
        let betas: Vec<f64> = walkers.iter().map(|w| w.1).collect();
        let mut out = vec![0.0; walkers.len() * ns];
        evaluate_batch(&c, &batch, &betas, &opts, &mut out).unwrap();
        let observed: Vec<f64> = (0..ns).map(|n| (n % 7) as f64).collect();
        let weights: Vec<f64> = (0..ns).map(|n| if n % 5 == 0 { 0.0 } else { 1.0 }).collect();
        let mut sse = vec![0.0; walkers.len()];
        sse_batch(&c, &batch, &betas, &opts, &observed, &weights, &mut sse).unwrap();
        let nu = per.len();
        let (mut sse2, mut sums) = (vec![0.0; walkers.len()], vec![0.0; walkers.len() * nu]);
        residual_sums_batch(&c, &batch, &betas, &opts, &observed, &weights, &mut sse2, &mut sums).unwrap();
        prop_assert!(first_difference(&sse2, &sse).is_none(), "{:?}", first_difference(&sse2, &sse));
        for w in 0..walkers.len() {
            let mut row0 = 0;
            for (u, times) in per.iter().enumerate() {
                let want: f64 = (row0..row0 + times.len()).map(|n| weights[n] * (observed[n] - out[w * ns + n])).sum();
                let got = sums[w * nu + u];
                prop_assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "walker {} utterance {}: {} vs {}", w, u, got, want);
                row0 += times.len();
            }
        }
        for (w, (rows, beta)) in walkers.iter().enumerate() {
            let single = eval(&c, &flat(rows), *beta, &opts);
            let got = &out[w * ns..(w + 1) * ns];
            prop_assert!(first_difference(got, &single).is_none(), "{:?}", first_difference(got, &single));
            let mut grad = vec![0.0; 3 * N_PARAMS];
            let (s, _) = sse_gradient(&c, &flat(rows), *beta, &opts, &observed, &weights, &mut grad).unwrap();
            prop_assert!((s - sse[w]).abs() <= 1e-10 * s.max(1.0));
        }
        let mut bad = batch.clone();
        bad[N_PARAMS * 3 + Param::ThetaFw.index()] = -1.0; // walker 1, phoneme 0
        let err = evaluate_batch(&c, &bad, &betas, &opts, &mut out).unwrap_err();
        prop_assert!(matches!(err, ModelError::InWalker { walker: 1, .. }), "{:?}", err);
        sse_batch(&c, &bad, &betas, &opts, &observed, &weights, &mut sse).unwrap();
        prop_assert_eq!(sse[1], f64::INFINITY);
        prop_assert!(sse[0].is_finite() && sse[2].is_finite());
        residual_sums_batch(&c, &bad, &betas, &opts, &observed, &weights, &mut sse2, &mut sums).unwrap();
        prop_assert_eq!(sse2[1], f64::INFINITY);
        prop_assert!(sums[nu..2 * nu].iter().all(|x| x.is_nan()) && sums[..nu].iter().all(|x| x.is_finite()));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4, ..ProptestConfig::default() })]

    /// jacobian_values into a reused buffer equals jacobian(), whose pattern is the corpus's.
    #[test]
    fn jacobian_values_reuse_the_pattern(models in prop::collection::vec(model_strategy(7), 200), rows in prop::collection::vec(row_strategy(), 5)) {
        let opts = ModelOptions::default();
        let (c, _) = big_corpus(&models, 5, 30);
        let params = flat(&rows);
        let mut v1 = vec![0.0; c.n_samples()];
        let j = jacobian(&c, &params, 0.8, &opts, &mut v1).unwrap();
        prop_assert_eq!(&j.indptr[..], c.jacobian_indptr());
        prop_assert_eq!(&j.indices, &c.jacobian_indices().unwrap());
        prop_assert_eq!(c.jacobian_nnz(), j.data.len());
        let mut v2 = vec![0.0; c.n_samples()];
        let mut data = vec![f64::NAN; c.jacobian_nnz()];
        jacobian_values(&c, &params, 0.8, &opts, &mut v2, &mut data).unwrap();
        prop_assert!(first_difference(&data, &j.data).is_none(), "{:?}", first_difference(&data, &j.data));
        prop_assert!(first_difference(&v1, &v2).is_none());
        let e = jacobian_values(&c, &params, 0.8, &opts, &mut v2, &mut data[1..]).unwrap_err();
        prop_assert!(matches!(e, ModelError::LengthMismatch { .. }), "{:?}", e);
    }
}

/// Empty utterances and an empty corpus are fine.
#[test]
fn empty_utterances() {
    let c = Corpus::new(
        vec![0, 0, 2, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 0, 3, 3],
        vec![0.0, 0.1, 0.3],
        2,
    )
    .unwrap();
    assert_eq!(
        (
            c.n_utterances(),
            c.n_samples(),
            c.n_segments(),
            c.n_phonemes()
        ),
        (3, 3, 2, 2)
    );
    let p = flat(&[
        row(1.0, 1.0, 10.0, 10.0, 1.0, 1.0, 0.5, 0.0, 100.0, 0.0),
        row(5.0, 1.0, 10.0, 10.0, 1.0, 1.0, 0.5, 0.0, 100.0, 0.0),
    ]);
    let f = eval(&c, &p, 1.0, &ModelOptions::default());
    assert!(f.iter().all(|v| v.is_finite()));
    let empty = Corpus::new(vec![0], vec![], vec![], vec![], vec![0], vec![], 0).unwrap();
    let mut out: Vec<f64> = vec![];
    coartic::evaluate(&empty, &[], 1.0, &ModelOptions::default(), &mut out).unwrap();
    let mut sse = vec![0.0; 2];
    sse_batch(
        &empty,
        &[],
        &[1.0, 2.0],
        &ModelOptions::default(),
        &[],
        &[],
        &mut sse,
    )
    .unwrap();
    assert_eq!(sse, vec![0.0, 0.0]);
    evaluate_batch(&empty, &[], &[1.0, 2.0], &ModelOptions::default(), &mut out).unwrap();
}
