//! `stereoscope reproduce`: the thesis's four experiments (chapter 4, Tables 4.1–4.4) repeated
//! in a simulation of its lab, through the project's own libraries.
//!
//! The lab (`deploy/rigs/thesis-lab.toml`): two parallel cameras looking down from a 280 cm
//! ceiling (camera 1 at 277.5 cm), 20 cm apart, 12.5 mm lenses, 320 × 240, PAR 0.86; the target
//! is two 40 mm ping-pong balls glued together. As a user would:
//!
//! 1. **calibrate** both cameras jointly from rendered images of a dot-grid board held tilted
//!    at several heights, and the world frame from the board lying on the floor;
//! 2. **fit the area models** of camera 0 from the target on stands of known height;
//! 3. **measure**: 25 readings at each height — 2–202 cm for one camera with the two- and
//!    three-parameter models (Tables 4.1, 4.2), 2–152 cm for two cameras at the board's centre
//!    and near its corner (Tables 4.3, 4.4) — each reading a freshly rendered, noisy frame.
//!
//! Each reading uses the moment engine (auto threshold, grey-level moments: the "area" is
//! Σ(pixel − background)/contrast, far less noisy than a pixel count) and the geometry library
//! (depth from area and the centroid's ray; or triangulation with the calibrated cameras).
//! Heights are of the target's underside, as the thesis measured them. Error = actual −
//! measured, as in the thesis's tables.

use crate::csvin;
use anyhow::{Context, anyhow};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stereoscope_geometry::Camera;
use stereoscope_geometry::calibrate::{DistortionModel, RigView, calibrate_rig};
use stereoscope_geometry::depth::{
    DepthFit, fit_three_parameter, fit_two_parameter, on_axis_area, point_from_depth,
};
use stereoscope_geometry::dotgrid::{DotGrid, detect, render as render_grid};
use stereoscope_geometry::triangulate::{Observation, triangulate};
use stereoscope_geometry::world_heading::{AxisView, fuse};
use stereoscope_numeric::SplitMix64;
use stereoscope_render::{Background, RenderOptions, Scene, Shape, State, Target, render_u8};
use stereoscope_rig::Rig;
use stereoscope_vision::raster::add_gaussian_noise;
use stereoscope_vision::{
    ExtractConfig, Extractor, GrayImage, Histogram, ThresholdMethod, Weighting,
};

/// The thesis's lab as shipped in `deploy/rigs/thesis-lab.toml`.
pub const THESIS_LAB: &str = include_str!("../../../deploy/rigs/thesis-lab.toml");
const BALL_RADIUS_M: f64 = 0.02;
const BACKGROUND: f64 = 20.0;
/// Where coverage saturates, grey levels above the background: just below the darkest part of
/// the target, its rim (the lit ball's rim is 60 % of the 190-level contrast, 114), which a
/// user reads off any frame of the target.
const FULL_ABOVE_BACKGROUND: u32 = 110;
/// Calibration views with the board held tilted.
const TILTED_VIEWS: usize = 48;
/// How high the tilted board's centre is held, metres above the floor: low enough for the
/// 80 × 60 cm board to stay whole in a 320 × 240 view.
const TILTED_HEIGHT_M: (f64, f64) = (0.2, 0.9);
/// The calibration board: the thesis's 10 cm grid, as 9 × 7 dots 10 cm apart (2 cm radius).
const BOARD: (usize, usize, f64) = (9, 7, 0.10);
/// A font every machine of this kind has (Debian's fonts-dejavu-core), for the plots' text.
pub const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

/// The realistic setting is the default (docs/reproduce.md).
#[derive(Debug, Clone)]
pub struct ReproduceOptions {
    pub out: PathBuf,
    pub seed: u64,
    /// Readings per height (the thesis took 25).
    pub readings: usize,
    pub noise_sigma: f64,
    pub blur_sigma_px: f64,
    /// Target brightness above the background, grey levels.
    pub contrast: f64,
    pub plots: bool,
    /// Also rerun the four experiments at other noise levels (the noise table).
    pub noise_sweep: bool,
    /// Another lab: a rig file whose first two cameras look down at the floor (z = 0), like
    /// `deploy/rigs/thesis-lab.toml`. `None`: the thesis's lab.
    pub rig: Option<PathBuf>,
}

impl ReproduceOptions {
    pub fn realistic(out: PathBuf) -> Self {
        ReproduceOptions {
            out,
            seed: 1994,
            readings: 25,
            noise_sigma: 2.0,
            blur_sigma_px: 0.5,
            contrast: 190.0,
            plots: true,
            noise_sweep: true,
            rig: None,
        }
    }
}

/// One row of a thesis table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    pub actual_cm: f64,
    pub mean_cm: f64,
    pub sd_cm: f64,
    /// Actual − measured, as the thesis's tables.
    pub error_cm: f64,
}

/// One experiment's table.
#[derive(Debug, Clone, PartialEq)]
pub struct Experiment {
    pub key: &'static str,
    pub title: &'static str,
    pub thesis_table: &'static str,
    pub thesis_rms_cm: f64,
    pub rows: Vec<Row>,
    pub rms_cm: f64,
}

impl Experiment {
    /// The goal: one fifth of the thesis's RMS.
    pub fn goal_cm(&self) -> f64 {
        self.thesis_rms_cm / 5.0
    }
}

