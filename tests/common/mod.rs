//! Helpers shared by the integration tests: small corpora and parameter rows.
#![allow(dead_code)]

use coartic::{Corpus, ModelOptions, Param, N_PARAMS};

/// A parameter row in the column order of `Param`.
#[allow(clippy::too_many_arguments)]
pub fn row(
    target: f64,
    alpha: f64,
    theta_bw: f64,
    theta_fw: f64,
    c_bw: f64,
    c_fw: f64,
    k_r: f64,
    sigma: f64,
    psi: f64,
    delta: f64,
) -> [f64; N_PARAMS] {
    let mut r = [0.0; N_PARAMS];
    r[Param::Target.index()] = target;
    r[Param::Alpha.index()] = alpha;
    r[Param::ThetaBw.index()] = theta_bw;
    r[Param::ThetaFw.index()] = theta_fw;
    r[Param::CBw.index()] = c_bw;
    r[Param::CFw.index()] = c_fw;
    r[Param::KR.index()] = k_r;
    r[Param::Sigma.index()] = sigma;
    r[Param::Psi.index()] = psi;
    r[Param::Delta.index()] = delta;
    r
}

/// One utterance from (phoneme, start, end) segments and sample times.
pub fn utterance(segs: &[(usize, f64, f64)], times: &[f64], n_phonemes: usize) -> Corpus {
    Corpus::new(
        vec![0, segs.len()],
        segs.iter().map(|s| s.0).collect(),
        segs.iter().map(|s| s.1).collect(),
        segs.iter().map(|s| s.2).collect(),
        vec![0, times.len()],
        times.to_vec(),
        n_phonemes,
    )
    .expect("valid test corpus")
}

/// Evaluates a corpus, panicking on error.
pub fn eval(corpus: &Corpus, params: &[f64], beta: f64, opts: &ModelOptions) -> Vec<f64> {
    let mut out = vec![0.0; corpus.n_samples()];
    coartic::evaluate(corpus, params, beta, opts, &mut out).expect("evaluate");
    out
}

/// Evenly spaced times from a to b inclusive.
pub fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| a + (b - a) * i as f64 / (n - 1) as f64)
        .collect()
}

/// The flattened parameter matrix from rows.
pub fn flat(rows: &[[f64; N_PARAMS]]) -> Vec<f64> {
    rows.iter().flat_map(|r| r.iter().copied()).collect()
}
