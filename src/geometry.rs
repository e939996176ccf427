//! Marker geometry (MODEL.md §6): a head frame per frame from NOSE, EAR_L, EAR_R, and the
//! articulatory channels ULO, LLO, ULP, LLP, LR, JO plus lip aperture LA.
//!
//! Marker arrays are flat, row-major `[frame][marker][xyz]` in mm; a missing (occluded) marker is
//! NaN in any coordinate. Nothing here panics on data: a channel that needs a missing marker, or a
//! degenerate head frame (ears coincide, nose on the ear axis), is NaN in that frame.

use glam::{DMat3, DVec3};
use thiserror::Error;

/// Marker order of [`marker_channels`] (the second axis of its input).
pub const MARKER_NAMES: [&str; 8] = ["NOSE", "EAR_L", "EAR_R", "UL", "LL", "LC_L", "LC_R", "CHIN"];
/// Column order of [`marker_channels`]' output.
pub const CHANNEL_NAMES: [&str; 7] = ["ULO", "LLO", "ULP", "LLP", "LR", "JO", "LA"];
pub const N_MARKERS: usize = 8;
pub const N_CHANNELS: usize = 7;

const NOSE: usize = 0;
const EAR_L: usize = 1;
const EAR_R: usize = 2;
const UL: usize = 3;
const LL: usize = 4;
const LC_L: usize = 5;
const LC_R: usize = 6;
const CHIN: usize = 7;

/// Invalid shapes or indices given to the geometry functions.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum GeometryError {
    #[error("length mismatch: {what} has length {got}, expected {expected}")]
    LengthMismatch {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what} = {index} is not a marker index (there are {n_markers} markers)")]
    MarkerIndex {
        what: &'static str,
        index: usize,
        n_markers: usize,
    },
    #[error(
        "rest selects {n_rest} frame(s), none with UL and LL visible and a defined head frame: \
         y_0 (the rest lip height, MODEL.md §6) needs at least one"
    )]
    NoRestFrame { n_rest: usize },
}

/// An orthonormal head frame: `axes` has the head x, y, z axes (in lab coordinates) as columns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadFrame {
    pub origin: DVec3,
    pub axes: DMat3,
}

impl HeadFrame {
    /// Origin at the ear midpoint, x from EAR_R to EAR_L, z towards NOSE made orthogonal to x,
    /// y = z × x (up). `None` if a marker is missing or the three are (nearly) collinear.
    pub fn from_markers(nose: DVec3, ear_l: DVec3, ear_r: DVec3) -> Option<HeadFrame> {
        let origin = 0.5 * (ear_l + ear_r);
        let x = (ear_l - ear_r).try_normalize()?;
        let to_nose = nose - origin;
        let z_perp = to_nose - to_nose.dot(x) * x;
        // A nose within a micrometre of the ear axis is a broken recording, not a face.
        let len = z_perp.length();
        if len.is_nan() || len < 1e-3 {
            return None;
        }
        let z = z_perp.normalize();
        let y = z.cross(x);
        Some(HeadFrame {
            origin,
            axes: DMat3::from_cols(x, y, z),
        })
    }

    /// A lab-frame point expressed in head coordinates.
    pub fn to_head(&self, p: DVec3) -> DVec3 {
        self.axes.transpose() * (p - self.origin)
    }
}

fn point(markers: &[f64], frame: usize, n_markers: usize, m: usize) -> DVec3 {
    let k = (frame * n_markers + m) * 3;
    DVec3::new(markers[k], markers[k + 1], markers[k + 2])
}

fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), GeometryError> {
    if got == expected {
        Ok(())
    } else {
        Err(GeometryError::LengthMismatch {
            what,
            got,
            expected,
        })
    }
}

/// Express every marker of every frame in that frame's head frame.
///
/// `markers` and `out` are `[n_frames][n_markers][3]`; a frame whose head frame is undefined is
/// all NaN in `out`, a missing marker stays NaN.
pub fn head_frame(
    markers: &[f64],
    n_frames: usize,
    n_markers: usize,
    nose: usize,
    ear_l: usize,
    ear_r: usize,
    out: &mut [f64],
) -> Result<(), GeometryError> {
    check_len("markers", markers.len(), n_frames * n_markers * 3)?;
    check_len("out", out.len(), n_frames * n_markers * 3)?;
    for (what, index) in [("nose", nose), ("ear_l", ear_l), ("ear_r", ear_r)] {
        if index >= n_markers {
            return Err(GeometryError::MarkerIndex {
                what,
                index,
                n_markers,
            });
        }
    }
    for f in 0..n_frames {
        let frame = HeadFrame::from_markers(
            point(markers, f, n_markers, nose),
            point(markers, f, n_markers, ear_l),
            point(markers, f, n_markers, ear_r),
        );
        for m in 0..n_markers {
            let k = (f * n_markers + m) * 3;
            let q = match frame {
                Some(h) => h.to_head(point(markers, f, n_markers, m)),
                None => DVec3::NAN,
            };
            out[k..k + 3].copy_from_slice(&q.to_array());
        }
    }
    Ok(())
}