/// Everything the run measured.
#[derive(Debug, Clone)]
pub struct Report {
    pub calibration_rms_px: f64,
    pub calibration_views: usize,
    pub experiments: Vec<Experiment>,
    pub fit_two: DepthFit,
    pub fit_three: DepthFit,
    /// `(height cm, grey-level area px)` of the fitting sweep.
    pub area_samples: Vec<(f64, f64)>,
    /// The double ball's heading from both cameras: `(height cm, true °, measured °, error °)`
    /// per reading; an axis, so compared modulo 180°.
    pub heading: Vec<(f64, f64, f64, f64)>,
    /// Height error over the whole board at `HEAT_HEIGHT_M`, one cell each 15 cm.
    pub heat: Vec<HeatCell>,
    /// `(noise σ, RMS of the four experiments in order)` at other noise levels.
    pub noise: Vec<(f64, [f64; 4])>,
}

/// Height of the heat-map sweep (the target's underside; the second height of every table).
pub const HEAT_HEIGHT_M: f64 = 0.12;
/// The thesis's board, metres (`../shared/DESIGN.md` §3), centred on the world origin.
pub const BOARD_SIZE_M: (f64, f64) = (2.17, 1.83);
/// Heat-map cell size, metres.
const HEAT_CELL_M: f64 = 0.15;

/// How a heat-map cell was measured: as the live fusion would, by both cameras where both see
/// the whole target, else by depth from area in the one camera that does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeatMethod {
    BothCameras,
    OneCamera(usize),
    Unseen,
}

impl HeatMethod {
    pub fn label(&self) -> String {
        match self {
            HeatMethod::BothCameras => "both".into(),
            HeatMethod::OneCamera(c) => format!("cam{c}"),
            HeatMethod::Unseen => "none".into(),
        }
    }
}

/// One heat-map cell: the mean height error (actual − measured) of a few readings there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeatCell {
    pub x_cm: f64,
    pub y_cm: f64,
    pub method: HeatMethod,
    /// NaN where no camera saw the whole target.
    pub error_cm: f64,
    /// One camera only: the error without the off-axis area correction
    /// (`depth::on_axis_area`), to show what it is worth; NaN otherwise.
    pub uncorrected_error_cm: f64,
}

impl Report {
    /// RMS and largest heading error, degrees.
    pub fn heading_error_deg(&self) -> (f64, f64) {
        let n = self.heading.len().max(1) as f64;
        let rms = (self.heading.iter().map(|h| h.3 * h.3).sum::<f64>() / n).sqrt();
        (
            rms,
            self.heading.iter().map(|h| h.3.abs()).fold(0.0, f64::max),
        )
    }
}

/// The target in a frame: its grey-level area (px) and its coverage centroid.
///
/// Two weightings of the same blob, each where it is best. The **area** is the grey-level area
/// Σ(pixel − background)/contrast: every pixel weighs its full brightness, so pixel noise
/// hardly moves it, and the ball's shading is the same at every height for a camera looking
/// down (a pixel count is about six times noisier). The **centroid** uses coverage weights
/// (`Weighting::Coverage`) saturating `FULL_ABOVE_BACKGROUND` levels above the background —
/// below the ball's darkest part, its rim — i.e. the silhouette with sub-pixel edges: grey-level
/// weights pull it towards the lit top of the ball, which the two cameras see from different
/// sides, a 2–3 mm height bias when triangulating.
fn measure(img: &GrayImage<u8>, contrast: f64) -> Option<(f64, Point2<f64>)> {
    let bg = background(img)?;
    // Σ(pixel − background) over the blob's box widened by 2 px: the dim edge pixels below the
    // threshold count too (they are a larger share of a small, far blob), and the background's
    // noise averages out.
    let b = target_blob(img, Weighting::Binary)?;
    let (w, h) = (img.width(), img.height());
    let (x0, y0) = (b.bbox.x0.saturating_sub(2), b.bbox.y0.saturating_sub(2));
    let (x1, y1) = ((b.bbox.x1 + 2).min(w - 1), (b.bbox.y1 + 2).min(h - 1));
    let view = img.view();
    let mut sum = 0.0;
    for y in y0..=y1 {
        sum += view.row(y)[x0 as usize..=x1 as usize]
            .iter()
            .map(|&p| p as f64 - bg as f64)
            .sum::<f64>();
    }
    let area = sum / contrast;
    let (x, y) = target_blob(img, coverage(img, bg)?)?.best_centroid_px();
    Some((area, Point2::new(x, y)))
}

/// The background level: the histogram's mode.
fn background(img: &GrayImage<u8>) -> Option<u32> {
    Histogram::of(&img.view()).mode().ok()
}

/// The blob threshold: the histogram's background knee, at least 12 levels above it.
fn threshold(img: &GrayImage<u8>, bg: u32) -> Option<u32> {
    Some(
        Histogram::of(&img.view())
            .threshold::<u8>(ThresholdMethod::Triangle)
            .ok()?
            .max(bg + 12)
            .min(254),
    )
}

/// Coverage weights saturating `FULL_ABOVE_BACKGROUND` above the background.
fn coverage(img: &GrayImage<u8>, bg: u32) -> Option<Weighting> {
    Some(Weighting::Coverage {
        background: bg,
        full: (bg + FULL_ABOVE_BACKGROUND).max(threshold(img, bg)? + 1),
    })
}

