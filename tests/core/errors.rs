//! Every bad input gets the error that names what is at fault.

use crate::common::*;
use coartic::{
    evaluate, jacobian, sse_gradient, validate_params, Corpus, ModelError, ModelOptions, Param,
    Variant, N_PARAMS,
};

fn good_params() -> Vec<f64> {
    flat(&[
        row(0.0, 1.0, 10.0, 10.0, 1.0, 1.0, 0.5, 0.1, 100.0, 0.0),
        row(5.0, 1.0, 20.0, 20.0, 1.0, 1.0, 1.0, 0.0, 100.0, 0.01),
    ])
}

fn corpus(
    seg_offsets: Vec<usize>,
    seg_phoneme: Vec<usize>,
    start: Vec<f64>,
    end: Vec<f64>,
    sample_offsets: Vec<usize>,
    times: Vec<f64>,
) -> Result<Corpus, ModelError> {
    Corpus::new(
        seg_offsets,
        seg_phoneme,
        start,
        end,
        sample_offsets,
        times,
        2,
    )
}

#[test]
fn corpus_errors_name_the_culprit() {
    use ModelError::*;
    let e = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            LengthMismatch {
                what: "seg_start",
                got: 1,
                expected: 2
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(matches!(e, LengthMismatch { .. }), "{e:?}");
    let e = corpus(
        vec![1, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            BadOffsets {
                what: "seg_offsets",
                index: 0,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2, 1, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1, 1, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            BadOffsets {
                what: "seg_offsets",
                index: 2,
                value: 1,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 2],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            BadOffsets {
                what: "sample_offsets",
                index: 1,
                value: 2,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, f64::NAN],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            NonFiniteTime {
                what: "seg_start",
                index: 1,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![f64::INFINITY],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            NonFiniteTime {
                what: "sample_times",
                index: 0,
                ..
            }
        ),
        "{e:?}"
    );
    // Segment 1 of utterance 1 (global 3) is empty.
    let e = corpus(
        vec![0, 2, 4],
        vec![0, 1, 0, 1],
        vec![0.0, 0.1, 0.0, 0.2],
        vec![0.1, 0.2, 0.1, 0.2],
        vec![0, 1, 2],
        vec![0.0, 0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            EmptySegment {
                utterance: 1,
                segment: 1,
                global: 3,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 3],
        vec![0, 1, 0],
        vec![0.0, 0.1, 0.15],
        vec![0.1, 0.2, 0.3],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            OverlappingSegments {
                utterance: 0,
                segment: 2,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![1, 0],
        vec![0.2, 0.0],
        vec![0.3, 0.1],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(e, OverlappingSegments { segment: 1, .. }),
        "unsorted: {e:?}"
    );
    let e = corpus(
        vec![0, 2],
        vec![0, 2],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            PhonemeOutOfRange {
                segment: 1,
                phoneme: 2,
                n_phonemes: 2,
                ..
            }
        ),
        "{e:?}"
    );
    let e = corpus(
        vec![0, 2, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 1, 3],
        vec![0.0, 0.1, 0.2],
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            NoSegments {
                utterance: 1,
                n_samples: 2
            }
        ),
        "{e:?}"
    );
    // Touching segments and samples outside the segments are fine.
    corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 2],
        vec![-1.0, 5.0],
    )
    .unwrap();
    // Messages name the array and the index.
    let msg = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, f64::NAN],
        vec![0.1, 0.2],
        vec![0, 1],
        vec![0.0],
    )
    .unwrap_err()
    .to_string();
    assert!(msg.contains("seg_start[1]"), "{msg}");
}

#[test]
fn parameter_errors_name_phoneme_and_parameter() {
    use ModelError::*;
    let opts = ModelOptions::default();
    let cases: &[(Param, f64, &str)] = &[
        (Param::Alpha, 0.0, "> 0"),
        (Param::ThetaBw, -1.0, "> 0"),
        (Param::ThetaFw, 0.0, "> 0"),
        (Param::CBw, 0.0, "> 0"),
        (Param::CFw, -0.5, "> 0"),
        (Param::KR, 1.5, "[0, 1]"),
        (Param::KR, -0.1, "[0, 1]"),
        (Param::Psi, -1.0, ">= 0"),
    ];
    for &(param, value, domain) in cases {
        let mut p = good_params();
        p[N_PARAMS + param.index()] = value;
        let e = validate_params(&p, 2, 1.0, &opts).unwrap_err();
        assert_eq!(
            e,
            ParameterOutOfDomain {
                phoneme: 1,
                param,
                value,
                domain
            }
        );
        assert!(e.to_string().contains(param.name()));
    }
    for param in Param::ALL {
        let mut p = good_params();
        p[param.index()] = f64::NAN;
        let e = validate_params(&p, 2, 1.0, &opts).unwrap_err();
        assert!(
            matches!(e, NonFiniteParameter { phoneme: 0, param: q, .. } if q == param),
            "{e:?}"
        );
    }
    let e = validate_params(&good_params(), 2, -0.1, &opts).unwrap_err();
    assert!(matches!(e, BadGlobal { name: "beta", .. }), "{e:?}");
    let e = validate_params(
        &good_params(),
        2,
        1.0,
        &ModelOptions {
            edge_extent: 0.0,
            ..opts
        },
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            BadGlobal {
                name: "edge_extent",
                ..
            }
        ),
        "{e:?}"
    );
    let e = validate_params(
        &good_params(),
        2,
        1.0,
        &ModelOptions {
            apex_fraction: 1.2,
            ..opts
        },
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            BadGlobal {
                name: "apex_fraction",
                ..
            }
        ),
        "{e:?}"
    );
    let e = validate_params(&good_params()[..15], 2, 1.0, &opts).unwrap_err();
    assert!(
        matches!(
            e,
            LengthMismatch {
                got: 15,
                expected: 20,
                ..
            }
        ),
        "{e:?}"
    );
    // The original model ignores k_R, σ, ψ and β.
    let mut p = good_params();
    p[Param::KR.index()] = 7.0;
    p[Param::Psi.index()] = -1.0;
    validate_params(
        &p,
        2,
        -3.0,
        &ModelOptions {
            variant: Variant::Original,
            ..opts
        },
    )
    .unwrap();
    assert_eq!("modified".parse::<Variant>().unwrap(), Variant::Modified);
    assert_eq!("original".parse::<Variant>().unwrap(), Variant::Original);
    assert!("Modified".parse::<Variant>().is_err());
}

