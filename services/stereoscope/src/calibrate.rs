//! `stereoscope calibrate`: a camera from target correspondences (CSV `view,X,Y,Z,u,v`) or
//! from images of the dot-grid target. Uses `stereoscope_geometry::calibrate` (thesis §2.2.3,
//! Zhang/DLT start, Levenberg–Marquardt) and `dotgrid`.

use std::io::Write;
use std::path::PathBuf;
use stereoscope_geometry::calibrate::{Calibration, DistortionModel, calibrate_camera};
use stereoscope_geometry::dotgrid::{DotGrid, detect};
use stereoscope_geometry::{Camera, Distortion};
use stereoscope_imageio::csv;
use stereoscope_imageio::{AnyGray, read_gray};
use stereoscope_proto::reports::{CalibrationReport, ViewReport};
use stereoscope_rig::{Units, camera_spec};

/// Where the correspondences come from.
#[derive(Debug, Clone)]
pub enum Source {
    /// CSV with the header `view,X,Y,Z,u,v`.
    Points(PathBuf),
    /// Images of a `cols × rows` dot grid with dots `spacing` apart (in `units`).
    DotGrid {
        images: Vec<PathBuf>,
        cols: usize,
        rows: usize,
        spacing: f64,
    },
}

#[derive(Debug, Clone)]
pub struct CalibrateOptions {
    pub source: Source,
    /// Required with `Points`; read from the images otherwise (and checked if given).
    pub image_size: Option<(u32, u32)>,
    /// Unit of the target coordinates: "m", "cm" or "mm".
    pub units: Units,
    pub distortion: DistortionModel,
    /// The camera's id in the written table.
    pub id: String,
    pub json: bool,
    /// Write the camera table here as well.
    pub out: Option<PathBuf>,
}

type Views = (
    Vec<String>,
    Vec<Vec<(nalgebra::Point3<f64>, nalgebra::Point2<f64>)>>,
);

fn views_from_csv(path: &std::path::Path, scale: f64) -> Result<Views, csv::CsvError> {
    let rows = csv::read(path, &["view", "X", "Y", "Z", "u", "v"])?;
    let (mut labels, mut views): Views = (Vec::new(), Vec::new());
    let file = path.display().to_string();
    for r in &rows {
        let num = |k: usize, name: &str| {
            r.number(k, name).map_err(|problem| csv::CsvError {
                file: file.clone(),
                problem,
            })
        };
        let (x, y, z, u, v) = (
            num(1, "X")?,
            num(2, "Y")?,
            num(3, "Z")?,
            num(4, "u")?,
            num(5, "v")?,
        );
        let label = &r.fields[0];
        let idx = match labels.iter().position(|l| l == label) {
            Some(i) => i,
            None => {
                labels.push(label.clone());
                views.push(Vec::new());
                labels.len() - 1
            }
        };
        views[idx].push((
            nalgebra::Point3::new(x * scale, y * scale, z * scale),
            nalgebra::Point2::new(u, v),
        ));
    }
    Ok((labels, views))
}

/// Runs the command. Returns the number of inputs that failed (each named on `err`); a
/// calibration that cannot be made at all is an `Err`.
pub fn run(
    opts: &CalibrateOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let scale = opts.units.metres();
    let mut failed = 0;
    let (labels, views, size) = match &opts.source {
        Source::Points(path) => {
            let size = opts
                .image_size
                .ok_or_else(|| anyhow::anyhow!("--image-size WxH is needed with --points"))?;
            let (labels, views) = views_from_csv(path, scale)?;
            (labels, views, size)
        }
        Source::DotGrid {
            images,
            cols,
            rows,
            spacing,
        } => {
            let grid = DotGrid::new(*cols, *rows, spacing * scale)
                .map_err(|e| anyhow::anyhow!("--dot-grid: {e}"))?;
            let (mut labels, mut views) = (Vec::new(), Vec::new());
            let mut size = opts.image_size;
            for path in images {
                let name = path.display().to_string();
                let result = read_gray(path).map_err(|e| e.to_string()).and_then(|img| {
                    let s = (img.width(), img.height());
                    match size {
                        Some(expected) if expected != s => {
                            return Err(format!(
                                "is {}×{}, the other images are {}×{}",
                                s.0, s.1, expected.0, expected.1
                            ));
                        }
                        _ => size = Some(s),
                    }
                    match &img {
                        AnyGray::U8(i) => detect(i.view(), &grid),
                        AnyGray::U16 { image, .. } => detect(image.view(), &grid),
                    }
                    .map_err(|e| e.to_string())
                });
                match result {
                    Ok(dots) => {
                        labels.push(name);
                        views.push(dots.iter().map(|&(i, px)| (grid.point(i), px)).collect());
                    }
                    Err(reason) => {
                        failed += 1;
                        writeln!(err, "error: {name}: {reason}")?;
                    }
                }
            }
            let size = size.ok_or_else(|| anyhow::anyhow!("no image could be used"))?;
            (labels, views, size)
        }
    };
    let cal = calibrate_camera(size.0, size.1, &views, opts.distortion)
        .map_err(|e| anyhow::anyhow!("calibration failed: {e}"))?;
    let report = report(&cal, &labels, size, opts.units, scale, &opts.id)?;
    // A target measured in one unit and read in another puts the camera absurdly near or far.
    for v in &report.views {
        let t = v.translation;
        let metres = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt() * scale;
        if !(0.05..=1000.0).contains(&metres) {
            writeln!(
                err,
                "warning: view {}: the camera is {metres:.3} m from the target; are the target's coordinates (or --spacing) in --units {}?",
                v.view, opts.units
            )?;
            break;
        }
    }
    if let Some(path) = &opts.out {
        std::fs::write(path, &report.camera_toml)
            .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", path.display()))?;
    }
    if opts.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        write_human(out, &report, views.iter().map(|v| v.len()).sum())?;
    }
    Ok(failed)
}

