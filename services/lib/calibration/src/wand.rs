//! The wand calibration's acceptance and report card (`stereoscope calibrate wand`,
//! `docs/calibration.md`): what a solution of `stereoscope_geometry::wand` says about each
//! camera (reprojection, samples, image coverage, masked share, position), the wand's length
//! error by region of the volume, the warnings a user acts on, the coverage picture, and the
//! rules that refuse a solution (a camera that did not converge, a three-marker wand whose
//! middle marker is not where the user said) with typed errors. The command reads the input,
//! writes the files and the rig.

use nalgebra::{Point2, Point3};
use serde::Serialize;
use stereoscope_geometry::Camera;
use stereoscope_geometry::wand::{Wand, WandFrame, WandSolution};

/// Image coverage is counted on a grid of this many cells across and down each image.
pub const COVERAGE_CELLS: (usize, usize) = (8, 6);
/// A solution with a camera reprojecting worse than this did not converge, and is refused.
pub const MAX_SOLVED_RMS_PX: f64 = 5.0;
/// A camera whose wand samples cover less of its image than this is warned about.
pub const MIN_COVERAGE: f64 = 0.5;

/// What the report needs of the rig.
#[derive(Debug, Clone)]
pub struct RigView<'a> {
    pub name: &'a str,
    /// The rig's unit, as written ("mm").
    pub units: &'a str,
    pub metres_per_unit: f64,
    pub cameras: Vec<CameraView<'a>>,
}

/// What the report needs of one camera.
#[derive(Debug, Clone)]
pub struct CameraView<'a> {
    pub id: &'a str,
    pub image_size: [u32; 2],
    /// Its `moments.mask` rectangles.
    pub mask: &'a [crate::mask::Rect],
}

/// Why a solution is refused (nothing is written).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WandRefusal {
    #[error(
        "the solve did not converge: camera {camera} reprojects {rms_px:.1} px RMS (over {MAX_SOLVED_RMS_PX} px). Collect more frames, and move the wand through more of the volume, turning it, not in one plane"
    )]
    NotConverged { camera: String, rms_px: f64 },
    #[error(
        "the wand's middle marker measures {measured_mm:.1} mm from its end marker, not {said_mm:.1} mm: measure the wand's distances again, centre to centre, from the end marker nearer the middle one"
    )]
    MiddleMarker { measured_mm: f64, said_mm: f64 },
}

