//! The **must** statements of MODEL.md §3 as property tests over random models.

use crate::common::*;
use coartic::{ModelOptions, Param, Variant};
use proptest::prelude::*;

/// Eq. 1 written out plainly (no logs), as an independent reference.
fn eq1_plain(m: &Model, t: f64) -> Option<f64> {
    let (mut num, mut den) = (0.0, 0.0);
    for (i, &(p, _, _)) in m.segs.iter().enumerate() {
        let r = &m.rows[p];
        let tau = t - m.target_time(i);
        let (theta, c) = if tau <= 0.0 {
            (r[Param::ThetaBw.index()], r[Param::CBw.index()])
        } else {
            (r[Param::ThetaFw.index()], r[Param::CFw.index()])
        };
        let d = r[Param::Alpha.index()] * (-theta * tau.abs().powf(c)).exp();
        num += r[Param::Target.index()] * d;
        den += d;
    }
    (den > 1e-200).then_some(num / den)
}

/// Extents Δ⁺, Δ⁻ of MODEL.md §3.1, written out from the text.
fn extents(m: &Model) -> (Vec<f64>, Vec<f64>) {
    let n = m.segs.len();
    let t: Vec<f64> = (0..n).map(|i| m.target_time(i)).collect();
    let k = |i: usize| m.rows[m.segs[i].0][Param::KR.index()];
    let mut fwd = vec![m.opts.edge_extent; n];
    let mut bwd = vec![m.opts.edge_extent; n];
    for i in (0..n - 1).rev() {
        fwd[i] = (t[i + 1] - t[i]) + (1.0 - k(i + 1)) * fwd[i + 1];
    }
    for i in 1..n {
        bwd[i] = (t[i] - t[i - 1]) + (1.0 - k(i - 1)) * bwd[i - 1];
    }
    (fwd, bwd)
}

/// A measure of a kink at t: |F(t+h) − 2F(t) + F(t−h)| / h for two step sizes. For a C¹
/// function it shrinks with h; at a kink it stays; at a jump it grows.
fn kink(m: &Model, t: f64) -> (f64, f64) {
    let k = |h: f64| {
        let f = eval(&m.corpus(&[t - h, t, t + h]), &m.params(), m.beta, &m.opts);
        (f[2] - 2.0 * f[1] + f[0]).abs() / h
    };
    (k(1e-4), k(1e-6))
}

fn scale_of(m: &Model) -> f64 {
    m.rows
        .iter()
        .fold(1.0f64, |a, r| a.max(r[Param::Target.index()].abs()))
}

/// Whether the kink measure at t says "smooth".
fn smooth_at(m: &Model, t: f64) -> bool {
    let (k1, k2) = kink(m, t);
    k2 <= 0.05 * k1 + 1e-7 * scale_of(m)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Must 1: with S ≡ 1 (σ = 0) and R ≡ 1 (β = 0, k_R = 0, Λ covering the samples) the
    /// modified model equals eq. 1 exactly, and eq. 1 equals its plain transcription.
    #[test]
    fn unit_shape_and_resistance_give_eq1(m in model_strategy(8)) {
        let mut m = m;
        for r in m.rows.iter_mut() {
            r[Param::Sigma.index()] = 0.0;
            r[Param::KR.index()] = 0.0;
        }
        m.beta = 0.0;
        m.opts.edge_extent = 1.0;
        let times = m.times(53);
        let c = m.corpus(&times);
        let modified = eval(&c, &m.params(), m.beta, &m.opts);
        let original = eval(&c, &m.params(), 2.5, &ModelOptions { variant: Variant::Original, ..m.opts });
        prop_assert_eq!(&modified, &original);
        for (t, f) in times.iter().zip(&original) {
            if let Some(plain) = eq1_plain(&m, *t) {
                prop_assert!((f - plain).abs() <= 1e-12 * scale_of(&m), "t = {}: {} vs {}", t, f, plain);
            }
        }
    }

    /// Must 3: a phoneme with k_R = 1 reaches T·S(0) = T(1 + σ) exactly at its target time, at
    /// normal and at 3× faster speech (both neighbours' extents end there).
    #[test]
    fn fully_resistant_phoneme_reaches_its_target(m in model_strategy(8), pick in 0usize..8, speed_up in prop::bool::ANY) {
        let mut m = m;
        let j = pick % m.segs.len();
        let p = m.segs[j].0;
        m.rows[p][Param::KR.index()] = 1.0;
        if speed_up {
            for s in m.segs.iter_mut() {
                s.1 /= 3.0;
                s.2 /= 3.0;
            }
        }
        let t: Vec<f64> = (0..m.segs.len()).map(|i| m.target_time(i)).collect();
        prop_assume!(t.windows(2).all(|w| w[1] > w[0]));
        let f = eval(&m.corpus(&t), &m.params(), m.beta, &m.opts);
        let r = &m.rows[p];
        let want = r[Param::Target.index()] * (1.0 + r[Param::Sigma.index()]);
        for (i, &(q, _, _)) in m.segs.iter().enumerate() {
            if q == p {
                prop_assert!((f[i] - want).abs() <= 1e-12 * want.abs().max(1.0), "segment {}: F = {}, T(1+σ) = {}", i, f[i], want);
            }
        }
    }

    /// Must 2/4 and §3.1: F is continuous in every k_R, including k_R → 1.
    #[test]
    fn continuous_in_resistance(m in model_strategy(7), pick in 0usize..4, k0 in prop_oneof![Just(1.0f64), 0.0..1.0f64]) {
        let mut m = m;
        let p = pick % m.n_phonemes();
        m.rows[p][Param::KR.index()] = k0;
        let times = m.times(61);
        let base = eval(&m.corpus(&times), &m.params(), m.beta, &m.opts);
        let eps = 1e-9;
        let mut near = m.clone();
        near.rows[p][Param::KR.index()] = if k0 >= 1.0 { k0 - eps } else { k0 + eps };
        let moved = eval(&near.corpus(&times), &near.params(), near.beta, &near.opts);
        for (a, b) in base.iter().zip(&moved) {
            prop_assert!((a - b).abs() <= 1e-6 * scale_of(&m), "{} vs {}", a, b);
        }
    }

    /// §3.1: F is smooth (C¹) where a neighbour's resistance reaches zero, i.e. at
    /// t_j ± Δ±_j, away from the target times (where |τ|^c has its own kink).
    #[test]
    fn smooth_where_resistance_cuts_off(m in model_strategy(7)) {
        let (fwd, bwd) = extents(&m);
        let n = m.segs.len();
        let t: Vec<f64> = (0..n).map(|i| m.target_time(i)).collect();
        let mut cuts = Vec::new();
        for j in 0..n {
            if j + 1 < n { cuts.push(t[j] + fwd[j]); }
            if j > 0 { cuts.push(t[j] - bwd[j]); }
        }
        for &tc in &cuts {
            if t.iter().any(|&ti| (ti - tc).abs() < 5e-3) {
                continue;
            }
            let (k1, k2) = kink(&m, tc);
            prop_assert!(smooth_at(&m, tc), "kink at cut-off t = {}: {} then {}", tc, k1, k2);
        }
    }
}