fn report(
    cal: &Calibration,
    labels: &[String],
    size: (u32, u32),
    units: Units,
    scale: f64,
    id: &str,
) -> anyhow::Result<CalibrationReport> {
    let c = &cal.cameras[0];
    let d = c.distortion;
    let world_from = cal
        .cam0_from_target
        .first()
        .copied()
        .unwrap_or_else(nalgebra::Isometry3::identity);
    let camera = Camera {
        intrinsics: c.intrinsics,
        distortion: Distortion { ..d },
        cam_from_world: world_from,
    };
    let spec = camera_spec(id, &camera, units);
    let camera_toml = spec.to_toml_table(units)?;
    let views = cal
        .cam0_from_target
        .iter()
        .enumerate()
        .map(|(v, pose)| {
            let mine: Vec<_> = cal.residuals.iter().filter(|r| r.view == v).collect();
            let rms = (mine
                .iter()
                .map(|r| r.du_px * r.du_px + r.dv_px * r.dv_px)
                .sum::<f64>()
                / mine.len().max(1) as f64)
                .sqrt();
            let r = pose.rotation.scaled_axis();
            let t = pose.translation.vector / scale;
            ViewReport {
                view: labels.get(v).cloned().unwrap_or_else(|| v.to_string()),
                points: mine.len(),
                rms_px: rms,
                rotation_deg: [r.x.to_degrees(), r.y.to_degrees(), r.z.to_degrees()],
                translation: [t.x, t.y, t.z],
            }
        })
        .collect();
    Ok(CalibrationReport {
        image_size: [size.0, size.1],
        units: units.to_string(),
        fx: c.intrinsics.fx,
        fy: c.intrinsics.fy,
        cx: c.intrinsics.cx,
        cy: c.intrinsics.cy,
        distortion: [d.k1, d.k2, d.p1, d.p2, d.k3],
        std_dev: c.std_dev,
        rms_px: cal.rms_px,
        views,
        residuals: cal
            .residuals
            .iter()
            .map(|r| (r.view, r.point, r.du_px, r.dv_px))
            .collect(),
        camera_toml,
    })
}

fn write_human(out: &mut impl Write, r: &CalibrationReport, points: usize) -> std::io::Result<()> {
    writeln!(
        out,
        "calibrated from {} views, {points} points, image {}×{}",
        r.views.len(),
        r.image_size[0],
        r.image_size[1]
    )?;
    let sd = |k: usize| r.std_dev[k].map_or(String::new(), |s| format!(" ± {s:.4}"));
    for (k, (name, v)) in [("fx", r.fx), ("fy", r.fy), ("cx", r.cx), ("cy", r.cy)]
        .into_iter()
        .enumerate()
    {
        writeln!(out, "  {name:<3} {v:>12.4} px{}", sd(k))?;
    }
    for (k, name) in ["k1", "k2", "p1", "p2", "k3"].iter().enumerate() {
        let idx = [4, 5, 6, 7, 8][k];
        if r.std_dev[idx].is_some() || r.distortion[k] != 0.0 {
            writeln!(out, "  {name:<3} {:>12.6}{}", r.distortion[k], sd(idx))?;
        }
    }
    writeln!(out, "  PAR (pixel width / height) {:.4}", r.fy / r.fx)?;
    writeln!(out, "  RMS reprojection error {:.4} px", r.rms_px)?;
    writeln!(
        out,
        "  {:<16} {:>6} {:>8}  {:<30} translation ({})",
        "view", "points", "rms_px", "rotation vector (deg)", r.units
    )?;
    for v in &r.views {
        writeln!(
            out,
            "  {:<16} {:>6} {:>8.4}  [{:>8.3}, {:>8.3}, {:>8.3}]   [{:.3}, {:.3}, {:.3}]",
            v.view,
            v.points,
            v.rms_px,
            v.rotation_deg[0],
            v.rotation_deg[1],
            v.rotation_deg[2],
            v.translation[0],
            v.translation[1],
            v.translation[2]
        )?;
    }
    writeln!(
        out,
        "camera table for a rig file (world frame = the target in the first view):"
    )?;
    write!(out, "{}", r.camera_toml)
}