/// The largest blob (the target) with the given weights.
fn target_blob(img: &GrayImage<u8>, weighting: Weighting) -> Option<stereoscope_vision::Blob> {
    let bg = background(img)?;
    let mut ex = Extractor::new(ExtractConfig {
        weighting,
        min_area_px: 10,
        ..Default::default()
    });
    let blobs = ex.extract(img.view(), threshold(img, bg)?, &[]).ok()?;
    // A blob cut by the frame's edge is no measurement of the target (the live system flags it).
    blobs
        .iter()
        .max_by_key(|b| b.area_px())
        .copied()
        .filter(|b| {
            !b.flags
                .contains(stereoscope_vision::BlobFlags::TOUCHES_BORDER)
        })
}

/// The target's coverage centroid, major-axis angle (degrees CCW on screen, PAR-corrected) and
/// roundness in a frame.
fn measure_axis(img: &GrayImage<u8>, par: f64) -> Option<(Point2<f64>, f64, f64)> {
    let b = target_blob(img, coverage(img, background(img)?)?)?;
    let (x, y) = b.best_centroid_px();
    let shape = b.best_central().axis_shape(par);
    Some((Point2::new(x, y), shape.angle_deg, shape.roundness()))
}

struct Lab {
    truth: Vec<Camera>,
    calibrated: Vec<Camera>,
    opts: ReproduceOptions,
    rng: SplitMix64,
}

impl Lab {
    fn frame(
        &mut self,
        cam: usize,
        x: f64,
        y: f64,
        height_m: f64,
    ) -> anyhow::Result<GrayImage<u8>> {
        self.frame_heading(cam, x, y, height_m, 30.0)
    }

    fn frame_heading(
        &mut self,
        cam: usize,
        x: f64,
        y: f64,
        height_m: f64,
        heading_deg: f64,
    ) -> anyhow::Result<GrayImage<u8>> {
        let state = State {
            position: Point3::new(x, y, height_m + BALL_RADIUS_M),
            heading_deg,
        };
        let scene = Scene {
            targets: vec![Target {
                shape: Shape::DoubleSphere {
                    radius_m: BALL_RADIUS_M,
                },
                world_from_body: state.world_from_body(),
                contrast: self.opts.contrast,
            }],
            background: Background {
                level: BACKGROUND,
                gradient_per_px: (0.0, 0.0),
            },
            ..Scene::default()
        };
        let ro = RenderOptions {
            samples: 4,
            blur_sigma_px: self.opts.blur_sigma_px,
            noise_sigma: self.opts.noise_sigma,
            shot_noise_gain: None,
            seed: self.rng.next_u64(),
        };
        Ok(render_u8(&self.truth[cam], &scene, &ro)?.image)
    }
}

/// Board poses for calibration: tilted at several heights, then flat on the floor (last).
fn board_poses(grid: &DotGrid, rng: &mut SplitMix64) -> Vec<Isometry3<f64>> {
    let half = Vector3::new(
        (grid.cols - 1) as f64 * grid.spacing / 2.0,
        (grid.rows - 1) as f64 * grid.spacing / 2.0,
        0.0,
    );
    let mut poses = Vec::new();
    for _ in 0..TILTED_VIEWS {
        let centre = Vector3::new(
            rng.range(-0.12, 0.12),
            rng.range(-0.1, 0.1),
            rng.range(TILTED_HEIGHT_M.0, TILTED_HEIGHT_M.1),
        );
        let axis_angle = rng.range(0.0, std::f64::consts::TAU);
        let axis =
            nalgebra::Unit::new_normalize(Vector3::new(axis_angle.cos(), axis_angle.sin(), 0.0));
        let tilt = UnitQuaternion::from_axis_angle(&axis, rng.range(15.0, 35.0).to_radians());
        let yaw = UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            rng.range(-20.0, 20.0).to_radians(),
        );
        let rot = tilt * yaw;
        poses.push(Isometry3::from_parts(
            Translation3::from(centre - rot * half),
            rot,
        ));
    }
    // On the floor: the first placement is the world frame (centred, square to the world
    // axes); the others are moved and turned, and all of them together fix the floor's plane.
    for (dx, dy, yaw_deg) in FLOOR_PLACEMENTS {
        let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians());
        poses.push(Isometry3::from_parts(
            Translation3::new(dx, dy, 0.0) * Translation3::from(-(rot * half)),
            rot,
        ));
    }
    poses
}

/// Where the board lies on the floor for calibration: offset (m) and turn (°); the first one
/// defines the world frame.
const FLOOR_PLACEMENTS: [(f64, f64, f64); 4] = [
    (0.0, 0.0, 0.0),
    (0.2, 0.15, 12.0),
    (-0.2, 0.12, -9.0),
    (0.05, -0.18, 5.0),
];

