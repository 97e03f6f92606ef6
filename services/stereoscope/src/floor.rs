//! `stereoscope calibrate floor`: the world's frame from an L-frame lying on the floor — its
//! corner marker the origin, its long arm +x, its short arm +y, z up — read from a recorder's
//! `poses.jsonl` taken while it lay still; the rig's camera poses rewritten in that world
//! (`docs/calibration.md`, step 3).

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use stereoscope_proto::messages::{PoseFrame, PoseMethod};
use stereoscope_rig::{Rig, Units};

#[derive(Debug, Clone)]
pub struct FloorOptions {
    pub rig: PathBuf,
    /// A recorder's poses.jsonl taken while the L-frame lay still in view.
    pub poses: PathBuf,
    /// The L-frame's arms, corner marker to end marker: long (+x), short (+y), in `units`.
    pub l_frame: [f64; 2],
    pub units: Units,
    pub out: Option<PathBuf>,
    pub json: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct FloorReport {
    pub rig: String,
    pub units: String,
    /// Pose frames read, and markers seen in at least half of them.
    pub frames: usize,
    pub steady_markers: usize,
    /// The L-frame's markers (object ids) and how far their distances are from the arms'.
    pub corner: u32,
    pub x_arm: u32,
    pub y_arm: u32,
    pub fit_error_mm: f64,
    /// The floor's tilt from the arms' plane: how far the y arm was from square, degrees.
    pub squareness_error_deg: f64,
    /// Each camera's height above the floor in the new world, the rig's unit.
    pub camera_heights: Vec<(String, f64)>,
    pub warnings: Vec<String>,
}

/// Each object's median position over the frames it was triangulated in, for the objects seen
/// in at least half of the frames.
fn steady_markers(frames: &[PoseFrame]) -> Vec<(u32, Point3<f64>)> {
    let mut seen: BTreeMap<u32, Vec<[f64; 3]>> = BTreeMap::new();
    for f in frames {
        for p in &f.poses {
            // Body markers too: an L-frame defined as a [[body]] is labelled as one.
            if p.method == PoseMethod::Triangulated {
                seen.entry(p.object_id).or_default().push(p.position_m);
            }
        }
    }
    seen.into_iter()
        .filter(|(_, v)| v.len() * 2 >= frames.len())
        .map(|(id, v)| {
            let med = |i: usize| {
                let mut a: Vec<f64> = v.iter().map(|p| p[i]).collect();
                a.sort_by(f64::total_cmp);
                a[a.len() / 2]
            };
            (id, Point3::new(med(0), med(1), med(2)))
        })
        .collect()
}

/// The markers that make the L: corner, x-arm end, y-arm end, and the worst of the three
/// distances' errors (metres).
fn find_l(
    markers: &[(u32, Point3<f64>)],
    long_m: f64,
    short_m: f64,
) -> Option<(usize, usize, usize, f64)> {
    let diag = (long_m * long_m + short_m * short_m).sqrt();
    let mut best: Option<(usize, usize, usize, f64)> = None;
    for o in 0..markers.len() {
        for x in 0..markers.len() {
            for y in 0..markers.len() {
                if o == x || o == y || x == y {
                    continue;
                }
                let d = |a: usize, b: usize| (markers[a].1 - markers[b].1).norm();
                let err = (d(o, x) - long_m)
                    .abs()
                    .max((d(o, y) - short_m).abs())
                    .max((d(x, y) - diag).abs());
                if best.is_none_or(|b| err < b.3) {
                    best = Some((o, x, y, err));
                }
            }
        }
    }
    best
}

pub fn run(
    opts: &FloorOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let [long, short] = opts.l_frame.map(|v| v * opts.units.metres());
    if !(long.is_finite() && short.is_finite() && long > 0.0 && short > 0.0) || long <= short {
        bail!(
            "--l-frame {:?}: the long arm (x) then the short arm (y), both above 0 and different",
            opts.l_frame
        );
    }
    let text = std::fs::read_to_string(&opts.rig)
        .with_context(|| format!("{}: cannot read", opts.rig.display()))?;
    let rig = Rig::from_toml(&text).map_err(|e| anyhow!("{}: {e}", opts.rig.display()))?;
    let (frames, warnings) =
        stereoscope_recorder::session::read_messages::<PoseFrame>(&opts.poses)?;
    for w in warnings {
        writeln!(err, "warning: {w}")?;
    }
    if frames.is_empty() {
        bail!("{}: no pose frames", opts.poses.display());
    }
    let markers = steady_markers(&frames);
    let tolerance = (0.003f64).max(0.01 * long);
    let found = (markers.len() >= 3)
        .then(|| find_l(&markers, long, short))
        .flatten()
        .filter(|l| l.3 <= tolerance);
    let Some((o, x, y, fit)) = found else {
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
        bail!(
            "{}: no three steady markers make an L of {:.1} × {:.1} mm within {:.1} mm ({} markers seen in half the frames; their distances: {})",
            opts.poses.display(),
            long * 1e3,
            short * 1e3,
            tolerance * 1e3,
            markers.len(),
            if pairs.is_empty() {
                "none".to_string()
            } else {
                pairs.join(", ")
            }
        );
    };
    let (po, px, py) = (markers[o].1, markers[x].1, markers[y].1);
    let ex = (px - po).normalize();
    let ry = py - po;
    let ey = (ry - ex * ry.dot(&ex)).normalize();
    let ez = ex.cross(&ey);
    let squareness = (90.0 - ex.angle(&ry).to_degrees()).abs();
    // Columns: the new world's axes in the old world's frame.
    let r = Matrix3::from_columns(&[ex, ey, ez]);
    let old_from_new = Isometry3::from_parts(
        Translation3::from(po.coords),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    let poses: Vec<Isometry3<f64>> = rig
        .cameras
        .iter()
        .map(|c| c.camera.cam_from_world * old_from_new)
        .collect();
    let scale = rig.spec.units.metres();
    let heights: Vec<(String, f64)> = rig
        .cameras
        .iter()
        .zip(&poses)
        .map(|(c, p)| (c.id.clone(), (p.inverse() * Point3::origin()).z / scale))
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
            "cameras {below:?} are below the floor: check where they are, or the L-frame"
        ));
    }
    if squareness > 1.0 {
        report_warnings.push(format!(
            "the L-frame's arms are {squareness:.2}° from square"
        ));
    }
    let report = FloorReport {
        rig: rig.name.clone(),
        units: rig.spec.units.to_string(),
        frames: frames.len(),
        steady_markers: markers.len(),
        corner: markers[o].0,
        x_arm: markers[x].0,
        y_arm: markers[y].0,
        fit_error_mm: fit * 1e3,
        squareness_error_deg: squareness,
        camera_heights: heights,
        warnings: report_warnings,
    };
    if opts.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        writeln!(
            out,
            "Floor from the L-frame: corner object {}, x arm {}, y arm {} (distances within {:.2} mm, {:.2}° from square), over {} pose frames.",
            report.corner,
            report.x_arm,
            report.y_arm,
            report.fit_error_mm,
            report.squareness_error_deg,
            report.frames
        )?;
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
