//! The exp/ln kernels against std (glibc's, itself within 1 ulp) over wide ranges, their special
//! values, and the four-lane AVX2 path against the scalar one, bit for bit.

use coartic::vector_math::{exp, exp_in_place, ln, ln_in_place};

/// Distance in units in the last place, on the ordered integer line of f64 bit patterns (so it
/// is meaningful across the subnormal range and across zero).
fn ulps(a: f64, b: f64) -> u64 {
    let key = |x: f64| {
        let b = x.to_bits() as i64;
        if b < 0 {
            i64::MIN - b
        } else {
            b
        }
    };
    key(a).abs_diff(key(b))
}

/// splitmix64, deterministic.
struct Rng(u64);
impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn worst(f: impl Fn(f64) -> f64, g: impl Fn(f64) -> f64, xs: &[f64]) -> (u64, f64) {
    xs.iter()
        .map(|&x| (ulps(f(x), g(x)), x))
        .max_by_key(|p| p.0)
        .unwrap()
}

#[test]
fn exp_within_one_ulp_of_std_everywhere() {
    let mut rng = Rng(1);
    let mut xs: Vec<f64> = (0..200_000).map(|_| -745.2 + 1455.0 * rng.unit()).collect();
    // Where the model evaluates it: weights exp(≤ 0), powers exp(c ln|τ|), shapes exp(−ψτ²).
    xs.extend((0..200_000).map(|_| -40.0 + 45.0 * rng.unit()));
    xs.extend((0..50_000).map(|_| 1e-3 * (rng.unit() - 0.5)));
    // The subnormal results and the edges of the range.
    xs.extend((0..50_000).map(|_| -745.14 + 37.0 * rng.unit()));
    xs.extend([
        0.0,
        -0.0,
        1.0,
        -1.0,
        709.78,
        709.782712893383,
        -745.13,
        -745.1332191019411,
    ]);
    let (u, x) = worst(exp, f64::exp, &xs);
    assert!(
        u <= 1,
        "exp({x:e}) is {u} ulp from std: {} vs {}",
        exp(x),
        x.exp()
    );
}

#[test]
fn ln_within_one_ulp_of_std_everywhere() {
    let mut rng = Rng(2);
    // Log-uniform over the whole positive range, subnormals included.
    let mut xs: Vec<f64> = (0..200_000)
        .map(|_| (2f64).powf(-1074.0 + 2098.0 * rng.unit()))
        .collect();
    xs.extend((0..200_000).map(|_| 1e-4 + 3.0 * rng.unit()));
    // Near 1, where ln is small and relative accuracy is hardest.
    xs.extend((0..100_000).map(|_| 1.0 + 1e-6 * (rng.unit() - 0.5)));
    xs.extend((0..1000).map(|i| f64::from_bits(1 + 7919 * i as u64)));
    xs.extend([
        f64::MIN_POSITIVE,
        5e-324,
        f64::MAX,
        1.0,
        2.0,
        0.5,
        std::f64::consts::SQRT_2,
    ]);
    let (u, x) = worst(ln, f64::ln, &xs);
    assert!(
        u <= 1,
        "ln({x:e}) is {u} ulp from std: {} vs {}",
        ln(x),
        x.ln()
    );
    assert_eq!(ln(1.0).to_bits(), 0.0f64.to_bits());
}

#[test]
fn special_values_as_std() {
    assert_eq!(exp(0.0), 1.0);
    assert_eq!(exp(f64::NEG_INFINITY).to_bits(), 0.0f64.to_bits());
    assert_eq!(exp(-1e300).to_bits(), 0.0f64.to_bits());
    assert_eq!(exp(-746.0), 0.0);
    assert_eq!(exp(-745.0), (-745.0f64).exp(), "smallest subnormals");
    assert_eq!(exp(710.0), f64::INFINITY);
    assert_eq!(exp(f64::INFINITY), f64::INFINITY);
    assert!(exp(f64::NAN).is_nan());
    assert_eq!(ln(0.0), f64::NEG_INFINITY);
    assert_eq!(ln(-0.0), f64::NEG_INFINITY);
    assert!(ln(-1.0).is_nan() && ln(-1e-310).is_nan() && ln(f64::NAN).is_nan());
    assert!(ln(f64::NEG_INFINITY).is_nan());
    assert_eq!(ln(f64::INFINITY), f64::INFINITY);
    assert_eq!(ln(5e-324), (5e-324f64).ln());
    // τ = 0 with c ≠ 1: |τ|^c = exp(c ln 0) = exp(−∞) = 0 exactly, as the scalar path's branch.
    assert_eq!(exp(0.7 * ln(0.0)).to_bits(), 0.0f64.to_bits());
}

#[test]
fn four_lanes_equal_the_scalar_kernels_bit_for_bit() {
    let mut rng = Rng(3);
    let mut xs: Vec<f64> = (0..100_000)
        .map(|i| match i % 4 {
            0 => -800.0 + 1600.0 * rng.unit(),
            1 => (2f64).powf(-1074.0 + 2098.0 * rng.unit()),
            2 => -(rng.unit() * 10.0),
            _ => rng.unit() - 0.5,
        })
        .collect();
    xs.extend([
        0.0,
        -0.0,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        5e-324,
        1.0,
        709.9,
        -745.2,
    ]);
    xs.push(0.25); // 100 010 values: the 2 left over go through the padded last block
    let mut e = xs.clone();
    exp_in_place(&mut e);
    let mut l = xs.clone();
    ln_in_place(&mut l);
    for (j, &x) in xs.iter().enumerate() {
        assert_eq!(e[j].to_bits(), exp(x).to_bits(), "exp({x:e})");
        assert_eq!(l[j].to_bits(), ln(x).to_bits(), "ln({x:e})");
    }
}

