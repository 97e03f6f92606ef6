//! The world's floor (`calibrate floor`, `docs/calibration.md` step 3), fitted to markers
//! triangulated in the rig's present world:
//!
//! - **An L-frame** lying on the floor — its corner marker the origin, its long arm +x, its
//!   short arm +y, z = x × y up (3 markers, or 4 with one more on the long arm) — found among
//!   the steady markers by its pairwise distances (`stereoscope_bodies::identify`, the rigid
//!   bodies' own identification), and fitted by least squares (Kabsch). With `scale` (after a
//!   one-marker wand, whose rig has no scale) it is found by its shape and the rig scaled to its
//!   known lengths.
//! - **Markers on the floor**: their plane by least squares (the eigenvector of the smallest
//!   eigenvalue of their scatter), z towards most cameras, the origin marker's foot on it, +x
//!   towards the x-axis marker's foot (or camera 0's right laid on the floor).
//!
//! Units: metres throughout; `height` is how far the markers' centres are above the floor.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;
use std::collections::BTreeMap;
use stereoscope_bodies::BodyDef;
use stereoscope_geometry::Camera;
use stereoscope_proto::messages::{PoseFrame, PoseMethod};

/// A steady marker: its object id and its median position (the rig's world, metres).
pub type Steady = (u32, Point3<f64>);

/// Fewer triangulations than this make no steady marker, however few frames could show it.
pub const MIN_STEADY_FRAMES: usize = 3;

/// More steady markers than this: the volume is not clear of all but the L-frame.
pub const MAX_L_FRAME_CANDIDATES: usize = 16;

/// Why a floor could not be fitted; each says what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FloorError {
    #[error(
        "the L-frame's long arm (x) then its short arm (y) must be above 0 and different (got {long_m} m and {short_m} m)"
    )]
    Arms { long_m: f64, short_m: f64 },
    #[error(
        "the L-frame's fourth marker must lie between the corner and the end of the long arm ({middle_m} m from the corner, arm {long_m} m)"
    )]
    Middle { middle_m: f64, long_m: f64 },
    #[error("{count} steady markers: clear the volume of all but the L-frame")]
    TooManyMarkers { count: usize },
    #[error(
        "no {wanted} steady markers make an L of {long_mm:.1} × {short_mm:.1} mm{} within {tolerance_mm:.1} mm{} ({count} markers seen in half the frames their cameras were in; their distances: {distances})",
        .middle_mm.map_or(String::new(), |m| format!(" with a marker {m:.1} mm along x")),
        if *.scaled { " (in shape: --scale)" } else { "" }
    )]
    NoLFrame {
        wanted: usize,
        long_mm: f64,
        short_mm: f64,
        middle_mm: Option<f64>,
        tolerance_mm: f64,
        scaled: bool,
        count: usize,
        distances: String,
    },
    #[error("the L-frame's markers are in a line")]
    Collinear,
    #[error("{count} steady markers; the floor needs at least 3 lying on it")]
    TooFewFloorMarkers { count: usize },
    #[error(
        "the {count} floor markers lie (nearly) in a line: spread them over the floor, at least 3 not in a line and apart"
    )]
    FloorInALine { count: usize },
    #[error(
        "the x axis cannot be set: the x-axis marker is within 5 cm of the origin (over the floor): put it farther along +x"
    )]
    XAxisTooNear,
    #[error(
        "the x axis cannot be set: camera 0 looks straight down; record a marker on +x and give it with --x-axis"
    )]
    CameraLooksDown,
}

/// An L-frame: its arms, corner marker to end marker (long +x, short +y), and optionally a
/// fourth marker on the long arm this far from the corner; metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LFrame {
    pub long_m: f64,
    pub short_m: f64,
    pub middle_m: Option<f64>,
}

/// The L-frame's markers (object ids) as found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LFrameFit {
    pub corner: u32,
    pub x_arm: u32,
    pub y_arm: u32,
    pub x_middle: Option<u32>,
    /// How far the y arm was from square to the x arm, degrees.
    pub squareness_error_deg: f64,
}

