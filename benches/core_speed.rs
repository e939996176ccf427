//! Pure-core speed on a corpus of ~600 utterances × 100 samples × 7 segments (the size named in
//! issue 2): evaluation against the physical-limit loop, the Jacobian and the SSE gradient
//! against one evaluation, and the walker batch. Prints times and ratios from one run; the
//! NumPy comparison and the Python-side overhead are in bench/core_speed.py.

use coartic::vector_math::{exp, exp_in_place, ln, ln_in_place, simd_enabled};
use coartic::{
    evaluate, jacobian, jacobian_values, physical_limit_loop, sse_batch, sse_gradient, Corpus,
    ModelOptions, Param, N_PARAMS,
};
use std::hint::black_box;
use std::time::Instant;

/// splitmix64: a deterministic corpus without a rand dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

fn build(n_utt: usize, n_samples: usize, n_seg: usize, n_phonemes: usize, rng: &mut Rng) -> Corpus {
    let (mut so, mut sp, mut ss, mut se, mut to, mut tt) =
        (vec![0], vec![], vec![], vec![], vec![0], vec![]);
    for _ in 0..n_utt {
        let mut t = 0.0;
        for _ in 0..n_seg {
            let d = rng.range(0.05, 0.2);
            sp.push((rng.next() * n_phonemes as f64) as usize % n_phonemes);
            ss.push(t);
            se.push(t + d);
            t += d;
        }
        for k in 0..n_samples {
            tt.push(-0.05 + (t + 0.1) * k as f64 / (n_samples - 1) as f64);
        }
        so.push(sp.len());
        to.push(tt.len());
    }
    Corpus::new(so, sp, ss, se, to, tt, n_phonemes).expect("valid corpus")
}

fn params(n_phonemes: usize, rng: &mut Rng) -> Vec<f64> {
    let mut p = vec![0.0; n_phonemes * N_PARAMS];
    for r in p.chunks_exact_mut(N_PARAMS) {
        r[Param::Target.index()] = rng.range(-5.0, 15.0);
        r[Param::Alpha.index()] = rng.range(0.3, 3.0);
        r[Param::ThetaBw.index()] = rng.range(5.0, 80.0);
        r[Param::ThetaFw.index()] = rng.range(5.0, 80.0);
        r[Param::CBw.index()] = rng.range(0.5, 3.0);
        r[Param::CFw.index()] = rng.range(0.5, 3.0);
        r[Param::KR.index()] = rng.range(0.0, 1.0);
        r[Param::Sigma.index()] = rng.range(-0.3, 0.3);
        r[Param::Psi.index()] = rng.range(50.0, 500.0);
        r[Param::Delta.index()] = rng.range(-0.02, 0.02);
    }
    p
}

/// Median wall time (s) of `reps` runs.
fn time(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(|a, b| a.total_cmp(b));
    t[reps / 2]
}

