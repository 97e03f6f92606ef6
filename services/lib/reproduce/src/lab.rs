//! The simulated lab: its cameras, the dot-grid board's poses, the joint calibration and the
//! world from the board on the floor (thesis §2.2.3), and the height sweeps of the experiments
//! (Tables 4.1–4.4).

use crate::*;

pub(crate) struct Lab {
    pub(crate) truth: Vec<Camera>,
    pub(crate) calibrated: Vec<Camera>,
    pub(crate) opts: ReproduceOptions,
    pub(crate) rng: SplitMix64,
}

impl Lab {
    pub(crate) fn frame(
        &mut self,
        cam: usize,
        x: f64,
        y: f64,
        height_m: f64,
    ) -> anyhow::Result<GrayImage<u8>> {
        self.frame_heading(cam, x, y, height_m, 30.0)
    }

    pub(crate) fn frame_heading(
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
            tilt: nalgebra::UnitQuaternion::identity(),
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
pub(crate) fn board_poses(grid: &DotGrid, rng: &mut SplitMix64) -> Vec<Isometry3<f64>> {
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
pub(crate) const FLOOR_PLACEMENTS: [(f64, f64, f64); 4] = [
    (0.0, 0.0, 0.0),
    (0.2, 0.15, 12.0),
    (-0.2, 0.12, -9.0),
    (0.05, -0.18, 5.0),
];

/// The world frame from the board lying on the floor in several placements (`cam0_from_target`
/// of each, the first defining the origin and the x axis): the floor plane is the mean of the
/// placements' planes, so one placement's small tilt does not tilt every height.
pub(crate) fn world_from_floor(placements: &[Isometry3<f64>]) -> Option<Isometry3<f64>> {
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
pub(crate) fn calibrate_lab(
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
pub(crate) fn sweep(
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
    pub(crate) fn new(
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

pub(crate) fn row(actual_m: f64, readings: &[f64]) -> Row {
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

pub(crate) fn rms(rows: &[Row]) -> f64 {
    (rows.iter().map(|r| r.error_cm * r.error_cm).sum::<f64>() / rows.len().max(1) as f64).sqrt()
}
