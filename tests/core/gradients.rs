//! Exact gradients (MODEL.md §4) against central finite differences on random models: every
//! Jacobian column (all ten parameters of every phoneme, and β), the SSE gradient, c < 1 with a
//! sample exactly at a target time, dominance underflow, and rows independent of the four-sample
//! blocks the value pass runs in.

use crate::common::*;
use coartic::{Dominance, ModelOptions, Param, Variant, N_PARAMS};
use proptest::prelude::*;

/// Rows where a segment of phoneme `p` has its target within `margin` of the sample (the kink
/// of |τ| at τ = 0), or its raw target within 1e-6 of a clamp boundary.
fn near_kink(m: &Model, times: &[f64], p: usize, margin: f64) -> Vec<bool> {
    times
        .iter()
        .map(|&t| {
            m.segs.iter().enumerate().any(|(i, &(q, s, e))| {
                if q != p {
                    return false;
                }
                let raw = m.raw_target(i);
                (t - m.target_time(i)).abs() < margin
                    || (raw - s).abs() < 1e-6
                    || (raw - e).abs() < 1e-6
            })
        })
        .collect()
}

/// Rows within `margin` of a plateau edge t_i ± h d_i of a segment of phoneme `p` (MODEL.md
/// §2.1: the reach max(|τ| − h d_i, 0) has a kink there, an infinite slope for c < 1).
fn near_plateau_edge(m: &Model, times: &[f64], p: usize, margin: f64) -> Vec<bool> {
    if m.opts.dominance != Dominance::Plateau {
        return vec![false; times.len()];
    }
    times
        .iter()
        .map(|&t| {
            m.segs.iter().enumerate().any(|(i, &(q, s, e))| {
                let half = m.opts.plateau_fraction * (e - s);
                // The segment's own δ moves its edges; a handed-over θ_fw/c_fw does not.
                q == p && ((t - m.target_time(i)).abs() - half).abs() < margin
            })
        })
        .collect()
}