mod lanes_in_the_model {
    use coartic::targets::target_time;
    use coartic::{
        evaluate, jacobian, sse_batch, Corpus, ModelError, ModelOptions, Param, N_PARAMS,
    };

    fn row(alpha: f64, c_bw: f64, c_fw: f64, k_r: f64, sigma: f64) -> [f64; N_PARAMS] {
        let mut r = [0.0; N_PARAMS];
        r[Param::Target.index()] = 3.0 + alpha;
        r[Param::Alpha.index()] = alpha;
        r[Param::ThetaBw.index()] = 25.0;
        r[Param::ThetaFw.index()] = 12.0;
        r[Param::CBw.index()] = c_bw;
        r[Param::CFw.index()] = c_fw;
        r[Param::KR.index()] = k_r;
        r[Param::Sigma.index()] = sigma;
        r[Param::Psi.index()] = 300.0;
        r
    }

    /// Four segments; samples exactly at every target time (τ = 0, where ln|τ| = −∞ and c ≠ 1),
    /// beyond the extents, and a count (23) that leaves a partial block of lanes.
    fn corpus(last: f64) -> (Corpus, Vec<f64>) {
        let starts = [0.0, 0.12, 0.2, 0.31];
        let ends = [0.12, 0.2, 0.31, 0.45];
        let mut times: Vec<f64> = (0..18).map(|k| -0.1 + 0.04 * k as f64).collect();
        for (s, e) in starts.iter().zip(&ends) {
            times.push(target_time(*s, *e, 0.5, 0.0).0);
        }
        times.push(last);
        times.sort_by(f64::total_cmp);
        let n = times.len();
        let c = Corpus::new(
            vec![0, 4],
            vec![0, 1, 2, 3],
            starts.to_vec(),
            ends.to_vec(),
            vec![0, n],
            times.clone(),
            4,
        )
        .unwrap();
        (c, times)
    }

    fn params() -> Vec<f64> {
        [
            row(0.7, 0.6, 1.0, 0.3, 0.0),
            row(1.3, 1.0, 1.0, 1.0, 0.2),
            row(0.4, 2.2, 1.7, 0.6, -0.1),
            row(2.0, 1.0, 0.8, 0.0, 0.0),
        ]
        .concat()
    }

    #[test]
    fn evaluate_equals_jacobian_values_bit_for_bit_at_tau_zero_and_a_partial_block() {
        let (c, times) = corpus(1.0);
        assert_eq!(times.len() % 4, 3);
        let p = params();
        for opts in [
            ModelOptions::default(),
            ModelOptions {
                variant: coartic::Variant::Original,
                ..ModelOptions::default()
            },
        ] {
            let mut f = vec![0.0; times.len()];
            evaluate(&c, &p, 0.9, &opts, &mut f).unwrap();
            let mut v = vec![0.0; times.len()];
            jacobian(&c, &p, 0.9, &opts, &mut v).unwrap();
            for (n, (a, b)) in f.iter().zip(&v).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "sample {n} at t = {}: {a} vs {b}",
                    times[n]
                );
            }
        }
    }

    #[test]
    fn degenerate_sample_in_a_block_is_an_error_unless_unweighted() {
        // The last sample, far after every target, lies beyond every extent but the last
        // segment's (+∞), where θ_fw |τ|^c overflows: every weight is zero there.
        let (c, times) = corpus(1000.0);
        let opts = ModelOptions::default();
        let mut p = params();
        for r in p.chunks_exact_mut(N_PARAMS) {
            r[Param::ThetaFw.index()] = 1e306;
        }
        let mut f = vec![0.0; times.len()];
        let last = times.len() - 1;
        match evaluate(&c, &p, 0.9, &opts, &mut f) {
            Err(ModelError::Degenerate {
                utterance: 0,
                sample,
            }) => assert_eq!(sample, last),
            other => panic!("expected the degenerate sample {last}, got {other:?}"),
        }
        let y = vec![1.0; times.len()];
        let mut w = vec![1.0; times.len()];
        let mut sse = [0.0];
        sse_batch(&c, &p, &[0.9], &opts, &y, &w, &mut sse).unwrap();
        assert_eq!(sse[0], f64::INFINITY);
        // Unweighted, it no longer matters: the SSE over the others, in sample order.
        w[last] = 0.0;
        sse_batch(&c, &p, &[0.9], &opts, &y, &w, &mut sse).unwrap();
        let mut values = vec![0.0; times.len()];
        assert!(jacobian(&c, &p, 0.9, &opts, &mut values).is_err());
        let mut want = 0.0;
        let mut g = vec![0.0; 1];
        for &t in &times[..last] {
            let one = Corpus::new(
                vec![0, 4],
                vec![0, 1, 2, 3],
                c.seg_start().to_vec(),
                c.seg_end().to_vec(),
                vec![0, 1],
                vec![t],
                4,
            )
            .unwrap();
            evaluate(&one, &p, 0.9, &opts, &mut g).unwrap();
            want += (1.0 - g[0]) * (1.0 - g[0]);
        }
        assert_eq!(sse[0], want);
    }
}