/// The world frame from the board lying on the floor in several placements (`cam0_from_target`
/// of each, the first defining the origin and the x axis): the floor plane is the mean of the
/// placements' planes, so one placement's small tilt does not tilt every height.
fn world_from_floor(placements: &[Isometry3<f64>]) -> Option<Isometry3<f64>> {
    let first = placements.first()?;
    let n = placements
        .iter()
        .fold(Vector3::zeros(), |a, p| a + p.rotation * Vector3::z())
        .normalize();
    let d = placements
        .iter()
        .map(|p| n.dot(&p.translation.vector))
        .sum::<f64>()
        / placements.len() as f64;
    // Origin: the first placement's origin dropped onto the mean plane; x: its x axis made
    // perpendicular to the mean normal.
    let o = first.translation.vector - n * (n.dot(&first.translation.vector) - d);
    let x =
        (first.rotation * Vector3::x() - n * n.dot(&(first.rotation * Vector3::x()))).normalize();
    let y = n.cross(&x);
    let rot =
        nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, n]));
    Some(Isometry3::from_parts(
        Translation3::from(o),
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// Calibrates both cameras from rendered views of the board ([`BOARD`]), as a user would.
fn calibrate_lab(
    truth: &[Camera],
    opts: &ReproduceOptions,
    rng: &mut SplitMix64,
) -> anyhow::Result<(Vec<Camera>, f64, usize)> {
    let grid = DotGrid::new(BOARD.0, BOARD.1, BOARD.2)?;
    let poses = board_poses(&grid, rng);
    let target: Vec<Point3<f64>> = (0..grid.len()).map(|i| grid.point(i)).collect();
    let mut views = Vec::new();
    let mut flat_views = Vec::new();
    let first_flat = poses.len() - FLOOR_PLACEMENTS.len();
    for (k, world_from_target) in poses.iter().enumerate() {
        let mut obs = Vec::new();
        let mut seen_by = 0;
        for (c, cam) in truth.iter().enumerate() {
            let mut img = render_grid(
                cam,
                &(cam.cam_from_world * world_from_target),
                &grid,
                BACKGROUND,
                BACKGROUND + opts.contrast,
                4,
            )?;
            add_gaussian_noise(&mut img, opts.noise_sigma, rng);
            if let Ok(dots) = detect(img.view(), &grid) {
                seen_by += 1;
                obs.extend(dots.into_iter().map(|(i, px)| (c, i, px)));
            }
        }
        // A tilted view seen by one camera still helps that camera's intrinsics; the views on
        // the floor, which fix the world frame, must be seen by both (the first one at least).
        let flat = k >= first_flat;
        if k == first_flat && seen_by < truth.len() {
            return Err(anyhow!(
                "the board lying at the floor's centre was not found in both cameras"
            ));
        }
        if seen_by == truth.len() || (!flat && seen_by > 0) {
            if flat {
                flat_views.push(views.len());
            }
            views.push(RigView {
                target: target.clone(),
                observations: obs,
            });
        }
    }
    let sizes: Vec<(u32, u32)> = truth
        .iter()
        .map(|c| (c.intrinsics.width, c.intrinsics.height))
        .collect();
    let cal = calibrate_rig(&sizes, &views, DistortionModel::Radial)
        .context("calibrating the lab's cameras")?;
    let placements: Vec<Isometry3<f64>> = flat_views
        .iter()
        .map(|&v| cal.cam0_from_target[v])
        .collect();
    let cam0_from_world =
        world_from_floor(&placements).ok_or_else(|| anyhow!("no floor placement was seen"))?;
    let cams = cal
        .cameras
        .iter()
        .map(|c| Camera {
            intrinsics: c.intrinsics,
            distortion: c.distortion,
            cam_from_world: c.cam_from_cam0 * cam0_from_world,
        })
        .collect();
    Ok((cams, cal.rms_px, views.len()))
}

/// The thesis's sweep: heights 2, 12, … cm (`heights` of them), `readings` measured heights
/// (metres) each, one table row per height.
fn sweep(
    heights: usize,
    readings: usize,
    mut read: impl FnMut(f64) -> anyhow::Result<f64>,
) -> anyhow::Result<Vec<Row>> {
    (0..heights)
        .map(|k| {
            let h = 0.02 + 0.10 * k as f64;
            let values = (0..readings)
                .map(|_| read(h))
                .collect::<anyhow::Result<Vec<f64>>>()?;
            Ok(row(h, &values))
        })
        .collect()
}

impl Experiment {
    fn new(
        key: &'static str,
        title: &'static str,
        thesis_table: &'static str,
        thesis_rms_cm: f64,
        rows: Vec<Row>,
    ) -> Self {
        let rms_cm = rms(&rows);
        Experiment {
            key,
            title,
            thesis_table,
            thesis_rms_cm,
            rows,
            rms_cm,
        }
    }
}

fn row(actual_m: f64, readings: &[f64]) -> Row {
    let n = readings.len().max(1) as f64;
    let mean = readings.iter().sum::<f64>() / n;
    let sd = (readings.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    Row {
        actual_cm: actual_m * 100.0,
        mean_cm: mean * 100.0,
        sd_cm: sd * 100.0,
        error_cm: (actual_m - mean) * 100.0,
    }
}

fn rms(rows: &[Row]) -> f64 {
    (rows.iter().map(|r| r.error_cm * r.error_cm).sum::<f64>() / rows.len().max(1) as f64).sqrt()
}

/// Runs the experiments (no files written): see [`write`] for the outputs.
pub fn run(opts: &ReproduceOptions) -> anyhow::Result<Report> {
    let rig = match &opts.rig {
        None => Rig::from_toml(THESIS_LAB).map_err(|e| anyhow!("the built-in thesis lab: {e}"))?,
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("{}: cannot read", path.display()))?;
            let rig = Rig::from_toml(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?;
            if rig.cameras.len() < 2 {
                return Err(anyhow!(
                    "{}: the experiments need two cameras, the rig has {}",
                    path.display(),
                    rig.cameras.len()
                ));
            }
            rig
        }
    };
    let truth: Vec<Camera> = rig.cameras().into_iter().take(2).collect();
    let mut rng = SplitMix64::new(opts.seed);
    let (calibrated, calibration_rms_px, calibration_views) =
        calibrate_lab(&truth, opts, &mut rng)?;
    let mut lab = Lab {
        truth: truth.clone(),
        calibrated,
        opts: opts.clone(),
        rng,
    };
    // Where the target stands: under camera 0 for one camera; for two, between the cameras
    // and near the corner of what both see at the top height.
    let under0 = truth[0].position_world();
    let cam0_height = lab.calibrated[0].position_world().z;
    // Fit the area models from stands at 7–197 cm (between the test heights), as many readings
    // each as the experiments take.
    let mut samples = Vec::new();
    let mut area_samples = Vec::new();
    for k in 0..20 {
        let h = 0.07 + 0.10 * k as f64;
        let mut area = 0.0;
        for _ in 0..opts.readings {
            let img = lab.frame(0, under0.x, under0.y, h)?;
            let (a, c) = measure(&img, opts.contrast)
                .ok_or_else(|| anyhow!("no target found at {:.0} cm while fitting", h * 100.0))?;
            area += on_axis_area(&lab.calibrated[0], c, a)? / opts.readings as f64;
        }
        samples.push((area, cam0_height - (h + BALL_RADIUS_M)));
        area_samples.push((h * 100.0, area));
    }
    let fit_two = fit_two_parameter(&samples)?;
    let fit_three = fit_three_parameter(&samples)?;
    let mut experiments = Vec::new();
    for (key, title, table, thesis_rms, fit) in [
        (
            "one_camera_two_parameter",
            "One camera, two-parameter area model",
            "4.1",
            1.90,
            &fit_two,
        ),
        (
            "one_camera_three_parameter",
            "One camera, three-parameter area model",
            "4.2",
            0.79,
            &fit_three,
        ),
    ] {
        let rows = sweep(21, opts.readings, |h| {
            let img = lab.frame(0, under0.x, under0.y, h)?;
            let (area, c) = measure(&img, opts.contrast)
                .ok_or_else(|| anyhow!("no target found at {:.0} cm", h * 100.0))?;
            let area = on_axis_area(&lab.calibrated[0], c, area)?;
            let d = fit.model.depth_from_area(area, fit.range)?;
            Ok(point_from_depth(&lab.calibrated[0], c, d.depth)?.z - BALL_RADIUS_M)
        })?;
        experiments.push(Experiment::new(key, title, table, thesis_rms, rows));
    }
    for (key, title, table, thesis_rms, x, y) in [
        (
            "two_cameras_centre",
            "Two cameras, board centre",
            "4.3",
            0.6290,
            0.0,
            0.0,
        ),
        (
            "two_cameras_corner",
            "Two cameras, near the corner of the shared view",
            "4.4",
            1.0173,
            0.20,
            0.15,
        ),
    ] {
        let rows = sweep(16, opts.readings, |h| {
            let mut obs = Vec::new();
            for c in 0..2 {
                let img = lab.frame(c, x, y, h)?;
                let (_, px) = measure(&img, opts.contrast)
                    .ok_or_else(|| anyhow!("camera {c} found no target at {:.0} cm", h * 100.0))?;
                obs.push(Observation {
                    camera: c,
                    pixel: px,
                });
            }
            Ok(triangulate(&lab.calibrated, &obs)?.point_world.z - BALL_RADIUS_M)
        })?;
        experiments.push(Experiment::new(key, title, table, thesis_rms, rows));
    }
    // Heading: the double ball at the centre, six heights, headings every 10°, both cameras.
    let mut heading = Vec::new();
    for k in 0..6 {
        let h = 0.02 + 0.30 * k as f64;
        for step in 0..18 {
            let truth_deg = 10.0 * step as f64 + 3.0;
            let mut views = Vec::new();
            let mut point_obs = Vec::new();
            for c in 0..2 {
                let img = lab.frame_heading(c, 0.0, 0.0, h, truth_deg)?;
                let par = lab.calibrated[c].intrinsics.par();
                let (px, angle, roundness) = measure_axis(&img, par)
                    .ok_or_else(|| anyhow!("camera {c} found no target for the heading"))?;
                views.push(AxisView {
                    camera: c,
                    centroid_px: px,
                    angle_deg: angle,
                    directed: false,
                    weight: (1.0 - roundness).max(1e-3),
                });
                point_obs.push(Observation {
                    camera: c,
                    pixel: px,
                });
            }
            let p = triangulate(&lab.calibrated, &point_obs)?.point_world;
            let fused = fuse(&lab.calibrated, &views, &p)
                .ok_or_else(|| anyhow!("no heading at {:.0} cm", h * 100.0))?;
            let err = stereoscope_numeric::angle::wrap_half_turn_deg(fused.heading_deg - truth_deg);
            heading.push((h * 100.0, truth_deg, fused.heading_deg, err));
        }
    }
    // The height error over the whole board, measured as the live fusion would.
    let heat = heat_map(&mut lab, &fit_three, opts)?;
    // The same four experiments at other noise levels (fewer readings, no further sweep).
    let mut noise = Vec::new();
    if opts.noise_sweep {
        for sigma in [0.0, 1.0, 2.0, 4.0, 8.0] {
            let sub = ReproduceOptions {
                noise_sigma: sigma,
                readings: opts.readings.min(10),
                noise_sweep: false,
                plots: false,
                ..opts.clone()
            };
            let r = run(&sub)?;
            let mut rms = [0.0; 4];
            for (slot, e) in rms.iter_mut().zip(&r.experiments) {
                *slot = e.rms_cm;
            }
            noise.push((sigma, rms));
        }
    }
    Ok(Report {
        calibration_rms_px,
        calibration_views,
        experiments,
        fit_two,
        fit_three,
        area_samples,
        heading,
        heat,
        noise,
    })
}

/// The height error over the whole board at [`HEAT_HEIGHT_M`] ([`HeatCell`]).
fn heat_map(
    lab: &mut Lab,
    fit: &DepthFit,
    opts: &ReproduceOptions,
) -> anyhow::Result<Vec<HeatCell>> {
    let n = opts.readings.clamp(1, 5);
    let (cols, rows) = (
        (BOARD_SIZE_M.0 / HEAT_CELL_M).floor() as i32 / 2,
        (BOARD_SIZE_M.1 / HEAT_CELL_M).floor() as i32 / 2,
    );
    let mut cells = Vec::new();
    for iy in -rows..=rows {
        for ix in -cols..=cols {
            let (x, y) = (HEAT_CELL_M * ix as f64, HEAT_CELL_M * iy as f64);
            // Each reading: how it was measured, the height, and (one camera) the height
            // without the off-axis correction.
            let mut readings: Vec<(HeatMethod, f64, f64)> = Vec::new();
            for _ in 0..n {
                let mut seen = Vec::new();
                for c in 0..2 {
                    let img = lab.frame(c, x, y, HEAT_HEIGHT_M)?;
                    if let Some(m) = measure(&img, opts.contrast) {
                        seen.push((c, m));
                    }
                }
                readings.push(match seen.as_slice() {
                    [(c0, (_, p0)), (c1, (_, p1))] => {
                        let obs = [
                            Observation {
                                camera: *c0,
                                pixel: *p0,
                            },
                            Observation {
                                camera: *c1,
                                pixel: *p1,
                            },
                        ];
                        let z = triangulate(&lab.calibrated, &obs)?.point_world.z;
                        (HeatMethod::BothCameras, z, f64::NAN)
                    }
                    [(c, (area, p))] => {
                        let cam = &lab.calibrated[*c];
                        let corrected = on_axis_area(cam, *p, *area)?;
                        let d = fit.model.depth_from_area(corrected, fit.range)?;
                        let d_raw = fit.model.depth_from_area(*area, fit.range)?;
                        (
                            HeatMethod::OneCamera(*c),
                            point_from_depth(cam, *p, d.depth)?.z,
                            point_from_depth(cam, *p, d_raw.depth)?.z,
                        )
                    }
                    _ => (HeatMethod::Unseen, f64::NAN, f64::NAN),
                });
            }
            // Noise can hide a target at the edge of a view in some readings: the cell is
            // measured the way most of its readings were, from those readings.
            let count = |m: HeatMethod| readings.iter().filter(|r| r.0 == m).count();
            let method = [
                HeatMethod::BothCameras,
                HeatMethod::OneCamera(0),
                HeatMethod::OneCamera(1),
                HeatMethod::Unseen,
            ]
            .into_iter()
            .max_by_key(|&m| count(m))
            .unwrap_or(HeatMethod::Unseen);
            let used: Vec<&(HeatMethod, f64, f64)> =
                readings.iter().filter(|r| r.0 == method).collect();
            let err = |pick: fn(&(HeatMethod, f64, f64)) -> f64| {
                let mean = used.iter().map(|r| pick(r)).sum::<f64>() / used.len().max(1) as f64;
                (HEAT_HEIGHT_M - (mean - BALL_RADIUS_M)) * 100.0
            };
            let (error_cm, uncorrected_error_cm) = match method {
                HeatMethod::BothCameras => (err(|r| r.1), f64::NAN),
                HeatMethod::OneCamera(_) => (err(|r| r.1), err(|r| r.2)),
                HeatMethod::Unseen => (f64::NAN, f64::NAN),
            };
            cells.push(HeatCell {
                x_cm: x * 100.0,
                y_cm: y * 100.0,
                method,
                error_cm,
                uncorrected_error_cm,
            });
        }
    }
    Ok(cells)
}

/// RMS and largest absolute value of the finite values.
fn rms_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64, usize)> {
    let v: Vec<f64> = values.filter(|e| e.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let rms = (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt();
    Some((rms, v.iter().map(|e| e.abs()).fold(0.0, f64::max), v.len()))
}

fn table_md(e: &Experiment) -> String {
    let mut s = format!("# {} (thesis Table {})\n\n", e.title, e.thesis_table);
    s.push_str("| Actual height (cm) | Measured height (cm), mean | Standard deviation (cm) | Error (cm) |\n|---|---|---|---|\n");
    for r in &e.rows {
        let _ = writeln!(
            s,
            "| {:.1} | {:.2} | {:.2} | {:.2} |",
            r.actual_cm, r.mean_cm, r.sd_cm, r.error_cm
        );
    }
    let _ = writeln!(
        s,
        "\nRoot-mean-square error: **{:.3} cm** (thesis: {:.2} cm; goal: {:.3} cm).",
        e.rms_cm,
        e.thesis_rms_cm,
        e.goal_cm()
    );
    s
}

fn table_csv(e: &Experiment) -> String {
    let mut s =
        String::from("actual_height_cm,measured_height_cm,standard_deviation_cm,error_cm\n");
    for r in &e.rows {
        let _ = writeln!(
            s,
            "{:.1},{:.4},{:.4},{:.4}",
            r.actual_cm, r.mean_cm, r.sd_cm, r.error_cm
        );
    }
    s
}

/// The summary table: the thesis's RMS next to ours.
pub fn summary_md(r: &Report, opts: &ReproduceOptions) -> String {
    let mut s = String::from("# The thesis's experiments, reproduced\n\n");
    let _ = writeln!(
        s,
        "Setting: 320 × 240 cameras with PAR 0.86, Gaussian noise σ = {} grey levels, defocus blur σ = {} px, target {} levels above a background of {}; {} readings per height; seed {}. Calibration: {} views of a {} × {} dot grid ({} cm), RMS reprojection error {:.3} px.\n",
        opts.noise_sigma,
        opts.blur_sigma_px,
        opts.contrast,
        BACKGROUND,
        opts.readings,
        opts.seed,
        r.calibration_views,
        BOARD.0,
        BOARD.1,
        BOARD.2 * 100.0,
        r.calibration_rms_px
    );
    s.push_str("| experiment | thesis table | thesis RMS (cm) | ours RMS (cm) | goal: ⅕ of the thesis (cm) | met |\n|---|---|---|---|---|---|\n");
    for e in &r.experiments {
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {:.3} | {:.3} | {} |",
            e.title,
            e.thesis_table,
            e.thesis_rms_cm,
            e.rms_cm,
            e.goal_cm(),
            if e.rms_cm <= e.goal_cm() { "yes" } else { "no" }
        );
    }
    let (h_rms, h_max) = r.heading_error_deg();
    let _ = writeln!(
        s,
        "\nHeading of the double ball (an axis: modulo 180°), both cameras, {} readings at the centre, 2–152 cm, headings every 10°: RMS error **{:.3}°**, largest {:.2}° (goal ≤ 1° RMS: {}). The thesis did not measure it.",
        r.heading.len(),
        h_rms,
        h_max,
        if h_rms <= 1.0 { "met" } else { "not met" }
    );
    let both = rms_max(
        r.heat
            .iter()
            .filter(|c| c.method == HeatMethod::BothCameras)
            .map(|c| c.error_cm),
    );
    let one = rms_max(
        r.heat
            .iter()
            .filter(|c| matches!(c.method, HeatMethod::OneCamera(_)))
            .map(|c| c.error_cm),
    );
    let one_raw = rms_max(r.heat.iter().map(|c| c.uncorrected_error_cm));
    let unseen = r
        .heat
        .iter()
        .filter(|c| c.method == HeatMethod::Unseen)
        .count();
    let _ = write!(
        s,
        "\nHeight error across the whole {:.2} × {:.2} m board at {:.0} cm, measured as the live fusion does ({} cells, {:.0} cm apart; `heat_map.csv`, `heat_map.png`):",
        BOARD_SIZE_M.0,
        BOARD_SIZE_M.1,
        HEAT_HEIGHT_M * 100.0,
        r.heat.len(),
        HEAT_CELL_M * 100.0
    );
    if let Some((rms, worst, k)) = both {
        let _ = write!(
            s,
            " both cameras in {k} cells, RMS {rms:.3} cm, largest {worst:.3} cm;"
        );
    }
    if let (Some((rms, worst, k)), Some((raw, _, _))) = (one, one_raw) {
        let _ = write!(
            s,
            " one camera (depth from area, three parameters) in {k} cells, RMS {rms:.3} cm, largest {worst:.3} cm ({raw:.3} cm without the off-axis area correction);"
        );
    }
    let _ = writeln!(s, " {unseen} cells seen whole by neither camera.");
    if !r.noise.is_empty() {
        s.push_str("\nRMS (cm) as the pixel noise grows (other settings as above, at most 10 readings per height):\n\n| noise σ (grey levels) | one camera, 2 parameters | one camera, 3 parameters | two cameras, centre | two cameras, corner |\n|---|---|---|---|---|\n");
        for (sigma, rms) in &r.noise {
            let _ = writeln!(
                s,
                "| {sigma} | {:.3} | {:.3} | {:.3} | {:.3} |",
                rms[0], rms[1], rms[2], rms[3]
            );
        }
    }
    s
}

fn plot_measured(path: &Path, e: &Experiment) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let root = BitMapBackend::new(path, (640, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let top = e
        .rows
        .iter()
        .map(|r| r.actual_cm.max(r.mean_cm))
        .fold(0.0, f64::max)
        + 10.0;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("{} (RMS {:.3} cm)", e.title, e.rms_cm),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0f64..top, 0f64..top)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("actual height (cm)")
        .y_desc("measured height (cm)")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(LineSeries::new([(0.0, 0.0), (top, top)], &BLACK))
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(
            e.rows
                .iter()
                .map(|r| Circle::new((r.actual_cm, r.mean_cm), 3, RED.filled())),
        )
        .map_err(|e| anyhow!("{e}"))?;
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

fn plot_area(path: &Path, r: &Report, cam0_height_cm: f64) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let root = BitMapBackend::new(path, (640, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let max_area = r.area_samples.iter().map(|s| s.1).fold(0.0, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Grey-level area vs height, with the fitted models",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..210f64, 0f64..max_area)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("height (cm)")
        .y_desc("area (px)")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(
            r.area_samples
                .iter()
                .map(|&(h, a)| Circle::new((h, a), 3, RED.filled())),
        )
        .map_err(|e| anyhow!("{e}"))?;
    for (fit, colour) in [(&r.fit_two, BLUE), (&r.fit_three, BLACK)] {
        let curve = (0..=200).map(|h| {
            let d = cam0_height_cm / 100.0 - (h as f64 / 100.0 + BALL_RADIUS_M);
            (h as f64, fit.model.area_at(d))
        });
        chart
            .draw_series(LineSeries::new(curve, &colour))
            .map_err(|e| anyhow!("{e}"))?;
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

fn plot_heat(path: &Path, r: &Report) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let (hx, hy) = (BOARD_SIZE_M.0 * 50.0, BOARD_SIZE_M.1 * 50.0);
    let root = BitMapBackend::new(path, (1000, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let limit = r
        .heat
        .iter()
        .map(|h| h.error_cm.abs())
        .filter(|e| e.is_finite())
        .fold(0.05, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "Height error (cm) at {:.0} cm over the board; colour range ±{limit:.2} cm; bold: both cameras, plain: one camera, grey: neither",
                HEAT_HEIGHT_M * 100.0
            ),
            ("sans-serif", 15),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-hx..hx, -hy..hy)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("x (cm)")
        .y_desc("y (cm)")
        .disable_mesh()
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    let half = HEAT_CELL_M * 50.0;
    chart
        .draw_series(r.heat.iter().map(|c| {
            let colour = if c.error_cm.is_finite() {
                let t = (c.error_cm / limit).clamp(-1.0, 1.0);
                // Blue below zero, red above, white at zero.
                let (rr, gg, bb) = if t >= 0.0 {
                    (255.0, 255.0 * (1.0 - t), 255.0 * (1.0 - t))
                } else {
                    (255.0 * (1.0 + t), 255.0 * (1.0 + t), 255.0)
                };
                RGBColor(rr as u8, gg as u8, bb as u8)
            } else {
                RGBColor(160, 160, 160)
            };
            Rectangle::new(
                [
                    (c.x_cm - half, c.y_cm - half),
                    (c.x_cm + half, c.y_cm + half),
                ],
                colour.filled(),
            )
        }))
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(r.heat.iter().filter(|c| c.error_cm.is_finite()).map(|c| {
            let style = if c.method == HeatMethod::BothCameras {
                ("sans-serif", 12).into_font().style(FontStyle::Bold)
            } else {
                ("sans-serif", 12).into_font()
            };
            Text::new(
                format!("{:+.2}", c.error_cm),
                (c.x_cm - 6.0, c.y_cm + 2.0),
                style,
            )
        }))
        .map_err(|e| anyhow!("{e}"))?;
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Writes the tables (Markdown and CSV), the plots and the summary to `opts.out`, all or
/// nothing: into a fresh folder beside it, renamed into place at the end.
pub fn write(r: &Report, opts: &ReproduceOptions) -> anyhow::Result<()> {
    let out = &opts.out;
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let staging = parent.join(format!(
        ".{}.partial-{}",
        out.file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("reproduce"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&staging);
    std::fs::create_dir_all(&staging)
        .with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    let result = (|| -> anyhow::Result<()> {
        for e in &r.experiments {
            std::fs::write(staging.join(format!("{}.md", e.key)), table_md(e))?;
            std::fs::write(staging.join(format!("{}.csv", e.key)), table_csv(e))?;
        }
        std::fs::write(staging.join("summary.md"), summary_md(r, opts))?;
        let mut h = String::from("height_cm,true_heading_deg,measured_heading_deg,error_deg\n");
        for (hc, t, m, e) in &r.heading {
            let _ = writeln!(h, "{hc:.1},{t:.1},{m:.4},{e:.4}");
        }
        std::fs::write(staging.join("heading.csv"), h)?;
        let mut hm = String::from("x_cm,y_cm,measured_by,mean_error_cm,uncorrected_error_cm\n");
        for c in &r.heat {
            let _ = writeln!(
                hm,
                "{:.1},{:.1},{},{:.4},{:.4}",
                c.x_cm,
                c.y_cm,
                c.method.label(),
                c.error_cm,
                c.uncorrected_error_cm
            );
        }
        std::fs::write(staging.join("heat_map.csv"), hm)?;
        if opts.plots {
            let font = std::fs::read(FONT).with_context(|| {
                format!(
                    "cannot read the font {FONT} for the plots (Debian package fonts-dejavu-core)"
                )
            })?;
            let font: &'static [u8] = Box::leak(font.into_boxed_slice());
            plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, font)
                .map_err(|_| anyhow!("{FONT} is not a usable font"))?;
            for e in &r.experiments {
                plot_measured(&staging.join(format!("{}.png", e.key)), e)?;
            }
            let h0 = Rig::from_toml(THESIS_LAB)
                .map_err(|e| anyhow!("{e}"))?
                .cameras[0]
                .camera
                .position_world()
                .z
                * 100.0;
            plot_area(&staging.join("area_vs_height.png"), r, h0)?;
            plot_heat(&staging.join("heat_map.png"), r)?;
        }
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e.context(format!(
            "{}: writing the results failed; nothing was written there",
            out.display()
        )));
    }
    if out.exists() {
        std::fs::remove_dir_all(out)
            .with_context(|| format!("{}: cannot replace the old results", out.display()))?;
    }
    std::fs::rename(&staging, out)
        .with_context(|| format!("{}: cannot move the results into place", out.display()))?;
    Ok(())
}

/// Reads a table CSV written by [`write`] (for checks).
pub fn read_table(path: &Path) -> anyhow::Result<Vec<Row>> {
    let rows = csvin::read(
        path,
        &[
            "actual_height_cm",
            "measured_height_cm",
            "standard_deviation_cm",
            "error_cm",
        ],
    )?;
    rows.iter()
        .map(|r| {
            Ok(Row {
                actual_cm: r
                    .number(0, "actual_height_cm")
                    .map_err(anyhow::Error::msg)?,
                mean_cm: r
                    .number(1, "measured_height_cm")
                    .map_err(anyhow::Error::msg)?,
                sd_cm: r
                    .number(2, "standard_deviation_cm")
                    .map_err(anyhow::Error::msg)?,
                error_cm: r.number(3, "error_cm").map_err(anyhow::Error::msg)?,
            })
        })
        .collect()
}