/// The floor markers' plane as found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointsFit {
    pub floor_markers: Vec<u32>,
    /// The origin marker's distance above the floor markers' plane, mm (its centre was put on
    /// the plane).
    pub origin_above_plane_mm: f64,
    /// "marker" (from `--x-axis`) or "camera 0's right".
    pub x_axis_from: String,
}

/// A floor fitted: the new world from the old (the old scaled by `scale` first), the fit's
/// RMS (metres: the L-frame's markers from the fitted L, or the floor markers from their
/// plane), and what was found.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor<F> {
    pub new_from_old: Isometry3<f64>,
    pub rms_m: f64,
    pub scale: f64,
    pub found: F,
}

/// Each object's median position over the frames it was triangulated in, for the objects seen
/// in at least half of the frames it could have been: those whose cameras include every
/// camera of the object's most frequent set (a marker on the floor seen by two cameras of
/// four is triangulated only when both are in the frame set, and cameras that drop frames
/// each on their own made it fall below half of all frames). A marker seen fewer than
/// [`MIN_STEADY_FRAMES`] times is not steady.
pub fn steady_markers(frames: &[PoseFrame]) -> Vec<Steady> {
    struct Seen<'a> {
        positions: Vec<[f64; 3]>,
        camera_sets: BTreeMap<&'a [String], usize>,
    }
    let mut seen: BTreeMap<u32, Seen> = BTreeMap::new();
    for f in frames {
        for p in &f.poses {
            // Body markers too: an L-frame defined as a [[body]] is labelled as one.
            if p.method == PoseMethod::Triangulated {
                let s = seen.entry(p.object_id).or_insert_with(|| Seen {
                    positions: Vec::new(),
                    camera_sets: BTreeMap::new(),
                });
                s.positions.push(p.position_m);
                *s.camera_sets.entry(p.cameras.as_slice()).or_default() += 1;
            }
        }
    }
    seen.into_iter()
        .filter(|(_, s)| {
            let usual = s
                .camera_sets
                .iter()
                .max_by_key(|(_, n)| **n)
                .map_or(&[][..], |(cams, _)| *cams);
            let possible = frames
                .iter()
                .filter(|f| usual.iter().all(|c| f.cameras.contains(c)))
                .count();
            s.positions.len() >= MIN_STEADY_FRAMES && s.positions.len() * 2 >= possible
        })
        .map(|(id, s)| {
            let med = |i: usize| {
                let mut a: Vec<f64> = s.positions.iter().map(|p| p[i]).collect();
                a.sort_by(f64::total_cmp);
                a[a.len() / 2]
            };
            (id, Point3::new(med(0), med(1), med(2)))
        })
        .collect()
}

/// The markers' pairwise distances, for a message when no L was found.
pub fn distances(markers: &[Steady]) -> String {
    let mut pairs = Vec::new();
    for i in 0..markers.len() {
        for j in i + 1..markers.len() {
            pairs.push(format!(
                "{}–{} {:.1} mm",
                markers[i].0,
                markers[j].0,
                (markers[i].1 - markers[j].1).norm() * 1e3
            ));
        }
    }
    if pairs.is_empty() {
        "none".to_string()
    } else {
        pairs.join(", ")
    }
}

