//! `stereoscope calibrate wand`: every camera's pose from a wand waved through the volume
//! (`stereoscope_geometry::wand`), read from a recorder's `observations.jsonl`, a CSV
//! `frame,camera,u,v` of blob centroids, or (`--live`) the running rig's observations until
//! every camera's image is covered — with a bar per camera filling meanwhile, and the
//! coverage published for the viewer; prints a report card, writes it as Markdown and JSON,
//! and writes the rig file with the poses (`docs/calibration.md`).

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Point2};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use stereoscope_geometry::Camera;
use stereoscope_geometry::GeometryError;
use stereoscope_geometry::wand::{Wand, WandConfig, WandFrame, calibrate_wand};
use stereoscope_proto::messages::{Observation, TrackState};
use stereoscope_rig::{Rig, Units};

/// More rows or frames than this in an input is refused (a day of 8 cameras at 120 fps is
/// far below; a wand wave is minutes).
pub const MAX_ROWS: usize = 20_000_000;
/// A camera's view with more blobs than this in one frame is not the wand (left out).
pub const MAX_BLOBS_PER_VIEW: usize = 16;
pub use stereoscope_calibration::wand::{COVERAGE_CELLS, MAX_SOLVED_RMS_PX, cell_of, share};
use stereoscope_calibration::wand::{CameraView, RigView, WandRefusal};

/// Where the wand's blobs come from.
#[derive(Debug, Clone)]
pub enum WandInput {
    /// A recorder's `observations.jsonl` or a CSV `frame,camera,u,v`.
    File(PathBuf),
    /// The running rig's observations, until covered.
    Live(crate::wand_live::LiveWand),
}

#[derive(Debug, Clone)]
pub struct WandOptions {
    pub rig: PathBuf,
    pub input: WandInput,
    /// The wand's markers' distances from its end marker, in `units`: `[0]` for one marker (no
    /// scale), one distance (two markers) or two (three markers).
    pub wand: Vec<f64>,
    pub units: Units,
    /// Adjust each camera's focal lengths and principal point too.
    pub refine_intrinsics: bool,
    /// Write the rig with the poses here.
    pub out: Option<PathBuf>,
    /// Write `wand-report.md` and `wand-report.json` into this folder.
    pub report: Option<PathBuf>,
    pub json: bool,
}

/// The rig file's text with a placeholder pose for each camera that has none (the pose is what
/// the calibration computes), and the parsed rig.
fn rig_without_poses(path: &Path) -> anyhow::Result<(String, Rig)> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let mut doc: toml_edit::DocumentMut = text
        .parse()
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    if let Some(cams) = doc
        .get_mut("camera")
        .and_then(|c| c.as_array_of_tables_mut())
    {
        for (k, cam) in cams.iter_mut().enumerate() {
            if !cam.contains_key("pose") {
                // Apart, so the rig's checks see distinct cameras; replaced by the result.
                let mut pose = toml_edit::InlineTable::new();
                let mut pos = toml_edit::Array::new();
                for v in [k as f64, 0.0, 0.0] {
                    pos.push(v);
                }
                let mut look = toml_edit::Array::new();
                for v in [k as f64, 0.0, 1.0] {
                    look.push(v);
                }
                let mut up = toml_edit::Array::new();
                for v in [0.0, -1.0, 0.0] {
                    up.push(v);
                }
                pose.insert("position", pos.into());
                pose.insert("look_at", look.into());
                pose.insert("up", up.into());
                cam.insert("pose", toml_edit::value(pose));
            }
        }
    }
    let rig = Rig::from_toml(&doc.to_string()).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    Ok((text, rig))
}

/// Usable blobs of an observation: seen this frame, whole, not merged.
pub(crate) fn blob_pixels(o: &Observation) -> Vec<Point2<f64>> {
    o.blobs
        .iter()
        .filter(|b| b.status != TrackState::Lost && !b.merged && !b.clipped)
        .map(|b| Point2::new(b.x_px, b.y_px))
        .collect()
}

