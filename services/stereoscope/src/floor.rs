//! `stereoscope calibrate floor`: the world's frame from an L-frame lying on the floor — its
//! corner marker the origin, its long arm +x, its short arm +y, z up (3 markers, or 4 with one
//! more on the long arm), fitted to the markers by least squares (Kabsch) — or from markers
//! lying on the floor (their plane), one at the origin and optionally one on +x; read from a
//! recorder's `poses.jsonl` taken while they lay still; the rig's camera poses rewritten in
//! that world, and with `--scale` the rig scaled to the L-frame's lengths (after a one-marker
//! wand) (`docs/calibration.md`, step 3).

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use stereoscope_proto::messages::{PoseFrame, PoseMethod};
use stereoscope_rig::{Rig, Units};

/// How the floor is given.
#[derive(Debug, Clone, PartialEq)]
pub enum FloorMethod {
    /// An L-frame lying on the floor: its arms, corner marker to end marker, long (+x) and short
    /// (+y), and optionally a fourth marker on the long arm this far from the corner; in `units`.
    LFrame {
        long: f64,
        short: f64,
        middle: Option<f64>,
    },
    /// At least three markers lying on the floor (the steady markers of `poses`), a recording
    /// of one marker at the origin, and optionally one of a marker on the +x axis (without it,
    /// +x is camera 0's right, laid on the floor).
    Points {
        origin: PathBuf,
        x_axis: Option<PathBuf>,
    },
}

#[derive(Debug, Clone)]
pub struct FloorOptions {
    pub rig: PathBuf,
    /// A recorder's poses.jsonl taken while the L-frame (or the floor markers) lay still.
    pub poses: PathBuf,
    pub method: FloorMethod,
    /// How far the markers' centres are above the floor, in `units` (their radius, plus the
    /// frame's thickness for an L-frame): the world's z = 0 is put that far below them.
    pub marker_height: f64,
    /// Scale the rig so that the L-frame's markers are their known distances apart (after a
    /// one-marker wand, which gives no scale).
    pub scale: bool,
    pub units: Units,
    pub out: Option<PathBuf>,
    pub json: bool,
}

/// The L-frame's markers (object ids) as found.
#[derive(Debug, Clone, Serialize)]
pub struct LFrameFit {
    pub corner: u32,
    pub x_arm: u32,
    pub y_arm: u32,
    pub x_middle: Option<u32>,
    /// How far the y arm was from square to the x arm, degrees.
    pub squareness_error_deg: f64,
}

