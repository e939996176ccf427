//! Helpers shared by the integration tests: small corpora and parameter rows.

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

use coartic::SparseJacobian;
use proptest::prelude::*;

/// A random single-utterance model within the default bounds of MODEL.md §1.
#[derive(Clone, Debug)]
pub struct Model {
    /// (phoneme, start, end)
    pub segs: Vec<(usize, f64, f64)>,
    pub rows: Vec<[f64; N_PARAMS]>,
    pub beta: f64,
    pub opts: ModelOptions,
}

impl Model {
    pub fn n_phonemes(&self) -> usize {
        self.rows.len()
    }
    pub fn params(&self) -> Vec<f64> {
        flat(&self.rows)
    }
    pub fn corpus(&self, times: &[f64]) -> Corpus {
        utterance(&self.segs, times, self.n_phonemes())
    }
    /// The raw (unclamped) target time of segment i, computed as the core does.
    pub fn raw_target(&self, i: usize) -> f64 {
        let (p, s, e) = self.segs[i];
        s + self.opts.apex_fraction * (e - s) + self.rows[p][Param::Delta.index()]
    }
    /// The clamped target time of segment i.
    pub fn target_time(&self, i: usize) -> f64 {
        let (_, s, e) = self.segs[i];
        self.raw_target(i).clamp(s, e)
    }
    /// `n` evenly spaced times from before the first segment to after the last.
    pub fn times(&self, n: usize) -> Vec<f64> {
        let first = self.segs[0].1;
        let last = self.segs[self.segs.len() - 1].2;
        linspace(first - 0.15, last + 0.15, n)
    }
}

/// A parameter row within the default bounds (k_R kept off 0 and 1 so central differences stay
/// inside the domain).
pub fn row_strategy() -> impl Strategy<Value = [f64; N_PARAMS]> {
    (
        (
            -10.0..20.0f64,
            -1.5..1.5f64,
            (2.0f64).ln()..(200.0f64).ln(),
            (2.0f64).ln()..(200.0f64).ln(),
        ),
        (0.5..3.0f64, 0.5..3.0f64, 0.02..0.98f64),
        (
            -0.5..0.5f64,
            (10.0f64).ln()..(1000.0f64).ln(),
            -0.08..0.08f64,
        ),
    )
        .prop_map(|((t, la, ltb, ltf), (cb, cf, k), (s, lpsi, d))| {
            row(
                t,
                la.exp(),
                ltb.exp(),
                ltf.exp(),
                cb,
                cf,
                k,
                s,
                lpsi.exp(),
                d,
            )
        })
}

/// A random utterance of 2..=max_segs segments (touching or with pauses between) over
/// 2..=4 phonemes, with random parameters, β, apex fraction and edge extent.
pub fn model_strategy(max_segs: usize) -> impl Strategy<Value = Model> {
    (2usize..=4)
        .prop_flat_map(move |n_ph| {
            (
                prop::collection::vec(
                    (
                        0..n_ph,
                        0.03..0.25f64,
                        prop::bool::weighted(0.2),
                        0.0..0.05f64,
                    ),
                    2..=max_segs,
                ),
                prop::collection::vec(row_strategy(), n_ph),
                0.2..3.0f64,
                0.2..0.8f64,
                0.3..1.5f64,
            )
        })
        .prop_map(|(segs, rows, beta, apex, edge)| {
            let mut t = 0.0;
            let mut out = Vec::new();
            for (p, dur, gap, gap_len) in segs {
                if gap {
                    t += gap_len;
                }
                out.push((p, t, t + dur));
                t += dur;
            }
            Model {
                segs: out,
                rows,
                beta,
                opts: ModelOptions {
                    variant: coartic::Variant::Modified,
                    apex_fraction: apex,
                    edge_extent: edge,
                    ..ModelOptions::default()
                },
            }
        })
}

/// The CSR Jacobian as a dense row-major matrix.
pub fn dense(j: &SparseJacobian) -> Vec<f64> {
    let mut d = vec![0.0; j.n_rows * j.n_cols];
    for r in 0..j.n_rows {
        for k in j.indptr[r]..j.indptr[r + 1] {
            d[r * j.n_cols + j.indices[k]] += j.data[k];
        }
    }
    d
}

/// Values and dense Jacobian of a model at `times`.
pub fn jac(m: &Model, times: &[f64]) -> (Vec<f64>, Vec<f64>, usize) {
    let c = m.corpus(times);
    let mut values = vec![0.0; times.len()];
    let j = coartic::jacobian(&c, &m.params(), m.beta, &m.opts, &mut values).expect("jacobian");
    (values, dense(&j), j.n_cols)
}

/// Central-difference step for a column (parameter k of a phoneme, or β when k is None).
pub fn step(m: &Model, p: usize, k: Option<Param>) -> f64 {
    match k {
        None => 1e-6 * m.beta.max(1.0),
        Some(par) => {
            let v = m.rows[p][par.index()];
            match par {
                Param::Target => 1e-6 * v.abs().max(1.0),
                Param::Alpha | Param::ThetaBw | Param::ThetaFw | Param::Psi => 1e-6 * v,
                Param::Delta => 1e-7,
                _ => 1e-6,
            }
        }
    }
}

/// Central differences of F at `times` for one column, Richardson-extrapolated from steps h and
/// h/2 (error O(h⁴): near a cut-off ρ's higher derivatives are large).
pub fn central(m: &Model, times: &[f64], p: usize, k: Option<Param>) -> Vec<f64> {
    let diff = |h: f64| {
        let shifted = |sign: f64| {
            let mut mm = m.clone();
            match k {
                None => mm.beta += sign * h,
                Some(par) => mm.rows[p][par.index()] += sign * h,
            }
            eval(&mm.corpus(times), &mm.params(), mm.beta, &mm.opts)
        };
        let (plus, minus) = (shifted(1.0), shifted(-1.0));
        plus.iter()
            .zip(&minus)
            .map(|(a, b)| (a - b) / (2.0 * h))
            .collect::<Vec<f64>>()
    };
    let h = step(m, p, k);
    let (coarse, fine) = (diff(h), diff(h / 2.0));
    coarse
        .iter()
        .zip(&fine)
        .map(|(c, f)| (4.0 * f - c) / 3.0)
        .collect()
}

/// Compares one analytic Jacobian column with central differences, skipping rows where `skip`
/// says the derivative is not defined. Returns a description of the first disagreement.
#[allow(clippy::too_many_arguments)]
pub fn check_column(
    m: &Model,
    times: &[f64],
    values: &[f64],
    dense_j: &[f64],
    n_cols: usize,
    p: usize,
    k: Option<Param>,
    skip: &dyn Fn(usize) -> bool,
) -> Result<(), String> {
    let col = match k {
        None => n_cols - 1,
        Some(par) => p * N_PARAMS + par.index(),
    };
    let fd = central(m, times, p, k);
    let h = step(m, p, k);
    let f_max = values.iter().fold(1.0f64, |a, v| a.max(v.abs()));
    // Rounding error of a central difference: a few ulps of F over h.
    let atol = 200.0 * f64::EPSILON * f_max / h + 1e-10;
    for (r, &d) in fd.iter().enumerate() {
        if skip(r) {
            continue;
        }
        let a = dense_j[r * n_cols + col];
        if !a.is_finite() || (a - d).abs() > 1e-6 * a.abs().max(d.abs()) + atol {
            return Err(format!(
                "column {:?} of phoneme {p}, sample {r} (t = {}): analytic {a}, central difference {d}",
                k.map(|x| x.name()).unwrap_or("beta"),
                times[r]
            ));
        }
    }
    Ok(())
}
