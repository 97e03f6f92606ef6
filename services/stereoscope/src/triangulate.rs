//! `stereoscope triangulate --rig RIG.toml --points FILE.csv`: 3D points from pixels seen by
//! the rig's calibrated cameras (CSV `point,camera,u,v`; `camera` is a camera id of the rig).
//! Uses `stereoscope_geometry::triangulate` (DLT + reprojection refinement, 2–16 cameras).

use std::io::Write;
use std::path::PathBuf;
use stereoscope_geometry::triangulate::{Observation, triangulate};
use stereoscope_imageio::csv;
use stereoscope_proto::reports::TriangulatedPoint;
use stereoscope_rig::Rig;

#[derive(Debug, Clone)]
pub struct TriangulateOptions {
    pub rig: PathBuf,
    pub points: PathBuf,
    pub json: bool,
}

/// Runs the command. Returns how many points failed (each named on `err`); an unreadable rig
/// or points file is an `Err`.
pub fn run(
    opts: &TriangulateOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let rig_name = opts.rig.display();
    let rig = Rig::load(&opts.rig)?;
    let scale = rig.metres_per_unit();
    let cams = rig.cameras();
    let rows = csv::read(&opts.points, &["point", "camera", "u", "v"])?;
    let pfile = opts.points.display();
    // Group by point label, in order of first appearance.
    let mut labels: Vec<String> = Vec::new();
    let mut groups: Vec<Vec<(Observation, usize)>> = Vec::new();
    for r in &rows {
        let cam = rig.camera_index(&r.fields[1]).ok_or_else(|| {
            let ids: Vec<&str> = rig.cameras.iter().map(|c| c.id.as_str()).collect();
            anyhow::anyhow!(
                "{pfile}: line {}: camera {:?} is not in {rig_name} (it has {})",
                r.line,
                r.fields[1],
                ids.join(", ")
            )
        })?;
        let u = r
            .number(2, "u")
            .map_err(|e| anyhow::anyhow!("{pfile}: {e}"))?;
        let v = r
            .number(3, "v")
            .map_err(|e| anyhow::anyhow!("{pfile}: {e}"))?;
        let i = match labels.iter().position(|l| *l == r.fields[0]) {
            Some(i) => i,
            None => {
                labels.push(r.fields[0].clone());
                groups.push(Vec::new());
                labels.len() - 1
            }
        };
        groups[i].push((
            Observation {
                camera: cam,
                pixel: nalgebra::Point2::new(u, v),
            },
            r.line,
        ));
    }
    let mut failed = 0;
    if !opts.json {
        let u = rig.spec.units;
        writeln!(
            out,
            "{:<10} {:>12} {:>12} {:>12} {:>9}  cameras",
            "point",
            format!("X ({u})"),
            format!("Y ({u})"),
            format!("Z ({u})"),
            "rms_px"
        )?;
    }
    for (label, group) in labels.iter().zip(&groups) {
        let obs: Vec<Observation> = group.iter().map(|g| g.0).collect();
        match triangulate(&cams, &obs) {
            Ok(t) => {
                let p = t.point_world.coords / scale;
                let rec = TriangulatedPoint {
                    point: label.clone(),
                    position: [p.x, p.y, p.z],
                    rms_px: t.rms_px,
                    cameras: t
                        .cameras
                        .iter()
                        .map(|&c| rig.cameras[c].id.clone())
                        .collect(),
                    residuals_px: t.residuals_px.clone(),
                };
                if opts.json {
                    writeln!(out, "{}", serde_json::to_string(&rec)?)?;
                } else {
                    writeln!(
                        out,
                        "{:<10} {:>12.4} {:>12.4} {:>12.4} {:>9.4}  {}",
                        rec.point,
                        p.x,
                        p.y,
                        p.z,
                        rec.rms_px,
                        rec.cameras.join(",")
                    )?;
                }
            }
            Err(e) => {
                failed += 1;
                writeln!(
                    err,
                    "error: {pfile}: point {label:?} (line {}): {e}",
                    group[0].1
                )?;
            }
        }
    }
    Ok(failed)
}
