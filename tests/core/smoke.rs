use crate::common::*;
use coartic::{ModelOptions, Variant};

/// /# a p a #/ with /p/ fully resistant: F reaches T_p at t_p, at normal and fast speech.
#[test]
fn vcv_bilabial_reaches_target() {
    let params = flat(&[
        row(0.0, 0.5, 10.0, 10.0, 1.0, 1.0, 0.0, 0.0, 100.0, 0.0), // #
        row(12.0, 1.0, 20.0, 20.0, 1.0, 1.0, 0.2, 0.0, 100.0, 0.0), // a
        row(-1.0, 0.8, 30.0, 30.0, 1.0, 1.0, 1.0, 0.0, 100.0, 0.0), // p
    ]);
    for speed in [1.0, 3.0] {
        let seg = |a: f64, b: f64| (a / speed, b / speed);
        let s = [
            (0usize, seg(0.0, 0.2)),
            (1, seg(0.2, 0.35)),
            (2, seg(0.35, 0.45)),
            (1, seg(0.45, 0.6)),
            (0, seg(0.6, 0.8)),
        ];
        let segs: Vec<_> = s.iter().map(|(p, (a, b))| (*p, *a, *b)).collect();
        let tp = (0.35 + 0.45) / 2.0 / speed;
        let c = utterance(&segs, &[tp, 0.3 / speed], 3);
        let f = eval(&c, &params, 1.0, &ModelOptions::default());
        assert!(
            (f[0] - (-1.0)).abs() < 1e-12,
            "speed {speed}: F(t_p) = {}",
            f[0]
        );
        let orig = eval(
            &c,
            &params,
            1.0,
            &ModelOptions {
                variant: Variant::Original,
                ..Default::default()
            },
        );
        assert!(
            (orig[0] - (-1.0)).abs() > 0.1,
            "the original model does not reach it: {}",
            orig[0]
        );
    }
}