/// Finds the L-frame among `markers` and fits the floor to it (module header).
pub fn fit_l_frame(
    markers: &[Steady],
    l: LFrame,
    height_m: f64,
    scale: bool,
) -> Result<Floor<LFrameFit>, FloorError> {
    let LFrame {
        long_m: long,
        short_m: short,
        middle_m: middle,
    } = l;
    if !(long.is_finite() && short.is_finite() && long > 0.0 && short > 0.0) || long <= short {
        return Err(FloorError::Arms {
            long_m: long,
            short_m: short,
        });
    }
    if let Some(m) = middle
        && !(m.is_finite() && m > 0.0 && m < long)
    {
        return Err(FloorError::Middle {
            middle_m: m,
            long_m: long,
        });
    }
    let mut model = vec![
        Point3::new(0.0, 0.0, height_m),
        Point3::new(long, 0.0, height_m),
        Point3::new(0.0, short, height_m),
    ];
    if let Some(m) = middle {
        model.push(Point3::new(m, 0.0, height_m));
    }
    let tolerance = (0.003f64).max(0.01 * long);
    if markers.len() > MAX_L_FRAME_CANDIDATES {
        return Err(FloorError::TooManyMarkers {
            count: markers.len(),
        });
    }
    let Some(ids) = find_l(markers, &model, tolerance, scale) else {
        return Err(FloorError::NoLFrame {
            wanted: model.len(),
            long_mm: long * 1e3,
            short_mm: short * 1e3,
            middle_mm: middle.map(|m| m * 1e3),
            tolerance_mm: tolerance * 1e3,
            scaled: scale,
            count: markers.len(),
            distances: distances(markers),
        });
    };
    let measured: Vec<Point3<f64>> = ids.iter().map(|&i| markers[i].1).collect();
    let centroid =
        |p: &[Point3<f64>]| p.iter().map(|q| q.coords).sum::<Vector3<f64>>() / p.len() as f64;
    let factor = if scale {
        let (cm, cw) = (centroid(&measured), centroid(&model));
        let spread = |p: &[Point3<f64>], c: Vector3<f64>| {
            p.iter().map(|q| (q.coords - c).norm_squared()).sum::<f64>()
        };
        (spread(&model, cw) / spread(&measured, cm)).sqrt()
    } else {
        1.0
    };
    let scaled: Vec<Point3<f64>> = measured
        .iter()
        .map(|p| Point3::from(p.coords * factor))
        .collect();
    let weights = vec![1.0; model.len()];
    let (new_from_old, rms) =
        stereoscope_bodies::kabsch(&scaled, &model, &weights).ok_or(FloorError::Collinear)?;
    let (po, px, py) = (measured[0], measured[1], measured[2]);
    let squareness = (90.0 - (px - po).angle(&(py - po)).to_degrees()).abs();
    Ok(Floor {
        new_from_old,
        rms_m: rms,
        scale: factor,
        found: LFrameFit {
            corner: markers[ids[0]].0,
            x_arm: markers[ids[1]].0,
            y_arm: markers[ids[2]].0,
            x_middle: ids.get(3).map(|&i| markers[i].0),
            squareness_error_deg: squareness,
        },
    })
}

/// The markers (indices into `markers`) that are the model's, in the model's order: the rigid
/// bodies' identification, every distance within `tolerance`. With `scaled` the markers' scale
/// is unknown: each pair of markers is tried as the model's longest distance, the markers
/// scaled to it, and the best fit (smallest residual) kept.
fn find_l(
    markers: &[Steady],
    model: &[Point3<f64>],
    tolerance: f64,
    scaled: bool,
) -> Option<Vec<usize>> {
    if markers.len() < model.len() {
        return None;
    }
    let def = BodyDef {
        name: "L-frame".into(),
        markers_m: model.to_vec(),
        tolerance_m: tolerance,
    };
    let whole = |points: &[Point3<f64>]| {
        stereoscope_bodies::identify(std::slice::from_ref(&def), points)
            .into_iter()
            .find(|m| m.seen() == model.len())
            .map(|m| {
                (
                    m.markers.iter().flatten().copied().collect::<Vec<_>>(),
                    m.residual_m,
                )
            })
    };
    let points: Vec<Point3<f64>> = markers.iter().map(|(_, p)| *p).collect();
    if !scaled {
        return whole(&points).map(|(ids, _)| ids);
    }
    let longest = (0..model.len())
        .flat_map(|i| (i + 1..model.len()).map(move |j| (i, j)))
        .map(|(i, j)| (model[i] - model[j]).norm())
        .fold(0.0, f64::max);
    let mut best: Option<(Vec<usize>, f64)> = None;
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            let d = (points[i] - points[j]).norm();
            if d <= 0.0 {
                continue;
            }
            let k = longest / d;
            let scaled: Vec<Point3<f64>> =
                points.iter().map(|p| Point3::from(p.coords * k)).collect();
            if let Some((ids, residual)) = whole(&scaled)
                && best.as_ref().is_none_or(|b| residual < b.1)
            {
                best = Some((ids, residual));
            }
        }
    }
    best.map(|(ids, _)| ids)
}