fn main() {
    let mut rng = Rng(7);
    let n_ph = 24;
    let corpus = build(600, 100, 7, n_ph, &mut rng);
    let p = params(n_ph, &mut rng);
    let opts = ModelOptions::default();
    let beta = 1.0;
    let ns = corpus.n_samples();
    let mut out = vec![0.0; ns];
    let reps = 21;
    // `cargo bench --bench core_speed -- jacobian`: time only the Jacobian (for profiling).
    if std::env::args().any(|a| a == "jacobian") {
        let mut vals = vec![0.0; ns];
        let t = time(reps, || {
            black_box(jacobian(&corpus, &p, beta, &opts, &mut vals).unwrap());
        });
        println!("jacobian {:.3} ms", t * 1e3);
        return;
    }
    kernel_speed(&mut rng);
    let mut vals = vec![0.0; ns];
    evaluate(&corpus, &p, beta, &opts, &mut out).unwrap();
    let observed: Vec<f64> = out.iter().map(|v| v + 0.1).collect();
    let weights = vec![1.0; ns];
    let mut grad = vec![0.0; n_ph * N_PARAMS];
    // Interleaved, so that load from other processes hits every measurement alike.
    let mut runs: [Vec<f64>; 4] = Default::default();
    for _ in 0..reps {
        let s = Instant::now();
        evaluate(&corpus, &p, beta, &opts, &mut out).unwrap();
        runs[0].push(s.elapsed().as_secs_f64());
        let s = Instant::now();
        black_box(physical_limit_loop(&corpus, &p, &opts));
        runs[1].push(s.elapsed().as_secs_f64());
        let s = Instant::now();
        black_box(jacobian(&corpus, &p, beta, &opts, &mut vals).unwrap());
        runs[2].push(s.elapsed().as_secs_f64());
        let s = Instant::now();
        black_box(sse_gradient(&corpus, &p, beta, &opts, &observed, &weights, &mut grad).unwrap());
        runs[3].push(s.elapsed().as_secs_f64());
    }
    let [t_eval, t_limit, t_jac, t_grad] = runs.map(|mut r| {
        r.sort_by(|a, b| a.total_cmp(b));
        r[r.len() / 2]
    });
    // The original model (eq. 1) with c = 1, where the power needs no ln/exp.
    let mut p1 = p.clone();
    for r in p1.chunks_exact_mut(N_PARAMS) {
        r[Param::CBw.index()] = 1.0;
        r[Param::CFw.index()] = 1.0;
    }
    let orig = ModelOptions {
        variant: coartic::Variant::Original,
        ..opts
    };
    let t_orig = time(reps, || {
        evaluate(&corpus, &p1, beta, &orig, &mut out).unwrap()
    });
    let t_orig_limit = time(reps, || {
        black_box(physical_limit_loop(&corpus, &p1, &orig));
    });
    // The values-only Jacobian into a reused buffer (the optimiser's loop).
    let mut jdata = vec![0.0; corpus.jacobian_nnz()];
    let t_jv = time(reps, || {
        jacobian_values(&corpus, &p, beta, &opts, &mut vals, &mut jdata).unwrap();
    });
    let w = 32;
    let batch: Vec<f64> = (0..w).flat_map(|_| p.iter().copied()).collect();
    let betas = vec![beta; w];
    let mut sse = vec![0.0; w];
    let t_batch = time(5, || {
        sse_batch(
            &corpus, &batch, &betas, &opts, &observed, &weights, &mut sse,
        )
        .unwrap()
    });
    println!(
        "corpus: {} utterances, {} samples, {} segments, {} rayon threads",
        corpus.n_utterances(),
        ns,
        corpus.n_segments(),
        rayon::current_num_threads()
    );
    println!("evaluate            {:9.3} ms", t_eval * 1e3);
    println!(
        "physical_limit_loop {:9.3} ms   evaluate / limit   = {:.2}",
        t_limit * 1e3,
        t_eval / t_limit
    );
    println!(
        "jacobian            {:9.3} ms   jacobian / evaluate = {:.2}",
        t_jac * 1e3,
        t_jac / t_eval
    );
    println!(
        "sse_gradient        {:9.3} ms   sse_grad / evaluate = {:.2}",
        t_grad * 1e3,
        t_grad / t_eval
    );
    println!(
        "jacobian_values     {:9.3} ms   (reused buffer) / evaluate = {:.2}",
        t_jv * 1e3,
        t_jv / t_eval
    );
    println!(
        "original, c = 1     {:9.3} ms   evaluate / limit   = {:.2}",
        t_orig * 1e3,
        t_orig / t_orig_limit
    );
    println!(
        "sse_batch W={w}      {:9.3} ms   per walker / evaluate = {:.2}",
        t_batch * 1e3,
        t_batch / w as f64 / t_eval
    );
}

/// ns per value of std's exp/ln (libm), the scalar kernels and the lane path, over arguments like
/// the model's (exp of c ln|τ| and of log-weights; ln of |τ|), single-threaded.
fn kernel_speed(rng: &mut Rng) {
    let n = 1 << 16;
    let ex: Vec<f64> = (0..n).map(|_| rng.range(-30.0, 2.0)).collect();
    let lx: Vec<f64> = (0..n).map(|_| rng.range(1e-4, 1.5)).collect();
    let per = |t: f64| t / n as f64 * 1e9;
    let mut buf = ex.clone();
    let t_std = time(21, || {
        buf.iter_mut()
            .zip(&ex)
            .for_each(|(b, &x)| *b = black_box(x).exp())
    });
    let t_scalar = time(21, || {
        buf.iter_mut()
            .zip(&ex)
            .for_each(|(b, &x)| *b = exp(black_box(x)))
    });
    let t_lanes = time(21, || {
        buf.copy_from_slice(&ex);
        exp_in_place(black_box(&mut buf));
    });
    println!(
        "exp per value: std {:.2} ns, scalar kernel {:.2} ns, lanes {:.2} ns (AVX2 {})",
        per(t_std),
        per(t_scalar),
        per(t_lanes),
        if simd_enabled() { "on" } else { "off" }
    );
    let t_std = time(21, || {
        buf.iter_mut()
            .zip(&lx)
            .for_each(|(b, &x)| *b = black_box(x).ln())
    });
    let t_scalar = time(21, || {
        buf.iter_mut()
            .zip(&lx)
            .for_each(|(b, &x)| *b = ln(black_box(x)))
    });
    let t_lanes = time(21, || {
        buf.copy_from_slice(&lx);
        ln_in_place(black_box(&mut buf));
    });
    println!(
        "ln  per value: std {:.2} ns, scalar kernel {:.2} ns, lanes {:.2} ns",
        per(t_std),
        per(t_scalar),
        per(t_lanes)
    );
}