fn check_all_columns(m: &Model, times: &[f64]) -> Result<(), String> {
    let (values, dj, n_cols) = jac(m, times);
    for p in 0..m.n_phonemes() {
        let edge = near_plateau_edge(m, times, p, 2e-3);
        let kink: Vec<bool> = near_kink(m, times, p, 2e-3)
            .iter()
            .zip(&edge)
            .map(|(a, b)| *a || *b)
            .collect();
        for par in Param::ALL {
            let skip = |r: usize| par == Param::Delta && kink[r];
            check_column(m, times, &values, &dj, n_cols, p, Some(par), &skip)?;
        }
    }
    check_column(m, times, &values, &dj, n_cols, 0, None, &|_| false)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Every column of the Jacobian of the modified model equals central differences.
    #[test]
    fn jacobian_matches_central_differences(m in model_strategy(7)) {
        let times = m.times(37);
        prop_assert!(check_all_columns(&m, &times).is_ok(), "{}", check_all_columns(&m, &times).unwrap_err());
    }

    /// The same for the original model (eq. 1), where k_R, σ, ψ and β have zero columns.
    #[test]
    fn original_jacobian_matches_central_differences(m in model_strategy(5)) {
        let mut m = m;
        m.opts.variant = Variant::Original;
        let times = m.times(29);
        prop_assert!(check_all_columns(&m, &times).is_ok(), "{}", check_all_columns(&m, &times).unwrap_err());
        let (_, dj, n_cols) = jac(&m, &times);
        for r in 0..times.len() {
            for p in 0..m.n_phonemes() {
                for par in [Param::KR, Param::Sigma, Param::Psi] {
                    prop_assert_eq!(dj[r * n_cols + p * N_PARAMS + par.index()], 0.0);
                }
            }
            prop_assert_eq!(dj[r * n_cols + n_cols - 1], 0.0);
        }
    }

    /// The rate-aware options of MODEL.md §2.1 (plateau dominance with any h, handover, both),
    /// in both variants: every Jacobian column equals central differences, and the SSE gradient
    /// agrees with the Jacobian.
    #[test]
    fn rate_aware_jacobian_matches_central_differences(m in model_strategy(6), h in 0.0..1.0f64, which in 0usize..3, original in prop::bool::weighted(0.3)) {
        let mut m = m;
        m.opts.dominance = if which == 1 { Dominance::Centre } else { Dominance::Plateau };
        m.opts.plateau_fraction = h;
        m.opts.handover = which >= 1;
        if original {
            m.opts.variant = Variant::Original;
        }
        let times = m.times(31);
        prop_assert!(check_all_columns(&m, &times).is_ok(), "{}", check_all_columns(&m, &times).unwrap_err());
        let (values, dj, n_cols) = jac(&m, &times);
        let c = m.corpus(&times);
        let observed: Vec<f64> = values.iter().enumerate().map(|(r, v)| v + (r as f64 * 0.37).sin()).collect();
        let weights = vec![1.0; times.len()];
        let mut grad = vec![0.0; m.n_phonemes() * N_PARAMS];
        coartic::sse_gradient(&c, &m.params(), m.beta, &m.opts, &observed, &weights, &mut grad).unwrap();
        for (col, &g) in grad.iter().enumerate() {
            let want: f64 = (0..times.len()).map(|r| -2.0 * (observed[r] - values[r]) * dj[r * n_cols + col]).sum();
            prop_assert!((g - want).abs() <= 1e-9 * want.abs().max(1.0), "column {}: {} vs {}", col, g, want);
        }
    }

    /// The derivative passes evaluate samples in blocks of four lanes: each sample's value and
    /// Jacobian row are the same bits whether it shares a block with others (at any lane, in a
    /// short last block) or is evaluated alone, and the values equal `evaluate`'s.
    #[test]
    fn jacobian_rows_do_not_depend_on_their_block(m in model_strategy(7), n in 2usize..11) {
        let times = m.times(n);
        let (values, dj, n_cols) = jac(&m, &times);
        let direct = eval(&m.corpus(&times), &m.params(), m.beta, &m.opts);
        for (r, &t) in times.iter().enumerate() {
            let (v, row, _) = jac(&m, &[t]);
            prop_assert_eq!(values[r].to_bits(), v[0].to_bits(), "value at sample {}", r);
            prop_assert_eq!(values[r].to_bits(), direct[r].to_bits(), "evaluate at sample {}", r);
            for (k, (a, b)) in dj[r * n_cols..(r + 1) * n_cols].iter().zip(&row).enumerate() {
                prop_assert_eq!(a.to_bits(), b.to_bits(), "sample {} column {}", r, k);
            }
        }
    }

    /// The SSE gradient equals Jᵀ(−2 w r), computed without the Jacobian, and its SSE is Σ w r².
    #[test]
    fn sse_gradient_is_jacobian_transpose_residual(m in model_strategy(7), noise in prop::collection::vec(-2.0..2.0f64, 31), wsel in prop::collection::vec(0usize..4, 31)) {
        let times = m.times(31);
        let (values, dj, n_cols) = jac(&m, &times);
        let mut observed: Vec<f64> = values.iter().zip(&noise).map(|(f, e)| f + e).collect();
        let weights: Vec<f64> = wsel.iter().map(|&w| [0.0, 0.5, 1.0, 2.0][w]).collect();
        // Masked samples may hold NaN.
        for (y, &w) in observed.iter_mut().zip(&weights) {
            if w == 0.0 { *y = f64::NAN; }
        }
        let c = m.corpus(&times);
        let mut grad = vec![0.0; m.n_phonemes() * N_PARAMS];
        let (sse, d_beta) = coartic::sse_gradient(&c, &m.params(), m.beta, &m.opts, &observed, &weights, &mut grad).unwrap();
        let mut want_sse = 0.0;
        let mut want = vec![0.0; n_cols];
        for r in 0..times.len() {
            if weights[r] == 0.0 { continue; }
            let res = observed[r] - values[r];
            want_sse += weights[r] * res * res;
            for (col, w) in want.iter_mut().enumerate() {
                *w += -2.0 * weights[r] * res * dj[r * n_cols + col];
            }
        }
        prop_assert!((sse - want_sse).abs() <= 1e-12 * want_sse.max(1.0));
        let scale = want.iter().fold(1e-12f64, |a, v| a.max(v.abs()));
        for (col, &g) in grad.iter().chain(std::iter::once(&d_beta)).enumerate() {
            prop_assert!((g - want[col]).abs() <= 1e-10 * scale, "column {}: {} vs {}", col, g, want[col]);
        }
    }
}