/// Observations grouped into frames: sorted by time, each frame the earliest observation left
/// and every other camera's first within `max_skew_ns` of it.
fn frames_from_observations(
    obs: &[Observation],
    ids: &[String],
    sizes: &[[u32; 2]],
    max_skew_ns: u64,
) -> anyhow::Result<Vec<WandFrame>> {
    let mut order: Vec<(u64, usize, usize)> = Vec::with_capacity(obs.len());
    for (i, o) in obs.iter().enumerate() {
        let Some(c) = ids.iter().position(|id| *id == o.camera) else {
            bail!(
                "observation {}: camera {:?} is not in the rig (its cameras: {ids:?})",
                i + 1,
                o.camera
            );
        };
        let [w, h] = sizes[c];
        if (o.width_px, o.height_px) != (w, h) {
            bail!(
                "observation {}: camera {:?} sent {} × {} frames, the rig says {w} × {h}: set its image_size (and calibrate its intrinsics) for the mode it runs in",
                i + 1,
                o.camera,
                o.width_px,
                o.height_px
            );
        }
        order.push((o.timestamp_ns, c, i));
    }
    order.sort_unstable();
    let mut frames = Vec::new();
    let mut taken = vec![false; order.len()];
    for s in 0..order.len() {
        if taken[s] {
            continue;
        }
        let t0 = order[s].0;
        let mut pixels = vec![Vec::new(); ids.len()];
        let mut seen = vec![false; ids.len()];
        for k in s..order.len() {
            let (t, c, i) = order[k];
            if t.saturating_sub(t0) > max_skew_ns {
                break;
            }
            if taken[k] || seen[c] {
                continue;
            }
            taken[k] = true;
            seen[c] = true;
            pixels[c] = blob_pixels(&obs[i]);
        }
        frames.push(WandFrame {
            frame: frames.len() as u64,
            pixels,
        });
    }
    Ok(frames)
}

/// A CSV `frame,camera,u,v` (camera by its rig id): each row one blob.
fn frames_from_csv(
    path: &Path,
    ids: &[String],
    sizes: &[[u32; 2]],
) -> anyhow::Result<Vec<WandFrame>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let mut lines = text.lines().enumerate();
    let header = lines
        .next()
        .map(|(_, l)| l.trim().to_ascii_lowercase())
        .unwrap_or_default();
    if header.replace(' ', "") != "frame,camera,u,v" {
        bail!(
            "{}:1: the header must be frame,camera,u,v (got {header:?})",
            path.display()
        );
    }
    let mut by_frame: BTreeMap<u64, Vec<Vec<Point2<f64>>>> = BTreeMap::new();
    for (n, line) in lines {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        if n > MAX_ROWS {
            bail!("{}: more than {MAX_ROWS} rows", path.display());
        }
        let at = || format!("{}:{}", path.display(), n + 1);
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() != 4 {
            bail!("{}: {} fields, expected frame,camera,u,v", at(), f.len());
        }
        let frame: u64 = f[0]
            .parse()
            .map_err(|_| anyhow!("{}: frame {:?} is not a whole number", at(), f[0]))?;
        let Some(c) = ids.iter().position(|id| id == f[1]) else {
            bail!(
                "{}: camera {:?} is not in the rig (its cameras: {ids:?})",
                at(),
                f[1]
            );
        };
        let num = |name: &str, s: &str| -> anyhow::Result<f64> {
            match s.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(anyhow!("{}: {name} {s:?} is not a finite number", at())),
            }
        };
        let (u, v) = (num("u", f[2])?, num("v", f[3])?);
        let [w, h] = sizes[c];
        if !(-0.5..f64::from(w) - 0.5).contains(&u) || !(-0.5..f64::from(h) - 0.5).contains(&v) {
            bail!(
                "{}: ({u}, {v}) is outside camera {:?}'s image, {w} × {h} in the rig: is its image_size the mode it ran in?",
                at(),
                f[1]
            );
        }
        let views = by_frame
            .entry(frame)
            .or_insert_with(|| vec![Vec::new(); ids.len()]);
        if views[c].len() <= MAX_BLOBS_PER_VIEW {
            views[c].push(Point2::new(u, v));
        }
    }
    Ok(by_frame
        .into_iter()
        .map(|(frame, pixels)| WandFrame { frame, pixels })
        .collect())
}

/// The rig file's text with every camera's pose set to `cam_from_ref` (rotation rows and
/// translation in the file's unit); the rest of the file, comments included, as it was.
pub(crate) fn with_poses(
    text: &str,
    rig: &Rig,
    poses: &[Isometry3<f64>],
) -> anyhow::Result<String> {
    with_poses_and_intrinsics(text, rig, poses, None)
}

