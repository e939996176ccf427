//! Target times of MODEL.md §1: t_i = clamp(s_i + a·(e_i − s_i) + δ_p(i), s_i, e_i).
//!
//! Clamping into the segment keeps t_1 ≤ t_2 ≤ … ≤ t_N (segments do not overlap), which the
//! extents of §3.1 need.

/// The target time of one segment and whether δ moves it (∂t/∂δ = 1 unless clamped, else 0).
#[inline(always)]
pub fn target_time(start: f64, end: f64, apex_fraction: f64, delta: f64) -> (f64, bool) {
    let raw = start + apex_fraction * (end - start) + delta;
    if raw < start {
        (start, false)
    } else if raw > end {
        (end, false)
    } else {
        // On the closed interval the clamp is the identity, so ∂t/∂δ = 1 (one-sided at the ends).
        (raw, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn apex_lag_and_clamp() {
        assert_eq!(target_time(1.0, 1.2, 0.5, 0.0), (1.1, true));
        let (t, free) = target_time(1.0, 1.2, 0.5, 0.05);
        assert!((t - 1.15).abs() < 1e-15 && free);
        assert_eq!(target_time(1.0, 1.2, 0.5, 0.15), (1.2, false));
        assert_eq!(target_time(1.0, 1.2, 0.5, -0.15), (1.0, false));
    }
}