/// The floor from markers on it (module header): `origin` and `x_axis` are the markers
/// recorded at the origin and on +x; `cameras` the rig's, in its world.
pub fn fit_floor_points(
    cameras: &[Camera],
    markers: &[Steady],
    origin: Point3<f64>,
    x_axis: Option<Point3<f64>>,
    height_m: f64,
) -> Result<Floor<PointsFit>, FloorError> {
    if markers.len() < 3 {
        return Err(FloorError::TooFewFloorMarkers {
            count: markers.len(),
        });
    }
    let n = markers.len() as f64;
    let c = markers.iter().map(|(_, p)| p.coords).sum::<Vector3<f64>>() / n;
    let mut cov = Matrix3::zeros();
    for (_, p) in markers {
        let d = p.coords - c;
        cov += d * d.transpose();
    }
    let eig = cov.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let (small, middle) = (
        eig.eigenvalues[order[0]].max(0.0),
        eig.eigenvalues[order[1]],
    );
    // Spread along the second axis under 5 cm RMS: the markers are (nearly) in a line.
    if middle / n < 0.05f64.powi(2) {
        return Err(FloorError::FloorInALine {
            count: markers.len(),
        });
    }
    let mut ez = eig.eigenvectors.column(order[0]).into_owned().normalize();
    // z up: towards most cameras.
    let above = cameras
        .iter()
        .filter(|cam| (cam.position_world().coords - c).dot(&ez) > 0.0)
        .count();
    if above * 2 < cameras.len() {
        ez = -ez;
    }
    let plane_rms = (small / n).sqrt();
    let origin_above = (origin.coords - c).dot(&ez);
    let foot = |p: Point3<f64>| p - ez * (p.coords - c).dot(&ez);
    let o = foot(origin);
    let (dir, from) = match x_axis {
        Some(p) => (foot(p) - o, "marker"),
        None => {
            let right = cameras.first().map_or(Vector3::x(), |cam| {
                cam.cam_from_world.rotation.inverse() * Vector3::x()
            });
            (right - ez * right.dot(&ez), "camera 0's right")
        }
    };
    if dir.norm() < 0.05 {
        return Err(if x_axis.is_some() {
            FloorError::XAxisTooNear
        } else {
            FloorError::CameraLooksDown
        });
    }
    let ex = dir.normalize();
    let ey = ez.cross(&ex);
    // Columns: the new world's axes in the old world's frame; the origin `height` under the
    // markers' centres.
    let r = Matrix3::from_columns(&[ex, ey, ez]);
    let old_from_new = Isometry3::from_parts(
        Translation3::from(o.coords - ez * height_m),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    Ok(Floor {
        new_from_old: old_from_new.inverse(),
        rms_m: plane_rms,
        scale: 1.0,
        found: PointsFit {
            floor_markers: markers.iter().map(|(id, _)| *id).collect(),
            origin_above_plane_mm: origin_above * 1e3,
            x_axis_from: from.to_string(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, SCHEMA_VERSION};

    fn frame(cameras: &[&str], poses: &[(u32, &[&str])]) -> PoseFrame {
        let names = |c: &[&str]| c.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            cameras: names(cameras),
            poses: poses
                .iter()
                .map(|(id, cams)| Pose {
                    object_id: *id,
                    position_m: [*id as f64, 0.0, 0.0],
                    velocity_m_per_s: [0.0; 3],
                    heading_deg: None,
                    heading_directed: false,
                    method: PoseMethod::Triangulated,
                    cameras: names(cams),
                    residual_px: 0.1,
                    out_of_range: false,
                    body: None,
                    model: None,
                })
                .collect(),
            sequence: 0,
            timestamp_ns: 0,
            frame_published_ns: 0,
            published_ns: 0,
            bodies: Vec::new(),
            models: Vec::new(),
        }
    }

    /// Marker 1 is seen by cam0 and cam3 whenever both are in the set (a third of the
    /// frames), marker 2 by all four in every frame; marker 3 is seen twice by cam1 and cam2,
    /// which are in every frame; marker 4 only in the three frames where cam0..cam2 were
    /// all present.
    #[test]
    fn a_marker_is_steady_in_half_the_frames_its_cameras_were_in() {
        let all = ["cam0", "cam1", "cam2", "cam3"];
        let mut frames = Vec::new();
        for k in 0..30 {
            let both = k % 3 == 0;
            let cams: Vec<&str> = all
                .iter()
                .copied()
                .filter(|c| both || (*c != "cam0" && *c != "cam3"))
                .collect();
            let mut poses: Vec<(u32, &[&str])> = vec![(2, &all)];
            if both {
                poses.push((1, &["cam0", "cam3"]));
            }
            if k < 2 {
                poses.push((3, &["cam1", "cam2"]));
            }
            frames.push(frame(&cams, &poses));
        }
        let ids: Vec<u32> = steady_markers(&frames).iter().map(|m| m.0).collect();
        assert_eq!(ids, vec![1, 2]);
        // A marker of three triangulations from three frames that could show it is steady; of
        // two, not.
        let three = [
            frame(&["cam0", "cam1", "cam2"], &[(4, &["cam0", "cam1", "cam2"])]),
            frame(&["cam0", "cam1", "cam2"], &[(4, &["cam0", "cam1", "cam2"])]),
            frame(&["cam0", "cam1", "cam2"], &[(4, &["cam0", "cam1", "cam2"])]),
            frame(&["cam0", "cam1"], &[]),
        ];
        assert_eq!(steady_markers(&three).len(), 1);
        assert!(steady_markers(&three[1..]).is_empty());
    }

    const L: LFrame = LFrame {
        long_m: 0.8,
        short_m: 0.5,
        middle_m: None,
    };

    /// An L-frame lying somewhere in the old world (turned, moved), with loose markers beside
    /// it: the L is found whatever the markers' order, and the new world puts its corner at
    /// the origin, its long arm on +x, its short arm on +y, its markers `height` up.
    fn placed_l(old_from_floor: Isometry3<f64>, height: f64) -> Vec<Steady> {
        let on = |x: f64, y: f64| old_from_floor * Point3::new(x, y, height);
        vec![
            (7, Point3::new(0.3, 0.2, 1.5)),
            (3, on(0.0, 0.5)),
            (9, on(0.8, 0.0)),
            (4, Point3::new(-0.4, 0.9, 0.2)),
            (5, on(0.0, 0.0)),
        ]
    }

    fn somewhere() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.4, -0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.05, -0.03, 1.1),
        )
    }

    #[test]
    fn an_l_frame_among_loose_markers_gives_the_floor() {
        let markers = placed_l(somewhere(), 0.02);
        let f = fit_l_frame(&markers, L, 0.02, false).unwrap();
        assert_eq!((f.found.corner, f.found.x_arm, f.found.y_arm), (5, 9, 3));
        assert!(f.rms_m < 1e-9 && f.found.squareness_error_deg < 1e-6);
        // The new world's origin is the floor under the corner; the old world's origin maps
        // where the placement says.
        let want = somewhere().inverse();
        let got = f.new_from_old;
        assert!((got.translation.vector - want.translation.vector).norm() < 1e-9);
        assert!(got.rotation.angle_to(&want.rotation) < 1e-9);
    }

    /// With `scale`, an L measured at 0.9 of its size (a one-marker wand's rig) is found by its
    /// shape, and the factor is the inverse.
    #[test]
    fn a_scaled_l_frame_is_found_by_its_shape() {
        let markers: Vec<Steady> = placed_l(somewhere(), 0.0)
            .into_iter()
            .map(|(id, p)| (id, Point3::from(p.coords * 0.9)))
            .collect();
        assert!(matches!(
            fit_l_frame(&markers, L, 0.0, false),
            Err(FloorError::NoLFrame { count: 5, .. })
        ));
        let f = fit_l_frame(&markers, L, 0.0, true).unwrap();
        assert_eq!((f.found.corner, f.found.x_arm, f.found.y_arm), (5, 9, 3));
        assert!((f.scale - 1.0 / 0.9).abs() < 1e-9, "{}", f.scale);
    }

    /// Each way an L-frame fit fails names what is wrong.
    #[test]
    fn l_frame_edge_cases_are_refused_with_their_reason() {
        let markers = placed_l(somewhere(), 0.0);
        let bad = |l: LFrame| fit_l_frame(&markers, l, 0.0, false).unwrap_err();
        assert!(matches!(
            bad(LFrame {
                long_m: 0.5,
                short_m: 0.8,
                middle_m: None
            }),
            FloorError::Arms { .. }
        ));
        assert!(matches!(
            bad(LFrame {
                middle_m: Some(0.9),
                ..L
            }),
            FloorError::Middle { .. }
        ));
        // A fourth marker the frame does not have: no L of four.
        let e = bad(LFrame {
            middle_m: Some(0.4),
            ..L
        });
        assert!(
            e.to_string().contains("no 4 steady markers make an L"),
            "{e}"
        );
        assert!(e.to_string().contains("9–5 800.0 mm"), "{e}");
        // Too few markers, and too many.
        let e = fit_l_frame(&markers[..2], L, 0.0, false).unwrap_err();
        assert!(matches!(e, FloorError::NoLFrame { count: 2, .. }), "{e}");
        let crowd: Vec<Steady> = (0..17)
            .map(|i| (i, Point3::new(i as f64, 0.0, 0.0)))
            .collect();
        assert_eq!(
            fit_l_frame(&crowd, L, 0.0, false).unwrap_err(),
            FloorError::TooManyMarkers { count: 17 }
        );
    }

    fn down_camera(at: [f64; 3]) -> Camera {
        let intrinsics =
            stereoscope_geometry::Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480).unwrap();
        let world_from_cam = Isometry3::face_towards(
            &Point3::from(at),
            &Point3::new(at[0] + 0.5, at[1] + 0.3, 0.0),
            &Vector3::z(),
        );
        Camera::new(intrinsics, Default::default(), world_from_cam.inverse()).unwrap()
    }

    /// Markers on a tilted floor: the plane found, z towards the cameras, the origin marker's
    /// foot at the origin, +x towards the x-axis marker; markers in a line and an x-axis
    /// marker at the origin are refused.
    #[test]
    fn floor_markers_give_the_plane_and_their_edge_cases_are_refused() {
        let tilt = somewhere();
        let on = |x: f64, y: f64| tilt * Point3::new(x, y, 0.0);
        let markers: Vec<Steady> = vec![
            (1, on(0.0, 0.0)),
            (2, on(1.0, 0.1)),
            (3, on(0.2, 1.0)),
            (4, on(-0.8, -0.6)),
        ];
        let cams = vec![down_camera([0.4, -0.2, 3.0]), down_camera([1.0, 1.0, 2.5])];
        let f = fit_floor_points(&cams, &markers, on(0.1, 0.1), Some(on(0.6, 0.1)), 0.0).unwrap();
        assert!(f.rms_m < 1e-9);
        let o = f.new_from_old * on(0.1, 0.1);
        assert!(o.coords.norm() < 1e-9, "{o}");
        let x = f.new_from_old * on(0.6, 0.1);
        assert!((x - Point3::new(0.5, 0.0, 0.0)).norm() < 1e-9, "{x}");
        assert_eq!(f.found.x_axis_from, "marker");
        // The cameras are above the new floor.
        for c in &cams {
            assert!((f.new_from_old * c.position_world()).z > 0.0);
        }
        let line: Vec<Steady> = (0..4).map(|i| (i, on(i as f64 * 0.3, 0.0))).collect();
        assert_eq!(
            fit_floor_points(&cams, &line, on(0.0, 0.0), None, 0.0).unwrap_err(),
            FloorError::FloorInALine { count: 4 }
        );
        assert_eq!(
            fit_floor_points(&cams, &markers, on(0.1, 0.1), Some(on(0.11, 0.12)), 0.0).unwrap_err(),
            FloorError::XAxisTooNear
        );
        assert_eq!(
            fit_floor_points(&cams, &markers[..2], on(0.0, 0.0), None, 0.0).unwrap_err(),
            FloorError::TooFewFloorMarkers { count: 2 }
        );
    }
}