/// [`with_poses`], and with `intrinsics` each camera's `fx`, `fy` and `principal_point` (its
/// `focal_length_mm` and `pixel_pitch_um` removed: the pixels say it all).
pub(crate) fn with_poses_and_intrinsics(
    text: &str,
    rig: &Rig,
    poses: &[Isometry3<f64>],
    intrinsics: Option<&[stereoscope_geometry::Intrinsics]>,
) -> anyhow::Result<String> {
    let mut doc: toml_edit::DocumentMut = text.parse()?;
    let scale = rig.spec.units.metres();
    let cams = doc
        .get_mut("camera")
        .and_then(|c| c.as_array_of_tables_mut())
        .ok_or_else(|| anyhow!("the rig file has no [[camera]] tables"))?;
    for (cam, pose) in cams.iter_mut().zip(poses) {
        let r = pose.rotation.to_rotation_matrix();
        let mut rows = toml_edit::Array::new();
        for i in 0..3 {
            let mut row = toml_edit::Array::new();
            for j in 0..3 {
                row.push(round(r[(i, j)], 1e12));
            }
            rows.push(row);
        }
        let mut t = toml_edit::Array::new();
        for v in pose.translation.vector.iter() {
            t.push(round(v / scale, 1e9));
        }
        let mut table = toml_edit::InlineTable::new();
        table.insert("cam_from_world_rotation", rows.into());
        table.insert("cam_from_world_translation", t.into());
        cam.insert("pose", toml_edit::value(table));
    }
    if let Some(ks) = intrinsics {
        for (cam, k) in cams.iter_mut().zip(ks) {
            cam.remove("focal_length_mm");
            cam.remove("pixel_pitch_um");
            cam.insert("fx", toml_edit::value(round(k.fx, 1e6)));
            cam.insert("fy", toml_edit::value(round(k.fy, 1e6)));
            let mut pp = toml_edit::Array::new();
            pp.push(round(k.cx, 1e6));
            pp.push(round(k.cy, 1e6));
            cam.insert("principal_point", toml_edit::value(pp));
        }
    }
    Ok(doc.to_string())
}

fn round(v: f64, k: f64) -> f64 {
    (v * k).round() / k
}