/// Refuses a solution a rig should not be written from: a three-marker wand whose middle
/// marker the solve puts more than 2 mm (or 2 %) from where the user said, or a camera
/// reprojecting worse than [`MAX_SOLVED_RMS_PX`] (or not a number).
pub fn accept(sol: &WandSolution, wand: &Wand, report: &WandReport) -> Result<(), WandRefusal> {
    if let (Some(middle), 3) = (sol.middle_mean_m, wand.markers()) {
        let said = wand.offsets_m[1];
        if (middle - said).abs() > (0.002f64).max(0.02 * said) {
            return Err(WandRefusal::MiddleMarker {
                measured_mm: middle * 1e3,
                said_mm: said * 1e3,
            });
        }
    }
    if let Some(c) = report
        .cameras
        .iter()
        .find(|c| !(c.reprojection_rms_px <= MAX_SOLVED_RMS_PX))
    {
        return Err(WandRefusal::NotConverged {
            camera: c.id.clone(),
            rms_px: c.reprojection_rms_px,
        });
    }
    Ok(())
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
pub fn regions(sol: &WandSolution, length_m: f64) -> Vec<RegionCard> {
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

/// The coverage cell (row by row) of pixel `p` in camera `cam`'s image.
pub fn cell_of(cam: &Camera, p: &Point2<f64>) -> usize {
    let (cx, cy) = COVERAGE_CELLS;
    let (w, h) = (cam.intrinsics.width as f64, cam.intrinsics.height as f64);
    let i = ((p.x / w * cx as f64).floor() as isize).clamp(0, cx as isize - 1);
    let j = ((p.y / h * cy as f64).floor() as isize).clamp(0, cy as isize - 1);
    j as usize * cx + i as usize
}

/// Share of cells with a sample.
pub fn share(counts: &[u32]) -> f64 {
    counts.iter().filter(|&&n| n > 0).count() as f64 / counts.len().max(1) as f64
}

/// Share of each camera's image cells that hold a sample of the wand (frames used).
pub fn coverage(cams: &[Camera], frames: &[WandFrame], wand: &Wand) -> Vec<f64> {
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
/// Returns the picture's RGB bytes, width and height.
pub fn heat_map(cams: &[Camera], frames: &[WandFrame], wand: &Wand) -> (Vec<u8>, u32, u32) {
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
    (rgb, width as u32, th as u32)
}

/// The report card of a solution.
pub fn card(
    rig: &RigView,
    sol: &WandSolution,
    frames: &[WandFrame],
    wand: &Wand,
    cams: &[Camera],
) -> WandReport {
    let scale = rig.metres_per_unit;
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
            let [w, h] = rc.image_size;
            CameraCard {
                id: rc.id.to_string(),
                reprojection_rms_px: rms,
                samples,
                coverage: cover[c],
                masked: crate::mask::share_pct(rc.mask, w, h) / 100.0,
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
        rig: rig.name.to_string(),
        units: rig.units.to_string(),
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

/// The report card as Markdown (what the command prints and `wand-report.md` holds).
pub fn markdown(r: &WandReport) -> String {
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

/// Why cameras `unplaced` (rig indices) could not be placed, by id: a frame is the wand's only
/// where a camera sees exactly its markers, so each camera's frames are counted by how many
/// blobs it saw ("cam2: 12 frames with the wand's 2 markers, 1 830 with 3 blobs").
pub fn unplaced(unplaced: &[usize], ids: &[String], frames: &[WandFrame], wand: &Wand) -> String {
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
    use nalgebra::Isometry3;

    fn solution(rms: [f64; 2], middle_m: Option<f64>) -> WandSolution {
        WandSolution {
            cam_from_ref: vec![
                Isometry3::identity(),
                Isometry3::translation(-1.0, 0.0, 0.0),
            ],
            intrinsics: Vec::new(),
            initial_cam_from_ref: Vec::new(),
            per_camera: vec![(rms[0], 100), (rms[1], 100)],
            frames_used: 50,
            frames_unusable: 0,
            frames_outliers: 0,
            length_mean_m: Some(0.5),
            length_sd_m: Some(0.001),
            scale_known: true,
            scale_anchor: 1,
            middle_mean_m: middle_m,
            // Two frames on each side of the volume along x, the wand 1 mm long and short.
            lengths: vec![
                (Point3::new(-1.0, 0.0, 0.0), 0.499),
                (Point3::new(-1.0, 0.0, 0.0), 0.499),
                (Point3::new(1.0, 0.0, 0.0), 0.501),
                (Point3::new(1.0, 0.0, 0.0), 0.501),
            ],
        }
    }

    fn report(sol: &WandSolution, wand: &Wand) -> WandReport {
        let cams: Vec<Camera> = (0..2)
            .map(|_| {
                Camera::new(
                    stereoscope_geometry::camera::Intrinsics::new(
                        600.0, 600.0, 320.0, 240.0, 640, 480,
                    )
                    .unwrap(),
                    Default::default(),
                    Isometry3::identity(),
                )
                .unwrap()
            })
            .collect();
        let mask = [[0, 0, 63, 47]];
        let view = RigView {
            name: "r",
            units: "mm",
            metres_per_unit: 1e-3,
            cameras: vec![
                CameraView {
                    id: "left",
                    image_size: [640, 480],
                    mask: &mask,
                },
                CameraView {
                    id: "right",
                    image_size: [640, 480],
                    mask: &[],
                },
            ],
        };
        card(&view, sol, &[], wand, &cams)
    }

    #[test]
    fn a_solution_is_refused_with_the_camera_or_the_marker_named() {
        let two = Wand::new(vec![0.0, 0.5]).unwrap();
        let sol = solution([0.2, 0.3], None);
        let r = report(&sol, &two);
        assert_eq!(accept(&sol, &two, &r), Ok(()));
        assert_eq!(r.cameras[1].id, "right");
        assert!(
            (r.cameras[1].position[0] - 1000.0).abs() < 1e-9,
            "{:?}",
            r.cameras[1]
        );
        assert!((r.cameras[0].masked - 0.01).abs() < 1e-12);
        // Nothing sampled: both cameras warned about their coverage.
        assert_eq!(r.warnings.len(), 2, "{:?}", r.warnings);

        let bad = solution([0.2, 7.5], None);
        let e = accept(&bad, &two, &report(&bad, &two)).unwrap_err();
        assert_eq!(
            e,
            WandRefusal::NotConverged {
                camera: "right".into(),
                rms_px: 7.5
            }
        );
        let nan = solution([f64::NAN, 0.2], None);
        assert!(matches!(
            accept(&nan, &two, &report(&nan, &two)),
            Err(WandRefusal::NotConverged { camera, .. }) if camera == "left"
        ));

        let three = Wand::new(vec![0.0, 0.2, 0.5]).unwrap();
        let off = solution([0.2, 0.2], Some(0.23));
        let e = accept(&off, &three, &report(&off, &three)).unwrap_err();
        assert!(
            e.to_string()
                .contains("230.0 mm from its end marker, not 200.0 mm"),
            "{e}"
        );
        let near = solution([0.2, 0.2], Some(0.2015));
        assert_eq!(accept(&near, &three, &report(&near, &three)), Ok(()));
    }

    #[test]
    fn the_length_error_is_split_by_octant() {
        let r = regions(&solution([0.2, 0.2], None), 0.5);
        assert_eq!(r.len(), 2, "{r:?}");
        let short = r.iter().find(|c| c.octant.starts_with("-x")).unwrap();
        let long = r.iter().find(|c| c.octant.starts_with("+x")).unwrap();
        assert!((short.mean_error_mm + 1.0).abs() < 1e-9 && short.samples == 2);
        assert!((long.mean_error_mm - 1.0).abs() < 1e-9 && long.sd_mm.abs() < 1e-9);
    }

    #[test]
    fn unplaced_cameras_are_named_with_their_frames_by_blob_count() {
        let two = Wand::new(vec![0.0, 0.5]).unwrap();
        let px = |n: usize| vec![Point2::new(1.0, 1.0); n];
        let frames: Vec<WandFrame> = (0..5)
            .map(|i| WandFrame {
                frame: i,
                pixels: vec![px(2), px(if i < 2 { 2 } else { 3 })],
            })
            .collect();
        let ids = vec!["a".to_string(), "b".to_string()];
        let m = unplaced(&[1], &ids, &frames, &two);
        assert!(
            m.contains("camera b shares too few wand frames")
                && m.contains("b: 2 frames with the wand's 2 markers, 3 with 3 blobs"),
            "{m}"
        );
    }
}
