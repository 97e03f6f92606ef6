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
use stereoscope_imageio::csv;
use stereoscope_numeric::SplitMix64;
use stereoscope_render::{Background, RenderOptions, Scene, Shape, State, Target, render_u8};
use stereoscope_rig::Rig;
use stereoscope_vision::raster::add_gaussian_noise;
use stereoscope_vision::{
    ExtractConfig, Extractor, GrayImage, Histogram, ThresholdMethod, Weighting,
};

/// The thesis's lab as shipped in `deploy/rigs/thesis-lab.toml`.
pub const THESIS_LAB: &str = include_str!("../../../../deploy/rigs/thesis-lab.toml");
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
    /// Say on standard error which step is running (the whole run takes minutes).
    pub progress: bool,
}

impl ReproduceOptions {
    fn step(&self, what: &str) {
        if self.progress {
            eprintln!("reproduce: {what}");
        }
    }

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
            progress: false,
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
mod heat;
mod lab;
mod measure;
mod output;

pub(crate) use heat::*;
pub(crate) use lab::*;
pub(crate) use measure::*;
pub use output::*;

/// Runs the experiments (no files written): see [`write()`] for the outputs.
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
    opts.step("calibrating both cameras from rendered dot-grid views");
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
        opts.step(&format!("{title}: 21 heights × {} readings", opts.readings));
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
        opts.step(&format!("{title}: 16 heights × {} readings", opts.readings));
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
    opts.step("the height error over the whole board");
    let heat = heat_map(&mut lab, &fit_three, opts)?;
    // The same four experiments at other noise levels (fewer readings, no further sweep).
    let mut noise = Vec::new();
    if opts.noise_sweep {
        for sigma in [0.0, 1.0, 2.0, 4.0, 8.0] {
            opts.step(&format!("the four experiments again at noise σ = {sigma}"));
            let sub = ReproduceOptions {
                progress: false,
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
