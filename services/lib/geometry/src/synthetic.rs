//! Synthetic calibration data with known truth: a reference camera, planar grids, and views
//! of a grid from random poses with pixel noise. Used by the tests, the benchmarks and the
//! OpenCV fixtures, and useful to check a calibration set-up before buying cameras.

use crate::camera::{Camera, Distortion, Intrinsics};
use crate::transform::look_at;
use nalgebra::{Isometry3, Point2, Point3, Vector2, Vector3};
use stereoscope_numeric::SplitMix64;

/// A 640 × 480 camera with non-square pixels and real-lens distortion: fx 812, fy 798,
/// principal point (322.5, 236), k1 −0.18, k2 0.07, p1 0.0008, p2 −0.0005; at the origin.
pub fn example_camera() -> Camera {
    let intrinsics = Intrinsics {
        fx: 812.0,
        fy: 798.0,
        cx: 322.5,
        cy: 236.0,
        width: 640,
        height: 480,
    };
    let distortion = Distortion {
        k1: -0.18,
        k2: 0.07,
        k3: 0.0,
        p1: 0.0008,
        p2: -0.0005,
    };
    Camera {
        intrinsics,
        distortion,
        cam_from_world: Isometry3::identity(),
    }
}

/// A `cols × rows` planar grid with `spacing` between points, row-major, z = 0.
pub fn grid(cols: usize, rows: usize, spacing: f64) -> Vec<Point3<f64>> {
    (0..rows)
        .flat_map(|r| {
            (0..cols).map(move |c| Point3::new(c as f64 * spacing, r as f64 * spacing, 0.0))
        })
        .collect()
}

/// How calibration views are spread around the target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewSpread {
    /// The camera moves up to this far sideways (x and y) from above the target's centre.
    pub lateral_m: f64,
    /// Its height above the target, `[near, far)`.
    pub distance_m: (f64, f64),
    /// The point it aims at moves up to this far from the centre.
    pub aim_jitter_m: f64,
    /// Roll: the up vector's sideways component, up to this much.
    pub roll: f64,
}

/// `n` views of `target` by `camera` (its intrinsics and distortion) from random poses, with
/// Gaussian pixel noise of `noise_px` per axis; points outside the image are left out.
pub fn calibration_views(
    camera: &Camera,
    target: &[Point3<f64>],
    n: usize,
    spread: &ViewSpread,
    noise_px: f64,
    seed: u64,
) -> Vec<Vec<(Point3<f64>, Point2<f64>)>> {
    let mut rng = SplitMix64::new(seed);
    let count = target.len().max(1) as f64;
    let centre = Point3::from(target.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / count);
    let (w, h) = (
        camera.intrinsics.width as f64 - 1.0,
        camera.intrinsics.height as f64 - 1.0,
    );
    let mut views = Vec::with_capacity(n);
    while views.len() < n {
        let l = spread.lateral_m;
        let pos = centre
            + Vector3::new(
                rng.range(-l, l),
                rng.range(-l, l),
                rng.range(spread.distance_m.0, spread.distance_m.1),
            );
        let j = spread.aim_jitter_m;
        let aim = centre + Vector3::new(rng.range(-j, j), rng.range(-j, j), 0.0);
        let up = Vector3::new(rng.range(-spread.roll, spread.roll), 1.0, 0.0);
        let Ok(world_from_cam) = look_at(pos, aim, up) else {
            continue;
        };
        let cam = Camera {
            cam_from_world: world_from_cam.inverse(),
            ..*camera
        };
        views.push(
            target
                .iter()
                .filter_map(|p| {
                    let px = cam
                        .project(p)
                        .filter(|q| q.x >= 0.0 && q.y >= 0.0 && q.x <= w && q.y <= h)?;
                    Some((
                        *p,
                        Point2::new(
                            px.x + noise_px * rng.normal(),
                            px.y + noise_px * rng.normal(),
                        ),
                    ))
                })
                .collect(),
        );
    }
    views
}

