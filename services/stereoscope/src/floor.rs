//! `stereoscope calibrate floor`: the world's frame from an L-frame lying on the floor or from
//! markers lying on it (the fits are `stereoscope_calibration::floor`'s), read from a
//! recorder's `poses.jsonl` taken while they lay still; the rig's camera poses rewritten in
//! that world, and with `--scale` the rig scaled to the L-frame's lengths (after a one-marker
//! wand) (`docs/calibration.md`, step 3). This file reads, reports and writes.

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Point3};
use serde::Serialize;
use std::io::Write;
use std::path::PathBuf;
use stereoscope_calibration::floor::{
    LFrame, LFrameFit, PointsFit, Steady, fit_floor_points, fit_l_frame, steady_markers,
};
use stereoscope_proto::messages::PoseFrame;
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
            let l = LFrame {
                long_m: long * unit,
                short_m: short * unit,
                middle_m: middle.map(|m| m * unit),
            };
            let f = fit_l_frame(&markers, l, height, opts.scale)
                .map_err(|e| anyhow!("{}: --l-frame: {e}", opts.poses.display()))?;
            (f.new_from_old, f.rms_m, f.scale, Some(f.found), None)
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
            let f = fit_floor_points(&rig.cameras(), &markers, o, x, height)
                .map_err(|e| anyhow!("{}: {e}", opts.poses.display()))?;
            (f.new_from_old, f.rms_m, 1.0, None, Some(f.found))
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