/// Runs the command; `Ok(0)` when the rig was calibrated (warnings or not).
pub fn run(
    opts: &WandOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let metres = opts.units.metres();
    let wand = if opts.wand == [0.0] {
        Wand::one()
    } else {
        let mut offsets = vec![0.0];
        offsets.extend(opts.wand.iter().map(|d| d * metres));
        Wand::new(offsets).map_err(|e| {
            anyhow!(
                "--wand {:?}: {e} (0 for one marker, D for two, D1,D2 for three)",
                opts.wand
            )
        })?
    };
    let (text, rig) = rig_without_poses(&opts.rig)?;
    let units_name = rig.spec.units.to_string();
    let ids: Vec<String> = rig.cameras.iter().map(|c| c.id.clone()).collect();
    let sizes: Vec<[u32; 2]> = rig.spec.cameras.iter().map(|c| c.image_size).collect();
    let cams: Vec<Camera> = rig.cameras.iter().map(|c| c.camera).collect();
    // Frames are grouped as fusion groups them.
    let skew_ns = stereoscope_pipeline::fusion::FusionSettings::of_rig(&rig.spec)
        .pairing
        .max_skew_ns;
    let (source, frames) = match &opts.input {
        WandInput::File(path) => {
            let is_csv = path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("csv"));
            let frames = if is_csv {
                frames_from_csv(path, &ids, &sizes)?
            } else {
                let (obs, warnings) =
                    stereoscope_recorder::session::read_messages::<Observation>(path)?;
                if obs.len() > MAX_ROWS {
                    bail!("{}: more than {MAX_ROWS} observations", path.display());
                }
                for w in warnings {
                    writeln!(err, "warning: {w}")?;
                }
                frames_from_observations(&obs, &ids, &sizes, skew_ns)?
            };
            (path.display().to_string(), frames)
        }
        WandInput::Live(live) => {
            if !(live.max_seconds.is_finite() && live.max_seconds > 0.0) {
                bail!("--seconds {} must be above zero", live.max_seconds);
            }
            if !(0.0..=1.0).contains(&live.target) {
                bail!("--coverage {} is not between 0 and 1", live.target);
            }
            let obs = crate::wand_live::collect_live(&rig, &cams, &wand, live, err)?;
            let frames = frames_from_observations(&obs, &ids, &sizes, skew_ns)?;
            ("the live observations".to_string(), frames)
        }
    };
    if frames.is_empty() {
        bail!("{source}: no frames");
    }
    let cfg = WandConfig {
        refine_intrinsics: opts.refine_intrinsics,
        ..WandConfig::default()
    };
    let sol = calibrate_wand(&cams, &frames, &wand, &cfg).map_err(|e| match e {
        GeometryError::WandUnplaced { cameras, .. } => {
            anyhow!(
                "{source}: {}",
                stereoscope_calibration::wand::unplaced(&cameras, &ids, &frames, &wand)
            )
        }
        e => anyhow!("{source}: {e}"),
    })?;
    let view = RigView {
        name: &rig.name,
        units: &units_name,
        metres_per_unit: rig.spec.units.metres(),
        cameras: rig
            .cameras
            .iter()
            .zip(&rig.spec.cameras)
            .map(|(c, spec)| CameraView {
                id: &c.id,
                image_size: spec.image_size,
                mask: spec
                    .moments
                    .as_ref()
                    .map(|m| m.mask.as_slice())
                    .unwrap_or_default(),
            })
            .collect(),
    };
    let report = stereoscope_calibration::wand::card(&view, &sol, &frames, &wand, &cams);
    // A solve that did not converge (too few frames, or all of them in one plane), or a wand
    // not as the user described it, is refused, not written.
    stereoscope_calibration::wand::accept(&sol, &wand, &report).map_err(|e| match e {
        WandRefusal::MiddleMarker { .. } => anyhow!("{source}: {e} (--wand {:?})", opts.wand),
        e => anyhow!("{source}: {e}"),
    })?;
    if opts.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        write!(out, "{}", stereoscope_calibration::wand::markdown(&report))?;
    }
    if let Some(dir) = &opts.report {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        let md = dir.join("wand-report.md");
        std::fs::write(&md, stereoscope_calibration::wand::markdown(&report))
            .with_context(|| format!("{}: cannot write", md.display()))?;
        let js = dir.join("wand-report.json");
        std::fs::write(&js, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("{}: cannot write", js.display()))?;
        let png = dir.join("wand-coverage.png");
        let (rgb, w, h) = stereoscope_calibration::wand::heat_map(&cams, &frames, &wand);
        std::fs::write(&png, stereoscope_imageio::encode_png_rgb8(&rgb, w, h)?)
            .with_context(|| format!("{}: cannot write", png.display()))?;
    }
    if let Some(path) = &opts.out {
        let written = with_poses_and_intrinsics(
            &text,
            &rig,
            &sol.cam_from_ref,
            opts.refine_intrinsics.then_some(sol.intrinsics.as_slice()),
        )?;
        // What is written must load as a rig.
        Rig::from_toml(&written).map_err(|e| anyhow!("the calibrated rig does not load: {e}"))?;
        std::fs::write(path, written)
            .with_context(|| format!("{}: cannot write", path.display()))?;
        writeln!(err, "wrote {}", path.display())?;
    }
    Ok(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{BlobObservation, SCHEMA_VERSION};

    fn obs(camera: &str, t_ns: u64, xs: &[f64]) -> Observation {
        Observation {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            camera: camera.into(),
            sequence: t_ns,
            timestamp_ns: t_ns,
            frame_published_ns: t_ns,
            published_ns: t_ns,
            width_px: 640,
            height_px: 480,
            threshold: 100,
            dark: false,
            full_frame: false,
            dropped_blobs: 0,
            blobs: xs
                .iter()
                .map(|&x| BlobObservation {
                    track_id: 1,
                    status: TrackState::Tracked,
                    area_px: 20.0,
                    x_px: x,
                    y_px: 10.0,
                    mu20: 1.0,
                    mu02: 1.0,
                    mu11: 0.0,
                    orientation_deg: 0.0,
                    roundness: 1.0,
                    heading_deg: 0.0,
                    directed: false,
                    heading_ambiguous: true,
                    clipped: x < 0.0,
                    merged: false,
                    window_px: [0, 0, 639, 479],
                    bbox_px: [0, 0, 1, 1],
                })
                .collect(),
        }
    }

    /// Recorded observations become frames by time: each camera at most once a frame, within
    /// the rig's skew; clipped blobs are left out; a camera not in the rig is named.
    #[test]
    fn observations_are_grouped_into_frames_by_time() {
        let ids = vec!["a".to_string(), "b".to_string()];
        let ms = 1_000_000;
        let list = vec![
            obs("b", 100 * ms + 2 * ms, &[5.0, 6.0]),
            obs("a", 100 * ms, &[1.0, 2.0]),
            obs("a", 133 * ms, &[3.0, -1.0]),
            obs("b", 134 * ms, &[7.0]),
            obs("b", 166 * ms, &[8.0]),
        ];
        let sizes = [[640, 480]; 2];
        let frames = frames_from_observations(&list, &ids, &sizes, 5 * ms).unwrap();
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[0].pixels[0].len(), 2);
        assert_eq!(frames[0].pixels[1][0].x, 5.0);
        assert_eq!(frames[1].pixels[0].len(), 1, "the clipped blob is left out");
        assert_eq!(frames[1].pixels[1][0].x, 7.0);
        assert!(frames[2].pixels[0].is_empty());
        let err = frames_from_observations(&[obs("c", 1, &[])], &ids, &sizes, 5 * ms).unwrap_err();
        assert!(err.to_string().contains("camera \"c\""), "{err}");
        // Frames of another size than the rig's: named, with both sizes.
        let small = [[320, 240], [640, 480]];
        let err = frames_from_observations(&list, &ids, &small, 5 * ms).unwrap_err();
        assert!(
            err.to_string()
                .contains("camera \"a\" sent 640 × 480 frames, the rig says 320 × 240"),
            "{err}"
        );
    }
}