/// The kink detector of the smoothness test is not blind: with β = 0, ρ is a step (1 inside
/// the extent, 0 beyond), and F jumps at the cut-off.
#[test]
fn kink_detector_flags_a_step_resistance() {
    let mut m = Model {
        segs: vec![(0, 0.0, 0.1), (1, 0.1, 0.2), (0, 0.2, 0.3), (2, 0.3, 0.45)],
        rows: vec![
            row(0.0, 1.0, 5.0, 5.0, 1.0, 1.0, 0.3, 0.0, 100.0, 0.0),
            row(10.0, 1.0, 5.0, 5.0, 1.0, 1.0, 0.6, 0.0, 100.0, 0.0),
            row(4.0, 1.0, 5.0, 5.0, 1.0, 1.0, 0.2, 0.0, 100.0, 0.0),
        ],
        beta: 1.0,
        opts: ModelOptions::default(),
    };
    let (fwd, _) = extents(&m);
    let tc = m.target_time(1) + fwd[1];
    assert!(smooth_at(&m, tc), "β > 0: smooth at the cut-off");
    m.beta = 0.0;
    assert!(!smooth_at(&m, tc), "β = 0: a jump at the cut-off");
}

/// With k_R < 1 next door the target is not reached exactly: the k_R = 1 property is not a
/// property of every phoneme.
#[test]
fn partially_resistant_phoneme_undershoots() {
    let mut m = Model {
        segs: vec![
            (0, 0.0, 0.1),
            (1, 0.1, 0.2),
            (2, 0.2, 0.3),
            (1, 0.3, 0.4),
            (0, 0.4, 0.5),
        ],
        rows: vec![
            row(0.0, 1.0, 20.0, 20.0, 1.0, 1.0, 0.0, 0.0, 100.0, 0.0),
            row(12.0, 1.0, 20.0, 20.0, 1.0, 1.0, 0.2, 0.0, 100.0, 0.0),
            row(-1.0, 1.0, 20.0, 20.0, 1.0, 1.0, 1.0, 0.0, 100.0, 0.0),
        ],
        beta: 1.0,
        opts: ModelOptions::default(),
    };
    let tp = m.target_time(2);
    let f = eval(&m.corpus(&[tp]), &m.params(), m.beta, &m.opts)[0];
    assert!((f - (-1.0)).abs() < 1e-12);
    m.rows[2][Param::KR.index()] = 0.8;
    let f = eval(&m.corpus(&[tp]), &m.params(), m.beta, &m.opts)[0];
    assert!(f > -1.0 + 0.1, "k_R = 0.8 undershoots: F = {f}");
}
