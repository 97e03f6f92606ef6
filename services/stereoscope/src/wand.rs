//! `stereoscope calibrate wand`: every camera's pose from a wand waved through the volume
//! (`stereoscope_geometry::wand`), read from a recorder's `observations.jsonl`, a CSV
//! `frame,camera,u,v` of blob centroids, or (`--live`) the running rig's observations until
//! every camera's image is covered — with a bar per camera filling meanwhile, and the
//! coverage published for the viewer; prints a report card, writes it as Markdown and JSON,
//! and writes the rig file with the poses (`docs/calibration.md`).

use anyhow::{Context, anyhow, bail};
use nalgebra::{Isometry3, Point2, Point3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use stereoscope_geometry::Camera;
use stereoscope_geometry::GeometryError;
use stereoscope_geometry::wand::{Wand, WandConfig, WandFrame, WandSolution, calibrate_wand};
use stereoscope_proto::messages::{Observation, TrackState};
use stereoscope_rig::{Rig, Units};

/// More rows or frames than this in an input is refused (a day of 8 cameras at 120 fps is
/// far below; a wand wave is minutes).
pub const MAX_ROWS: usize = 20_000_000;
/// A camera's view with more blobs than this in one frame is not the wand (left out).
pub const MAX_BLOBS_PER_VIEW: usize = 16;
/// Image coverage is counted on a grid of this many cells across and down each image.
pub(crate) const COVERAGE_CELLS: (usize, usize) = (8, 6);
/// A solution with a camera reprojecting worse than this did not converge, and is refused.
pub const MAX_SOLVED_RMS_PX: f64 = 5.0;
/// A camera whose wand samples cover less of its image than this is warned about.
const MIN_COVERAGE: f64 = 0.5;

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

#[derive(Debug, Clone, Serialize)]
pub struct CameraCard {
    pub id: String,
    pub reprojection_rms_px: f64,
    pub samples: usize,
    /// Share of the image's grid cells with wand samples.
    pub coverage: f64,
    /// Share of the image the camera's masks cover (`moments.mask`: nothing is seen there).
    pub masked: f64,
    /// The camera's position in camera 0's frame, the rig's unit.
    pub position: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct RegionCard {
    /// `"+x-y+z"`: which side of the median along camera 0's x, y and z.
    pub octant: String,
    pub samples: usize,
    pub mean_error_mm: f64,
    pub sd_mm: f64,
}

/// The wand's length error (measured − true) in each octant of the swept volume.
fn regions(sol: &WandSolution, length_m: f64) -> Vec<RegionCard> {
    let median = |i: usize| {
        let mut v: Vec<f64> = sol.lengths.iter().map(|(p, _)| p[i]).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let mid = [median(0), median(1), median(2)];
    let mut errs: Vec<Vec<f64>> = vec![Vec::new(); 8];
    for (p, l) in &sol.lengths {
        let k = (0..3).fold(0, |k, i| k | (usize::from(p[i] >= mid[i]) << i));
        errs[k].push((l - length_m) * 1e3);
    }
    errs.iter()
        .enumerate()
        .filter(|(_, e)| !e.is_empty())
        .map(|(k, e)| {
            let n = e.len() as f64;
            let mean = e.iter().sum::<f64>() / n;
            let sd =
                (e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
            let sign =
                |i: usize, axis: char| format!("{}{axis}", if k >> i & 1 == 1 { '+' } else { '-' });
            RegionCard {
                octant: format!("{}{}{}", sign(0, 'x'), sign(1, 'y'), sign(2, 'z')),
                samples: e.len(),
                mean_error_mm: mean,
                sd_mm: sd,
            }
        })
        .collect()
}

#[derive(Debug, Clone, Serialize)]
pub struct WandReport {
    pub rig: String,
    pub units: String,
    pub frames_read: usize,
    pub frames_used: usize,
    pub frames_unusable: usize,
    pub frames_outliers: usize,
    /// The wand's length; `None` (and the two below too) for a one-marker wand.
    pub wand_length_mm: Option<f64>,
    pub wand_length_mean_error_mm: Option<f64>,
    pub wand_length_sd_mm: Option<f64>,
    /// False for a one-marker wand: the poses' scale is arbitrary until `calibrate floor
    /// --scale` sets it from the L-frame.
    pub scale_known: bool,
    pub cameras: Vec<CameraCard>,
    /// The wand's length error by region of the volume: the volume the wand swept cut at its
    /// median along each of camera 0's axes into eight octants.
    pub regions: Vec<RegionCard>,
    pub warnings: Vec<String>,
    /// The world until `calibrate floor` sets one: camera 0's frame.
    pub world: String,
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

/// The coverage cell (row by row) of pixel `p` in camera `cam`'s image.
pub(crate) fn cell_of(cam: &Camera, p: &Point2<f64>) -> usize {
    let (cx, cy) = COVERAGE_CELLS;
    let (w, h) = (cam.intrinsics.width as f64, cam.intrinsics.height as f64);
    let i = ((p.x / w * cx as f64).floor() as isize).clamp(0, cx as isize - 1);
    let j = ((p.y / h * cy as f64).floor() as isize).clamp(0, cy as isize - 1);
    j as usize * cx + i as usize
}

/// Share of cells with a sample.
pub(crate) fn share(counts: &[u32]) -> f64 {
    counts.iter().filter(|&&n| n > 0).count() as f64 / counts.len().max(1) as f64
}

/// Share of each camera's image cells that hold a sample of the wand (frames used).
fn coverage(cams: &[Camera], frames: &[WandFrame], wand: &Wand) -> Vec<f64> {
    let (cx, cy) = COVERAGE_CELLS;
    cams.iter()
        .enumerate()
        .map(|(c, cam)| {
            let mut counts = vec![0u32; cx * cy];
            for f in frames
                .iter()
                .filter(|f| f.pixels[c].len() == wand.markers())
            {
                for p in &f.pixels[c] {
                    counts[cell_of(cam, p)] += 1;
                }
            }
            share(&counts)
        })
        .collect()
}

/// Tiles of the heat map, pixels.
const TILE: (usize, usize) = (160, 120);

/// The report's picture (`wand-coverage.png`): one tile per camera, left to right in the rig's
/// order, each its image shrunk to 160 × 120 with the wand's samples as heat (none: black;
/// few: blue; many: yellow) on a 32 × 24 grid, and the 8 × 6 coverage cells outlined in grey.
fn heat_map(cams: &[Camera], frames: &[WandFrame], wand: &Wand) -> anyhow::Result<Vec<u8>> {
    let (tw, th) = TILE;
    let (gx, gy) = (32usize, 24usize);
    let gap = 4;
    let width = cams.len() * (tw + gap) - gap;
    let mut rgb = vec![30u8; width * th * 3];
    for (c, cam) in cams.iter().enumerate() {
        let (w, h) = (cam.intrinsics.width as f64, cam.intrinsics.height as f64);
        let mut counts = vec![0u32; gx * gy];
        for f in frames
            .iter()
            .filter(|f| f.pixels[c].len() == wand.markers())
        {
            for p in &f.pixels[c] {
                let i = ((p.x / w * gx as f64).floor() as isize).clamp(0, gx as isize - 1);
                let j = ((p.y / h * gy as f64).floor() as isize).clamp(0, gy as isize - 1);
                counts[j as usize * gx + i as usize] += 1;
            }
        }
        let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
        let (cx, cy) = COVERAGE_CELLS;
        for y in 0..th {
            for x in 0..tw {
                let n = counts[(y * gy / th) * gx + x * gx / tw] as f64;
                // Log scale: a single sample shows.
                let t = if n > 0.0 {
                    (1.0 + n).ln() / (1.0 + top).ln()
                } else {
                    0.0
                };
                let mut px = if n > 0.0 {
                    [
                        (255.0 * t) as u8,
                        (255.0 * t) as u8,
                        (255.0 * (1.0 - t)) as u8,
                    ]
                } else {
                    [0, 0, 0]
                };
                if x % (tw / cx) == 0 || y % (th / cy) == 0 || x == tw - 1 || y == th - 1 {
                    px = [90, 90, 90];
                }
                let i = 3 * (y * width + c * (tw + gap) + x);
                rgb[i..i + 3].copy_from_slice(&px);
            }
        }
    }
    Ok(stereoscope_imageio::encode_png_rgb8(
        &rgb,
        width as u32,
        th as u32,
    )?)
}

/// The report card of a solution.
fn card(
    rig: &Rig,
    sol: &WandSolution,
    frames: &[WandFrame],
    wand: &Wand,
    cams: &[Camera],
) -> WandReport {
    let scale = rig.spec.units.metres();
    let cover = coverage(cams, frames, wand);
    let mut warnings = Vec::new();
    let cameras: Vec<CameraCard> = rig
        .cameras
        .iter()
        .enumerate()
        .map(|(c, rc)| {
            let at = sol.cam_from_ref[c].inverse() * Point3::origin();
            let (rms, samples) = sol.per_camera[c];
            if cover[c] < MIN_COVERAGE {
                warnings.push(format!(
                    "camera {}: the wand covered {:.0} % of its image (less than {:.0} %): wave it into the corners this camera sees",
                    rc.id,
                    cover[c] * 100.0,
                    MIN_COVERAGE * 100.0
                ));
            }
            if rms > 1.0 {
                warnings.push(format!(
                    "camera {}: reprojection RMS {rms:.2} px (above 1 px): check its intrinsics and distortion",
                    rc.id
                ));
            }
            let [w, h] = rig.spec.cameras[c].image_size;
            let mask = rig.spec.cameras[c]
                .moments
                .as_ref()
                .map(|m| m.mask.as_slice())
                .unwrap_or_default();
            CameraCard {
                id: rc.id.clone(),
                reprojection_rms_px: rms,
                samples,
                coverage: cover[c],
                masked: stereoscope_calibration::mask::share_pct(mask, w, h) / 100.0,
                position: [at.x / scale, at.y / scale, at.z / scale],
            }
        })
        .collect();
    let length = sol.length_mean_m.zip(sol.length_sd_m);
    if let Some((mean, sd)) = length {
        let err_mm = (mean - wand.length_m()) * 1e3;
        if err_mm.abs() > 1.0 || sd * 1e3 > 2.0 {
            warnings.push(format!(
                "the wand measures {:.2} ± {:.2} mm against {:.2} mm: check its length and the cameras' intrinsics",
                mean * 1e3,
                sd * 1e3,
                wand.length_m() * 1e3
            ));
        }
    }
    if !sol.scale_known {
        warnings.push(format!(
            "a one-marker wand gives no scale: camera {} is put 1 m from camera {}; set the scale with `stereoscope calibrate floor --l-frame LONG,SHORT --scale` before using the rig",
            rig.cameras[sol.scale_anchor].id, rig.cameras[0].id
        ));
    }
    WandReport {
        rig: rig.name.clone(),
        units: rig.spec.units.to_string(),
        frames_read: frames.len(),
        frames_used: sol.frames_used,
        frames_unusable: sol.frames_unusable,
        frames_outliers: sol.frames_outliers,
        wand_length_mm: wand.has_length().then(|| wand.length_m() * 1e3),
        wand_length_mean_error_mm: length.map(|(mean, _)| (mean - wand.length_m()) * 1e3),
        wand_length_sd_mm: length.map(|(_, sd)| sd * 1e3),
        scale_known: sol.scale_known,
        cameras,
        regions: regions(sol, wand.length_m()),
        warnings,
        world: format!(
            "camera {}'s frame (x right, y down, z along its axis); set the floor with `stereoscope calibrate floor`",
            rig.cameras[0].id
        ),
    }
}

fn markdown(r: &WandReport) -> String {
    let wand = match (
        r.wand_length_mm,
        r.wand_length_mean_error_mm,
        r.wand_length_sd_mm,
    ) {
        (Some(length), Some(err), Some(sd)) => {
            format!("Wand: {length:.2} mm; measured {err:+.3} mm off on average, SD {sd:.3} mm.")
        }
        _ => "Wand: one marker; the scale is not known yet.".to_string(),
    };
    let mut s = format!(
        "# Wand calibration of rig {}\n\nFrames: {} read, {} used, {} unusable (the wand whole in fewer than two cameras), {} outliers.\n\n{wand}\n\n| camera | reprojection RMS px | samples | image coverage | masked | position ({}) |\n|---|---|---|---|---|---|\n",
        r.rig, r.frames_read, r.frames_used, r.frames_unusable, r.frames_outliers, r.units
    );
    for c in &r.cameras {
        s.push_str(&format!(
            "| {} | {:.3} | {} | {:.0} % | {:.1} % | {:.2}, {:.2}, {:.2} |\n",
            c.id,
            c.reprojection_rms_px,
            c.samples,
            c.coverage * 100.0,
            c.masked * 100.0,
            c.position[0],
            c.position[1],
            c.position[2]
        ));
    }
    if !r.regions.is_empty() {
        s.push_str("\nThe wand's length error by region (octants of the swept volume about its median, camera 0's axes):\n\n| octant | samples | mean error mm | SD mm |\n|---|---|---|---|\n");
    }
    for g in &r.regions {
        s.push_str(&format!(
            "| {} | {} | {:+.3} | {:.3} |\n",
            g.octant, g.samples, g.mean_error_mm, g.sd_mm
        ));
    }
    s.push_str(&format!("\nWorld: {}.\n", r.world));
    if !r.warnings.is_empty() {
        s.push_str("\nWarnings:\n\n");
        for w in &r.warnings {
            s.push_str(&format!("- {w}\n"));
        }
    }
    s
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
    let ids: Vec<String> = rig.cameras.iter().map(|c| c.id.clone()).collect();
    let sizes: Vec<[u32; 2]> = rig.spec.cameras.iter().map(|c| c.image_size).collect();
    let cams: Vec<Camera> = rig.cameras.iter().map(|c| c.camera).collect();
    let skew_ns = (rig
        .spec
        .fusion
        .as_ref()
        .and_then(|f| f.max_skew_ms)
        .unwrap_or(5.0)
        * 1e6) as u64;
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
            anyhow!("{source}: {}", unplaced(&cameras, &ids, &frames, &wand))
        }
        e => anyhow!("{source}: {e}"),
    })?;
    if let (Some(middle), 3) = (sol.middle_mean_m, wand.markers()) {
        let said = wand.offsets_m[1];
        if (middle - said).abs() > (0.002f64).max(0.02 * said) {
            bail!(
                "{source}: the wand's middle marker measures {:.1} mm from its end marker, not {:.1} mm (--wand {:?}): measure the wand's distances again, centre to centre, from the end marker nearer the middle one",
                middle * 1e3,
                said * 1e3,
                opts.wand
            );
        }
    }
    let report = card(&rig, &sol, &frames, &wand, &cams);
    // A solve that did not converge (too few frames, or all of them in one plane) is refused,
    // not written.
    if let Some(c) = report
        .cameras
        .iter()
        .find(|c| !(c.reprojection_rms_px <= MAX_SOLVED_RMS_PX))
    {
        bail!(
            "{source}: the solve did not converge: camera {} reprojects {:.1} px RMS (over {MAX_SOLVED_RMS_PX} px). Collect more frames, and move the wand through more of the volume, turning it, not in one plane",
            c.id,
            c.reprojection_rms_px
        );
    }
    if opts.json {
        writeln!(out, "{}", serde_json::to_string(&report)?)?;
    } else {
        write!(out, "{}", markdown(&report))?;
    }
    if let Some(dir) = &opts.report {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create", dir.display()))?;
        let md = dir.join("wand-report.md");
        std::fs::write(&md, markdown(&report))
            .with_context(|| format!("{}: cannot write", md.display()))?;
        let js = dir.join("wand-report.json");
        std::fs::write(&js, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("{}: cannot write", js.display()))?;
        let png = dir.join("wand-coverage.png");
        std::fs::write(&png, heat_map(&cams, &frames, &wand)?)
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

/// Why cameras `unplaced` (rig indices) could not be placed, by id: a frame is the wand's only
/// where a camera sees exactly its markers, so each camera's frames are counted by how many
/// blobs it saw ("cam2: 12 frames with the wand's 2 markers, 1 830 with 3 blobs").
fn unplaced(unplaced: &[usize], ids: &[String], frames: &[WandFrame], wand: &Wand) -> String {
    let per_camera: Vec<String> = unplaced
        .iter()
        .map(|&c| {
            let mut by_count = std::collections::BTreeMap::<usize, usize>::new();
            for f in frames {
                *by_count
                    .entry(f.pixels.get(c).map_or(0, Vec::len))
                    .or_default() += 1;
            }
            let right = by_count.remove(&wand.markers()).unwrap_or(0);
            let others: Vec<String> = by_count
                .iter()
                .rev()
                .map(|(blobs, n)| {
                    format!(
                        "{n} with {blobs} blob{}",
                        if *blobs == 1 { "" } else { "s" }
                    )
                })
                .collect();
            format!(
                "{}: {right} frames with the wand's {} markers{}{}",
                ids.get(c).map_or("?", String::as_str),
                wand.markers(),
                if others.is_empty() { "" } else { ", " },
                others.join(", ")
            )
        })
        .collect();
    let names: Vec<&str> = unplaced
        .iter()
        .map(|&c| ids.get(c).map_or("?", String::as_str))
        .collect();
    format!(
        "camera{} {} share{} too few wand frames (8 at least) with the others to be placed — {}. A frame counts where a camera sees exactly the wand's markers: remove other bright things from view (or mask them, `calibrate mask`), and wave the wand where each of these cameras sees it together with another camera",
        if names.len() == 1 { "" } else { "s" },
        names.join(", "),
        if names.len() == 1 { "s" } else { "" },
        per_camera.join("; ")
    )
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