#[test]
fn evaluation_errors() {
    use ModelError::*;
    let c = corpus(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 3],
        vec![0.0, 0.1, 0.2],
    )
    .unwrap();
    let opts = ModelOptions::default();
    let p = good_params();
    let mut out = vec![0.0; 2];
    assert!(matches!(
        evaluate(&c, &p, 1.0, &opts, &mut out),
        Err(LengthMismatch {
            got: 2,
            expected: 3,
            ..
        })
    ));
    let mut bad = p.clone();
    bad[Param::Alpha.index()] = -1.0;
    let mut out = vec![0.0; 3];
    assert!(matches!(
        evaluate(&c, &bad, 1.0, &opts, &mut out),
        Err(ParameterOutOfDomain {
            phoneme: 0,
            param: Param::Alpha,
            ..
        })
    ));
    assert!(matches!(
        jacobian(&c, &bad, 1.0, &opts, &mut out),
        Err(ParameterOutOfDomain { .. })
    ));
    let mut g = vec![0.0; 20];
    let y = [1.0, f64::NAN, 2.0];
    let e = sse_gradient(&c, &p, 1.0, &opts, &y, &[1.0, 1.0, 1.0], &mut g).unwrap_err();
    assert!(matches!(e, NonFiniteObserved { sample: 1, .. }), "{e:?}");
    sse_gradient(&c, &p, 1.0, &opts, &y, &[1.0, 0.0, 1.0], &mut g).unwrap();
    let e = sse_gradient(&c, &p, 1.0, &opts, &[1.0; 3], &[1.0, -1.0, 1.0], &mut g).unwrap_err();
    assert!(matches!(e, BadWeight { sample: 1, .. }), "{e:?}");
    let e = sse_gradient(&c, &p, 1.0, &opts, &[1.0; 3], &[1.0; 3], &mut g[..10]).unwrap_err();
    assert!(
        matches!(
            e,
            LengthMismatch {
                got: 10,
                expected: 20,
                ..
            }
        ),
        "{e:?}"
    );
    // residual_sums_batch checks both outputs and the observations like sse_batch
    let (mut sse, mut sums) = (vec![0.0; 1], vec![0.0; 2]);
    let e = coartic::residual_sums_batch(
        &c,
        &p,
        &[1.0],
        &opts,
        &[1.0; 3],
        &[1.0; 3],
        &mut sse,
        &mut sums,
    )
    .unwrap_err();
    assert!(
        matches!(
            e,
            LengthMismatch {
                got: 2,
                expected: 1,
                ..
            }
        ),
        "{e:?}"
    );
    let mut sums = vec![0.0; 1];
    let e = coartic::residual_sums_batch(&c, &p, &[1.0], &opts, &y, &[1.0; 3], &mut sse, &mut sums)
        .unwrap_err();
    assert!(matches!(e, NonFiniteObserved { sample: 1, .. }), "{e:?}");
    coartic::residual_sums_batch(
        &c,
        &p,
        &[1.0],
        &opts,
        &[1.0; 3],
        &[1.0; 3],
        &mut sse,
        &mut sums,
    )
    .unwrap();
    assert!(sse[0].is_finite() && sums[0].is_finite());
}

/// θ|τ|^c overflowing to +∞ for every segment leaves no weight at all: an error naming the
/// sample (never NaN), and +∞ for that walker in sse_batch.
#[test]
fn degenerate_weights_are_an_error_not_nan() {
    let c = Corpus::new(
        vec![0, 2],
        vec![0, 1],
        vec![0.0, 0.1],
        vec![0.1, 0.2],
        vec![0, 2],
        vec![0.15, 50.0],
        2,
    )
    .unwrap();
    let p = flat(&[
        row(0.0, 1.0, 1e306, 1e306, 3.0, 3.0, 0.5, 0.0, 1.0, 0.0),
        row(5.0, 1.0, 1e306, 1e306, 3.0, 3.0, 0.5, 0.0, 1.0, 0.0),
    ]);
    let opts = ModelOptions {
        variant: Variant::Original,
        ..ModelOptions::default()
    };
    let mut out = vec![0.0; 2];
    let e = evaluate(&c, &p, 1.0, &opts, &mut out).unwrap_err();
    assert_eq!(
        e,
        ModelError::Degenerate {
            utterance: 0,
            sample: 1
        }
    );
    assert!(jacobian(&c, &p, 1.0, &opts, &mut out).is_err());
    let mut sse = vec![0.0; 1];
    coartic::sse_batch(&c, &p, &[1.0], &opts, &[0.0, 0.0], &[1.0, 1.0], &mut sse).unwrap();
    assert_eq!(sse[0], f64::INFINITY);
}