/// The floor markers' plane as found.
#[derive(Debug, Clone, Serialize)]
pub struct PointsFit {
    pub floor_markers: Vec<u32>,
    /// The origin marker's distance above the floor markers' plane, mm (its centre was put on
    /// the plane).
    pub origin_above_plane_mm: f64,
    /// "marker" (from `--x-axis`) or "camera 0's right".
    pub x_axis_from: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct FloorReport {
    pub rig: String,
    pub units: String,
    /// Pose frames read, and markers seen in at least half of those their cameras were in.
    pub frames: usize,
    pub steady_markers: usize,
    /// L-frame: the RMS distance of its markers from the fitted L; points: the floor markers'
    /// RMS distance from their plane; mm (after scaling).
    pub fit_error_mm: f64,
    pub l_frame: Option<LFrameFit>,
    pub points: Option<PointsFit>,
    /// What the rig's lengths were multiplied by (1 without `--scale`).
    pub scale: f64,
    /// Each camera's height above the floor in the new world, the rig's unit.
    pub camera_heights: Vec<(String, f64)>,
    pub warnings: Vec<String>,
}

/// A marker's object id and its median position (the rig's world, metres).
type Steady = (u32, Point3<f64>);

/// Each object's median position over the frames it was triangulated in, for the objects seen
/// in at least half of the frames it could have been: those whose cameras include every
/// camera of the object's most frequent set (a marker on the floor seen by two cameras of
/// four is triangulated only when both are in the frame set, and cameras that drop frames
/// each on their own made it fall below half of all frames). A marker seen fewer than
/// `MIN_STEADY_FRAMES` times is not steady.
fn steady_markers(frames: &[PoseFrame]) -> Vec<Steady> {
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

/// Fewer triangulations than this make no steady marker, however few frames could show it.
const MIN_STEADY_FRAMES: usize = 3;

/// The assignment of `markers` to the model's points whose pairwise distances fit the model's
/// best, and the worst distance error (model units). With `scaled`, distances are compared
/// after scaling the candidate's to the model's total (the rig's scale is unknown).
fn find_model(
    markers: &[Steady],
    model: &[Point3<f64>],
    scaled: bool,
) -> Option<(Vec<usize>, f64)> {
    fn search(
        markers: &[Steady],
        model: &[Point3<f64>],
        scaled: bool,
        chosen: &mut Vec<usize>,
        best: &mut Option<(Vec<usize>, f64)>,
    ) {
        if chosen.len() == model.len() {
            let mut got = Vec::new();
            let mut want = Vec::new();
            for i in 0..model.len() {
                for j in i + 1..model.len() {
                    got.push((markers[chosen[i]].1 - markers[chosen[j]].1).norm());
                    want.push((model[i] - model[j]).norm());
                }
            }
            let k = if scaled {
                let sum: f64 = got.iter().sum();
                if sum <= 0.0 {
                    return;
                }
                want.iter().sum::<f64>() / sum
            } else {
                1.0
            };
            let err = got
                .iter()
                .zip(&want)
                .map(|(g, w)| (g * k - w).abs())
                .fold(0.0, f64::max);
            if best.as_ref().is_none_or(|b| err < b.1) {
                *best = Some((chosen.clone(), err));
            }
            return;
        }
        for m in 0..markers.len() {
            if !chosen.contains(&m) {
                chosen.push(m);
                search(markers, model, scaled, chosen, best);
                chosen.pop();
            }
        }
    }
    let mut best = None;
    search(markers, model, scaled, &mut Vec::new(), &mut best);
    best
}

/// The steady markers of a poses file, with its frame count and its read warnings printed.
fn steady_in(path: &std::path::Path, err: &mut impl Write) -> anyhow::Result<(usize, Vec<Steady>)> {
    let (frames, warnings) = stereoscope_recorder::session::read_messages::<PoseFrame>(path)?;
    for w in warnings {
        writeln!(err, "warning: {w}")?;
    }
    if frames.is_empty() {
        bail!("{}: no pose frames", path.display());
    }
    Ok((frames.len(), steady_markers(&frames)))
}

/// The one steady marker of a recording (the origin's or the x axis's).
fn single_marker(
    path: &std::path::Path,
    what: &str,
    err: &mut impl Write,
) -> anyhow::Result<Point3<f64>> {
    let (_, markers) = steady_in(path, err)?;
    match markers.as_slice() {
        [(_, p)] => Ok(*p),
        _ => bail!(
            "{}: {} steady markers; the {what} recording must hold exactly one (the marker at the {what})",
            path.display(),
            markers.len()
        ),
    }
}

/// The markers' distances, for a message when no L was found.
fn distances(markers: &[Steady]) -> String {
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

/// The L-frame's fit: `new_from_old` (old: the rig's world, scaled by the returned factor),
/// the fit's RMS and what was found.
fn fit_l_frame(
    opts: &FloorOptions,
    markers: &[Steady],
    [long, short]: [f64; 2],
    middle: Option<f64>,
    height: f64,
) -> anyhow::Result<(Isometry3<f64>, f64, f64, LFrameFit)> {
    if !(long.is_finite() && short.is_finite() && long > 0.0 && short > 0.0) || long <= short {
        bail!(
            "--l-frame: the long arm (x) then the short arm (y), both above 0 and different (got {:?})",
            opts.method
        );
    }
    if middle.is_some_and(|m| !(m.is_finite() && m > 0.0 && m < long)) {
        bail!(
            "--l-frame: the fourth marker's distance from the corner must be between 0 and the long arm (got {:?})",
            opts.method
        );
    }
    let mut model = vec![
        Point3::new(0.0, 0.0, height),
        Point3::new(long, 0.0, height),
        Point3::new(0.0, short, height),
    ];
    if let Some(m) = middle {
        model.push(Point3::new(m, 0.0, height));
    }
    let tolerance = (0.003f64).max(0.01 * long);
    if markers.len() > 16 {
        bail!(
            "{}: {} steady markers: clear the volume of all but the L-frame",
            opts.poses.display(),
            markers.len()
        );
    }
    let found = (markers.len() >= model.len())
        .then(|| find_model(markers, &model, opts.scale))
        .flatten()
        .filter(|l| l.1 <= tolerance);
    let Some((ids, _)) = found else {
        bail!(
            "{}: no {} steady markers make an L of {:.1} × {:.1} mm{} within {:.1} mm{} ({} markers seen in half the frames their cameras were in; their distances: {})",
            opts.poses.display(),
            model.len(),
            long * 1e3,
            short * 1e3,
            middle.map_or(String::new(), |m| format!(
                " with a marker {:.1} mm along x",
                m * 1e3
            )),
            tolerance * 1e3,
            if opts.scale {
                " (in shape: --scale)"
            } else {
                ""
            },
            markers.len(),
            distances(markers)
        );
    };
    let measured: Vec<Point3<f64>> = ids.iter().map(|&i| markers[i].1).collect();
    let centroid = |p: &[Point3<f64>]| {
        p.iter().map(|q| q.coords).sum::<nalgebra::Vector3<f64>>() / p.len() as f64
    };
    let scale = if opts.scale {
        let (cm, cw) = (centroid(&measured), centroid(&model));
        let spread = |p: &[Point3<f64>], c: nalgebra::Vector3<f64>| {
            p.iter().map(|q| (q.coords - c).norm_squared()).sum::<f64>()
        };
        (spread(&model, cw) / spread(&measured, cm)).sqrt()
    } else {
        1.0
    };
    let scaled: Vec<Point3<f64>> = measured
        .iter()
        .map(|p| Point3::from(p.coords * scale))
        .collect();
    let weights = vec![1.0; model.len()];
    let (new_from_old, rms) =
        stereoscope_bodies::kabsch(&scaled, &model, &weights).ok_or_else(|| {
            anyhow!(
                "{}: the L-frame's markers are in a line",
                opts.poses.display()
            )
        })?;
    let (po, px, py) = (measured[0], measured[1], measured[2]);
    let squareness = (90.0 - (px - po).angle(&(py - po)).to_degrees()).abs();
    let fit = LFrameFit {
        corner: markers[ids[0]].0,
        x_arm: markers[ids[1]].0,
        y_arm: markers[ids[2]].0,
        x_middle: ids.get(3).map(|&i| markers[i].0),
        squareness_error_deg: squareness,
    };
    Ok((new_from_old, rms, scale, fit))
}

/// The floor from markers on it: their plane (least squares), z towards the cameras, the origin
/// marker's foot on it, x towards the x-axis marker's foot (or camera 0's right).
fn fit_points(
    rig: &Rig,
    markers: &[Steady],
    origin: Point3<f64>,
    x_axis: Option<Point3<f64>>,
    height: f64,
) -> anyhow::Result<(Isometry3<f64>, f64, PointsFit)> {
    let n = markers.len() as f64;
    let c = markers
        .iter()
        .map(|(_, p)| p.coords)
        .sum::<nalgebra::Vector3<f64>>()
        / n;
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
        bail!(
            "the {} floor markers lie (nearly) in a line: spread them over the floor, at least 3 not in a line and apart",
            markers.len()
        );
    }
    let mut ez = eig.eigenvectors.column(order[0]).into_owned().normalize();
    // z up: towards most cameras.
    let above = rig
        .cameras
        .iter()
        .filter(|cam| (cam.camera.position_world().coords - c).dot(&ez) > 0.0)
        .count();
    if above * 2 < rig.cameras.len() {
        ez = -ez;
    }
    let plane_rms = (small / n).sqrt();
    let origin_above = (origin.coords - c).dot(&ez);
    let foot = |p: Point3<f64>| p - ez * (p.coords - c).dot(&ez);
    let o = foot(origin);
    let (dir, from) = match x_axis {
        Some(p) => (foot(p) - o, "marker"),
        None => {
            let right =
                rig.cameras[0].camera.cam_from_world.rotation.inverse() * nalgebra::Vector3::x();
            (right - ez * right.dot(&ez), "camera 0's right")
        }
    };
    if dir.norm() < 0.05 {
        bail!(
            "the x axis cannot be set: {}",
            if x_axis.is_some() {
                "the x-axis marker is within 5 cm of the origin (over the floor): put it farther along +x"
            } else {
                "camera 0 looks straight down; record a marker on +x and give it with --x-axis"
            }
        );
    }
    let ex = dir.normalize();
    let ey = ez.cross(&ex);
    // Columns: the new world's axes in the old world's frame; the origin `height` under the
    // markers' centres.
    let r = Matrix3::from_columns(&[ex, ey, ez]);
    let old_from_new = Isometry3::from_parts(
        Translation3::from(o.coords - ez * height),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    let fit = PointsFit {
        floor_markers: markers.iter().map(|(id, _)| *id).collect(),
        origin_above_plane_mm: origin_above * 1e3,
        x_axis_from: from.to_string(),
    };
    Ok((old_from_new.inverse(), plane_rms, fit))
}

pub fn run(
    opts: &FloorOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let unit = opts.units.metres();
    let height = opts.marker_height * unit;
    if !(height.is_finite() && (0.0..1.0).contains(&height)) {
        bail!(
            "--marker-height {}: the markers' centres above the floor, 0 up to 1 m",
            opts.marker_height
        );
    }
    let text = std::fs::read_to_string(&opts.rig)
        .with_context(|| format!("{}: cannot read", opts.rig.display()))?;
    let rig = Rig::from_toml(&text).map_err(|e| anyhow!("{}: {e}", opts.rig.display()))?;
    let (frames, markers) = steady_in(&opts.poses, err)?;
    let (new_from_old, fit, scale, l_frame, points) = match &opts.method {
        FloorMethod::LFrame {
            long,
            short,
            middle,
        } => {
            let (pose, fit, scale, l) = fit_l_frame(
                opts,
                &markers,
                [long * unit, short * unit],
                middle.map(|m| m * unit),
                height,
            )?;
            (pose, fit, scale, Some(l), None)
        }
        FloorMethod::Points { origin, x_axis } => {
            if opts.scale {
                bail!("--scale needs the L-frame's known lengths (--l-frame), not --points");
            }
            if markers.len() < 3 {
                bail!(
                    "{}: {} steady markers; --points needs at least 3 lying on the floor",
                    opts.poses.display(),
                    markers.len()
                );
            }
            let o = single_marker(origin, "origin", err)?;
            let x = x_axis
                .as_deref()
                .map(|p| single_marker(p, "x-axis", err))
                .transpose()?;
            let (pose, fit, p) = fit_points(&rig, &markers, o, x, height)?;
            (pose, fit, 1.0, None, Some(p))
        }
    };
    // Each camera: its pose in the old world scaled, then in the new.
    let poses: Vec<Isometry3<f64>> = rig
        .cameras
        .iter()
        .map(|c| {
            let mut p = c.camera.cam_from_world;
            p.translation.vector *= scale;
            p * new_from_old.inverse()
        })
        .collect();
    let rig_unit = rig.spec.units.metres();
    let heights: Vec<(String, f64)> = rig
        .cameras
        .iter()
        .zip(&poses)
        .map(|(c, p)| (c.id.clone(), (p.inverse() * Point3::origin()).z / rig_unit))
        .collect();
    let below: Vec<&str> = heights
        .iter()
        .filter(|(_, z)| *z < 0.0)
        .map(|(id, _)| id.as_str())
        .collect();
    if below.len() == heights.len() {
        bail!(
            "every camera is below this floor: the L-frame was seen upside down or its arms swapped (x is the long arm, y the short, z = x × y must point up to the cameras)"
        );
    }
    let mut report_warnings = Vec::new();
    if !below.is_empty() {
        report_warnings.push(format!(
            "cameras {below:?} are below the floor: check where they are, or the floor's markers"
        ));
    }
    if let Some(l) = &l_frame
        && l.squareness_error_deg > 1.0
    {
        report_warnings.push(format!(
            "the L-frame's arms are {:.2}° from square",
            l.squareness_error_deg
        ));
    }
    if points.is_some() && fit > 0.005 {
        report_warnings.push(format!(
            "the floor markers are {:.1} mm RMS from one plane: is the floor flat, and are they all on it?",
            fit * 1e3
        ));
    }
    if let Some(p) = &points
        && (p.origin_above_plane_mm.abs() > 20.0)
    {
        report_warnings.push(format!(
            "the origin marker is {:.1} mm off the floor markers' plane: was it on the floor?",
            p.origin_above_plane_mm
        ));
    }
    let report = FloorReport {
        rig: rig.name.clone(),
        units: rig.spec.units.to_string(),
        frames,
        steady_markers: markers.len(),
        fit_error_mm: fit * 1e3,
        l_frame,
        points,
        scale,
        camera_heights: heights,
        warnings: report_warnings,
    };
    if opts.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        if let Some(l) = &report.l_frame {
            writeln!(
                out,
                "Floor from the L-frame: corner object {}, x arm {}, y arm {}{} (fit {:.2} mm RMS, {:.2}° from square), over {} pose frames.",
                l.corner,
                l.x_arm,
                l.y_arm,
                l.x_middle
                    .map_or(String::new(), |m| format!(", middle {m}")),
                report.fit_error_mm,
                l.squareness_error_deg,
                report.frames
            )?;
        }
        if let Some(p) = &report.points {
            writeln!(
                out,
                "Floor from {} markers on it ({:.2} mm RMS from their plane), the origin marker {:.1} mm above it, x towards the {}, over {} pose frames.",
                p.floor_markers.len(),
                report.fit_error_mm,
                p.origin_above_plane_mm,
                p.x_axis_from,
                report.frames
            )?;
        }
        if opts.scale {
            writeln!(out, "Scaled the rig by {:.6}.", report.scale)?;
        }
        for (id, z) in &report.camera_heights {
            writeln!(out, "  {id}: {z:.1} {} above the floor", report.units)?;
        }
        for w in &report.warnings {
            writeln!(out, "warning: {w}")?;
        }
    }
    if let Some(path) = &opts.out {
        let written = crate::wand::with_poses(&text, &rig, &poses)?;
        Rig::from_toml(&written)
            .map_err(|e| anyhow!("the rig with the floor does not load: {e}"))?;
        std::fs::write(path, written)
            .with_context(|| format!("{}: cannot write", path.display()))?;
        writeln!(err, "wrote {}", path.display())?;
    }
    Ok(0)
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
                })
                .collect(),
            sequence: 0,
            timestamp_ns: 0,
            frame_published_ns: 0,
            published_ns: 0,
            bodies: Vec::new(),
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
}