/// `n` cameras (1280 × 720, fx 900 + 20·i, k1 −0.12, k2 0.03) on a 2.5 m circle, 1.8 m up,
/// all aimed at (0, 0, 0.4): a motion-capture ring around a 1 m volume.
pub fn ring_cameras(n: usize) -> Vec<Camera> {
    (0..n)
        .filter_map(|i| {
            let a = i as f64 * std::f64::consts::TAU / n.max(1) as f64 + 0.3;
            let world_from_cam = look_at(
                Point3::new(2.5 * a.cos(), 2.5 * a.sin(), 1.8),
                Point3::new(0.0, 0.0, 0.4),
                Vector3::z(),
            )
            .ok()?;
            let intrinsics = Intrinsics {
                fx: 900.0 + 20.0 * i as f64,
                fy: 895.0,
                cx: 640.0,
                cy: 360.0,
                width: 1280,
                height: 720,
            };
            let distortion = Distortion {
                k1: -0.12,
                k2: 0.03,
                ..Default::default()
            };
            Some(Camera {
                intrinsics,
                distortion,
                cam_from_world: world_from_cam.inverse(),
            })
        })
        .collect()
}

/// Four 640 × 480 cameras (fx = fy = 600, no distortion) round a volume about 3 m away, at
/// mixed heights (1–2.5 m), one rolled 90°, all aimed at (0, 0, 1): a wand calibration's
/// test rig.
pub fn wand_rig_cameras() -> Vec<Camera> {
    let intrinsics = Intrinsics {
        fx: 600.0,
        fy: 600.0,
        cx: 319.5,
        cy: 239.5,
        width: 640,
        height: 480,
    };
    [
        (Point3::new(3.0, 0.0, 1.5), Vector3::z()),
        (Point3::new(0.0, 3.0, 2.5), Vector3::z()),
        (Point3::new(-3.0, 0.2, 1.0), Vector3::z()),
        (Point3::new(0.2, -3.0, 2.0), Vector3::x()),
    ]
    .iter()
    .filter_map(|(at, up)| {
        let world_from_cam = look_at(*at, Point3::new(0.0, 0.0, 1.0), *up).ok()?;
        Some(Camera {
            intrinsics,
            distortion: Distortion::default(),
            cam_from_world: world_from_cam.inverse(),
        })
    })
    .collect()
}

/// `count` frames of a straight wand (markers at `offsets_m` from its first) waved through a
/// 1.2 × 1.2 × 1 m volume centred on (0, 0, 1) in random directions: per frame, per camera, the
/// markers' pixels inside the image with Gaussian noise of `noise_px`, in either order.
pub fn wand_frames(
    cams: &[Camera],
    offsets_m: &[f64],
    count: usize,
    noise_px: f64,
    seed: u64,
) -> Vec<Vec<Vec<Point2<f64>>>> {
    wand_frames_in_order(cams, offsets_m, count, noise_px, seed, true)
}

/// [`wand_frames`] with each view's blobs in the wand's marker order when `shuffle` is false
/// (the same frames otherwise: for peers that need labelled points). A view that lost a
/// marker off its image is shorter, as in [`wand_frames`].
pub fn wand_frames_in_order(
    cams: &[Camera],
    offsets_m: &[f64],
    count: usize,
    noise_px: f64,
    seed: u64,
    shuffle: bool,
) -> Vec<Vec<Vec<Point2<f64>>>> {
    let mut rng = SplitMix64::new(seed);
    (0..count)
        .map(|_| {
            let a = Point3::new(
                rng.range(-0.6, 0.6),
                rng.range(-0.6, 0.6),
                rng.range(0.5, 1.5),
            );
            let d = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
            let markers: Vec<Point3<f64>> = offsets_m.iter().map(|o| a + d * *o).collect();
            cams.iter()
                .map(|c| {
                    let (w, h) = (c.intrinsics.width as f64, c.intrinsics.height as f64);
                    let mut px: Vec<Point2<f64>> = markers
                        .iter()
                        .filter_map(|m| c.project(m))
                        .filter(|p| p.x >= -0.5 && p.y >= -0.5 && p.x < w - 0.5 && p.y < h - 0.5)
                        .map(|p| p + Vector2::new(rng.normal(), rng.normal()) * noise_px)
                        .collect();
                    if rng.uniform() < 0.5 && shuffle {
                        px.reverse();
                    }
                    px
                })
                .collect()
        })
        .collect()
}