/// c < 1 and a sample exactly at a target time: every column finite; all but δ of that phoneme
/// (a kink of |τ| there) equal central differences; ∂/∂c uses ln|τ| · |τ|^c = 0.
#[test]
fn c_below_one_with_sample_at_target_time() {
    let m = Model {
        segs: vec![
            (0, 0.0, 0.12),
            (1, 0.12, 0.2),
            (2, 0.2, 0.33),
            (0, 0.33, 0.5),
        ],
        rows: vec![
            row(0.0, 0.7, 8.0, 9.0, 0.9, 1.1, 0.3, 0.1, 200.0, 0.0),
            row(11.0, 1.0, 25.0, 25.0, 0.55, 0.55, 0.4, -0.2, 300.0, 0.01),
            row(3.0, 1.3, 30.0, 12.0, 0.6, 0.7, 0.8, 0.3, 150.0, -0.02),
        ],
        beta: 1.3,
        opts: ModelOptions::default(),
    };
    let mut times = m.times(25);
    let t1 = m.target_time(1);
    let t2 = m.target_time(2);
    times.push(t1);
    times.push(t2);
    let (values, dj, n_cols) = jac(&m, &times);
    assert!(values.iter().chain(&dj).all(|v| v.is_finite()));
    let n = times.len();
    for p in 0..3 {
        let kink = near_kink(&m, &times, p, 2e-3);
        for par in Param::ALL {
            let skip = |r: usize| par == Param::Delta && kink[r];
            check_column(&m, &times, &values, &dj, n_cols, p, Some(par), &skip).unwrap();
        }
    }
    check_column(&m, &times, &values, &dj, n_cols, 0, None, &|_| false).unwrap();
    // At τ = 0 the c columns of that segment's own phoneme get no ln|τ| term.
    let r = n - 2;
    let dc = dj[r * n_cols + N_PARAMS + Param::CBw.index()];
    assert!(dc.is_finite());
}

/// Huge θ: dominance underflows to 0 far from every target; log-sum-exp keeps F, the Jacobian
/// and the SSE gradient finite and F inside the range of the targets.
#[test]
fn dominance_underflow_gives_no_nan() {
    let m = Model {
        segs: vec![(0, 0.0, 0.1), (1, 0.1, 0.2), (0, 0.2, 0.4)],
        rows: vec![
            row(-2.0, 1.0, 1e6, 1e6, 1.0, 1.0, 0.5, 0.0, 100.0, 0.0),
            row(9.0, 1.0, 3e7, 2e6, 0.5, 3.0, 0.5, 0.4, 100.0, 0.0),
        ],
        beta: 1.0,
        opts: ModelOptions::default(),
    };
    let times = linspace(-0.5, 1.0, 301);
    let (values, dj, _) = jac(&m, &times);
    for (t, v) in times.iter().zip(&values) {
        assert!(
            v.is_finite() && *v >= -2.0 - 1e-9 && *v <= 9.0 * 1.4 + 1e-9,
            "F({t}) = {v}"
        );
    }
    assert!(dj.iter().all(|v| v.is_finite()));
    // A plain (non-log) evaluation would be 0/0 at t = 1.0: every D underflows there.
    let d_plain: f64 = [0.05f64, 0.15, 0.3]
        .iter()
        .map(|ti| (-1e6 * (1.0f64 - ti).abs()).exp())
        .sum();
    assert_eq!(d_plain, 0.0);
    // There the last segment dominates (its forward R is 1): F is its target.
    assert!(
        (values[300] - (-2.0)).abs() < 1e-12,
        "F(1.0) = {}",
        values[300]
    );
    let c = m.corpus(&times);
    let observed = vec![1.0; times.len()];
    let weights = vec![1.0; times.len()];
    let mut grad = vec![0.0; 2 * N_PARAMS];
    let (sse, db) = coartic::sse_gradient(
        &c,
        &m.params(),
        m.beta,
        &m.opts,
        &observed,
        &weights,
        &mut grad,
    )
    .unwrap();
    assert!(sse.is_finite() && db.is_finite() && grad.iter().all(|g| g.is_finite()));
}