/// The channels ULO, LLO, ULP, LLP, LR, JO, LA (columns in [`CHANNEL_NAMES`] order) of every frame.
///
/// `markers` is `[n_frames][8][3]` in [`MARKER_NAMES`] order; `rest[f]` marks the rest frames
/// whose mean lip height (UL_y + LL_y)/2 is y_0; `out` is `[n_frames][7]`. Distances (LR, JO, LA)
/// need no head frame; heights and protrusions (ULO, LLO, ULP, LLP) do.
pub fn marker_channels(
    markers: &[f64],
    n_frames: usize,
    rest: &[bool],
    out: &mut [f64],
) -> Result<(), GeometryError> {
    check_len("markers", markers.len(), n_frames * N_MARKERS * 3)?;
    check_len("rest", rest.len(), n_frames)?;
    check_len("out", out.len(), n_frames * N_CHANNELS)?;
    if n_frames == 0 {
        return Ok(()); // nothing to measure, so no y_0 needed
    }
    let p = |f: usize, m: usize| point(markers, f, N_MARKERS, m);
    let mut lips = Vec::with_capacity(n_frames);
    for f in 0..n_frames {
        let ul_ll = match HeadFrame::from_markers(p(f, NOSE), p(f, EAR_L), p(f, EAR_R)) {
            Some(h) => (h.to_head(p(f, UL)), h.to_head(p(f, LL))),
            None => (DVec3::NAN, DVec3::NAN),
        };
        lips.push(ul_ll);
    }
    let (mut sum, mut count) = (0.0, 0usize);
    for (&(ul, ll), _) in lips.iter().zip(rest).filter(|(_, &r)| r) {
        let mid = 0.5 * (ul.y + ll.y);
        if mid.is_finite() {
            sum += mid;
            count += 1;
        }
    }
    if count == 0 {
        return Err(GeometryError::NoRestFrame {
            n_rest: rest.iter().filter(|&&r| r).count(),
        });
    }
    let y0 = sum / count as f64;
    for (f, &(ul, ll)) in lips.iter().enumerate() {
        let row = &mut out[f * N_CHANNELS..(f + 1) * N_CHANNELS];
        row[0] = ul.y - y0;
        row[1] = y0 - ll.y;
        row[2] = ul.z;
        row[3] = ll.z;
        row[4] = p(f, LC_L).distance(p(f, LC_R));
        row[5] = p(f, NOSE).distance(p(f, CHIN));
        row[6] = p(f, UL).distance(p(f, LL));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;
    use proptest::prelude::*;

    /// A face in its own head frame (mm): ears at x = ±70, nose 100 mm in front, lips below it.
    fn face(jaw: f64) -> [DVec3; 8] {
        [
            DVec3::new(0.0, 0.0, 100.0),        // NOSE
            DVec3::new(70.0, 0.0, 0.0),         // EAR_L
            DVec3::new(-70.0, 0.0, 0.0),        // EAR_R
            DVec3::new(0.0, -20.0, 95.0),       // UL
            DVec3::new(0.0, -30.0 - jaw, 93.0), // LL
            DVec3::new(25.0, -25.0, 85.0),      // LC_L
            DVec3::new(-24.0, -25.0, 85.0),     // LC_R
            DVec3::new(0.0, -60.0 - jaw, 90.0), // CHIN
        ]
    }

    fn flatten(frames: &[[DVec3; 8]]) -> Vec<f64> {
        frames
            .iter()
            .flat_map(|f| f.iter().flat_map(|p| p.to_array()))
            .collect()
    }

    fn channels(frames: &[[DVec3; 8]], rest: &[bool]) -> Vec<f64> {
        let mut out = vec![0.0; frames.len() * N_CHANNELS];
        marker_channels(&flatten(frames), frames.len(), rest, &mut out).unwrap();
        out
    }

    #[test]
    fn known_geometry_gives_known_channels() {
        let frames = [face(0.0), face(8.0)];
        let out = channels(&frames, &[true, false]);
        let y0 = -25.0; // (UL_y + LL_y) / 2 at rest
                        // JO: nose (0, 0, 100) to chin (0, -60 - jaw, 90); LA: UL (0, -20, 95) to LL (0, -30 - jaw, 93).
        let jo0 = (60.0f64 * 60.0 + 10.0 * 10.0).sqrt();
        let jo1 = (68.0f64 * 68.0 + 10.0 * 10.0).sqrt();
        let la1 = (18.0f64 * 18.0 + 2.0 * 2.0).sqrt();
        let la0 = (10.0f64 * 10.0 + 2.0 * 2.0).sqrt();
        let want = [
            [-20.0 - y0, y0 + 30.0, 95.0, 93.0, 49.0, jo0, la0],
            [5.0, 13.0, 95.0, 93.0, 49.0, jo1, la1],
        ];
        for f in 0..2 {
            for c in 0..N_CHANNELS {
                assert!(
                    (out[f * N_CHANNELS + c] - want[f][c]).abs() < 1e-12,
                    "frame {f} {}",
                    CHANNEL_NAMES[c]
                );
            }
        }
    }

    #[test]
    fn missing_markers_give_nan_only_where_needed() {
        let mut frames = vec![face(0.0), face(3.0), face(3.0)];
        frames[1][UL] = DVec3::new(f64::NAN, 0.0, 0.0);
        frames[2][NOSE] = DVec3::NAN;
        let out = channels(&frames, &[true, true, true]);
        let row = |f: usize| &out[f * N_CHANNELS..(f + 1) * N_CHANNELS];
        // Frame 1: UL missing → ULO, ULP, LA NaN; the rest defined.
        let nan1: Vec<bool> = row(1).iter().map(|v| v.is_nan()).collect();
        assert_eq!(nan1, [true, false, true, false, false, false, true]);
        // Frame 2: no head frame → heights and protrusions NaN, and JO needs the nose.
        let nan2: Vec<bool> = row(2).iter().map(|v| v.is_nan()).collect();
        assert_eq!(nan2, [true, true, true, true, false, true, false]);
        // y_0 comes from frame 0 only (the others have no usable UL/LL): ULO at rest is 5.
        assert!((row(0)[0] - 5.0).abs() < 1e-12);
    }

    #[test]
    fn degenerate_head_frame_is_nan_and_no_rest_frame_is_an_error() {
        let mut f = face(0.0);
        f[EAR_L] = f[EAR_R];
        let mut out = vec![0.0; N_CHANNELS];
        let err = marker_channels(&flatten(&[f]), 1, &[true], &mut out).unwrap_err();
        assert_eq!(err, GeometryError::NoRestFrame { n_rest: 1 });
        let err = marker_channels(&flatten(&[face(0.0)]), 1, &[false], &mut out).unwrap_err();
        assert_eq!(err, GeometryError::NoRestFrame { n_rest: 0 });
        let mut hf = vec![0.0; 24];
        head_frame(&flatten(&[f]), 1, 8, NOSE, EAR_L, EAR_R, &mut hf).unwrap();
        assert!(hf.iter().all(|v| v.is_nan()));
        // Nose on the ear axis.
        let mut g = face(0.0);
        g[NOSE] = DVec3::new(10.0, 0.0, 0.0);
        head_frame(&flatten(&[g]), 1, 8, NOSE, EAR_L, EAR_R, &mut hf).unwrap();
        assert!(hf.iter().all(|v| v.is_nan()));
    }

    #[test]
    fn bad_shapes_and_indices_are_errors() {
        let m = flatten(&[face(0.0)]);
        let mut out = vec![0.0; 7];
        assert!(matches!(
            marker_channels(&m, 2, &[true, true], &mut out),
            Err(GeometryError::LengthMismatch {
                what: "markers",
                ..
            })
        ));
        assert!(matches!(
            marker_channels(&m, 1, &[true, true], &mut out),
            Err(GeometryError::LengthMismatch { what: "rest", .. })
        ));
        let mut hf = vec![0.0; 24];
        assert_eq!(
            head_frame(&m, 1, 8, 8, 1, 2, &mut hf),
            Err(GeometryError::MarkerIndex {
                what: "nose",
                index: 8,
                n_markers: 8
            })
        );
    }

    #[test]
    fn head_frame_of_an_unmoved_face_is_the_identity() {
        let f = face(2.0);
        let m = flatten(&[f]);
        let mut hf = vec![0.0; 24];
        head_frame(&m, 1, 8, NOSE, EAR_L, EAR_R, &mut hf).unwrap();
        for (a, b) in hf.iter().zip(&m) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    proptest! {
        /// Moving the whole head rigidly changes no channel and no head-frame coordinate.
        #[test]
        fn rigid_motion_leaves_channels_unchanged(
            ax in -1.0f64..1.0, ay in -1.0f64..1.0, az in -1.0f64..1.0, angle in -3.1f64..3.1,
            tx in -500.0f64..500.0, ty in -500.0f64..500.0, tz in -500.0f64..500.0,
            jaw in 0.0f64..20.0,
        ) {
            let axis = DVec3::new(ax, ay, az);
            prop_assume!(axis.length() > 0.1);
            let rot = DQuat::from_axis_angle(axis.normalize(), angle);
            let shift = DVec3::new(tx, ty, tz);
            let still = [face(0.0), face(jaw)];
            let moved: Vec<[DVec3; 8]> = still.iter().map(|f| f.map(|p| rot * p + shift)).collect();
            let a = channels(&still, &[true, false]);
            let b = channels(&moved, &[true, false]);
            for (x, y) in a.iter().zip(&b) {
                prop_assert!((x - y).abs() < 1e-9, "{} vs {}", x, y);
            }
            let mut ha = vec![0.0; 48];
            let mut hb = vec![0.0; 48];
            head_frame(&flatten(&still), 2, 8, NOSE, EAR_L, EAR_R, &mut ha).unwrap();
            head_frame(&flatten(&moved), 2, 8, NOSE, EAR_L, EAR_R, &mut hb).unwrap();
            for (x, y) in ha.iter().zip(&hb) {
                prop_assert!((x - y).abs() < 1e-9);
            }
        }
    }
}