/// Repeated phonemes: the Jacobian column of a phoneme is the sum over its occurrences
/// (checked by central differences, which perturb all occurrences at once).
#[test]
fn duplicate_phonemes_are_summed() {
    let m = Model {
        segs: vec![
            (0, 0.0, 0.1),
            (1, 0.1, 0.2),
            (0, 0.2, 0.3),
            (1, 0.3, 0.45),
            (0, 0.45, 0.6),
        ],
        rows: vec![
            row(1.0, 0.8, 20.0, 15.0, 1.2, 0.8, 0.4, 0.1, 400.0, 0.01),
            row(7.0, 1.0, 30.0, 25.0, 1.0, 1.5, 0.9, -0.3, 250.0, -0.015),
        ],
        beta: 0.7,
        opts: ModelOptions::default(),
    };
    let times = m.times(41);
    check_all_columns(&m, &times).unwrap();
    let c = m.corpus(&times);
    let mut values = vec![0.0; times.len()];
    let j = coartic::jacobian(&c, &m.params(), m.beta, &m.opts, &mut values).unwrap();
    // One entry per (distinct phoneme, parameter) and β: 2 × 10 + 1 per row, columns sorted.
    for r in 0..j.n_rows {
        let cols = &j.indices[j.indptr[r]..j.indptr[r + 1]];
        assert_eq!(cols.len(), 21);
        assert!(cols.windows(2).all(|w| w[0] < w[1]));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// The SSE gradient against Richardson-extrapolated central differences of the SSE itself.
    #[test]
    fn sse_gradient_matches_central_differences(m in model_strategy(6), noise in prop::collection::vec(-2.0..2.0f64, 23)) {
        let times = m.times(23);
        let c = m.corpus(&times);
        let f = eval(&c, &m.params(), m.beta, &m.opts);
        let observed: Vec<f64> = f.iter().zip(&noise).map(|(a, b)| a + b).collect();
        let weights: Vec<f64> = (0..times.len()).map(|n| 1.0 + (n % 3) as f64).collect();
        let sse_of = |mm: &Model| {
            let mut g = vec![0.0; mm.n_phonemes() * N_PARAMS];
            coartic::sse_gradient(&c, &mm.params(), mm.beta, &mm.opts, &observed, &weights, &mut g).unwrap()
        };
        let mut grad = vec![0.0; m.n_phonemes() * N_PARAMS];
        let (sse, d_beta) = coartic::sse_gradient(&c, &m.params(), m.beta, &m.opts, &observed, &weights, &mut grad).unwrap();
        let mut columns: Vec<(usize, Option<Param>)> = (0..m.n_phonemes()).flat_map(|p| Param::ALL.map(|k| (p, Some(k)))).collect();
        columns.push((0, None));
        for (p, k) in columns {
            if k == Some(Param::Delta) && near_kink(&m, &times, p, 2e-3).iter().any(|&x| x) {
                continue;
            }
            let h = step(&m, p, k);
            let diff = |h: f64| {
                let mut plus = m.clone();
                let mut minus = m.clone();
                match k {
                    None => { plus.beta += h; minus.beta -= h; }
                    Some(par) => { plus.rows[p][par.index()] += h; minus.rows[p][par.index()] -= h; }
                }
                (sse_of(&plus).0 - sse_of(&minus).0) / (2.0 * h)
            };
            let fd = (4.0 * diff(h / 2.0) - diff(h)) / 3.0;
            let analytic = match k { None => d_beta, Some(par) => grad[p * N_PARAMS + par.index()] };
            let atol = 200.0 * f64::EPSILON * sse.max(1.0) / h + 1e-10;
            prop_assert!((analytic - fd).abs() <= 1e-6 * analytic.abs().max(fd.abs()) + atol,
                "phoneme {} column {:?}: analytic {} vs {}", p, k, analytic, fd);
        }
    }
}
