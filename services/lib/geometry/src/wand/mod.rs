//! Extrinsic calibration of a rig from a wand waved through the volume: where each camera is,
//! from frames in which several cameras saw the wand's markers.
//!
//! Not a thesis equation: the thesis measured its two cameras' placement by hand (§2.3.1).
//! The method is the one every motion-capture system uses:
//!
//! 1. Each camera's pixels are undistorted with its intrinsics into normalised coordinates.
//! 2. For each pair of cameras, the essential matrix from the frames both saw (the eight-point
//!    algorithm on the wand's centre, RANSAC on the Sampson distance), decomposed into the
//!    pair's rotation and direction of translation (the pose in front of both cameras); the
//!    translation's length from the wand: its two end markers triangulated in the pair's frame
//!    are `length` apart.
//! 3. A spanning tree over the pairs (most inlier frames first) from the reference camera
//!    (camera 0, the world's origin until the floor is set) composes every camera's first pose.
//! 4. Bundle adjustment (`lm`, cameras global, one wand per frame): each frame's wand is one
//!    end marker's position and a direction, its other markers at their known distances along
//!    it, so the wand's length sets the scale exactly; residuals are every camera's pixels of
//!    the markers, each blob taken by the nearer projected marker. Frames whose residual is
//!    far above the rest are dropped and the adjustment run again.
//!
//! Frames: `cam_from_ref` maps camera 0's frame into each camera's (x right, y down, z along
//! the optical axis: `docs/conventions.md`). Lengths in metres, pixels as observed
//! (distorted).

use crate::camera::Camera;
use crate::error::GeometryError;
use crate::lm::{self, BlockProblem};
use nalgebra::{
    Isometry3, Matrix3, Point2, Point3, Rotation3, SMatrix, Translation3, UnitQuaternion, Vector2,
    Vector3,
};
use stereoscope_numeric::SplitMix64;

mod pairs;
use pairs::{Ends, Pair, PairPose, ends, pair_pose, pair_scale};

/// The wand: its markers' distances from one end marker, along a straight line (metres). One
/// marker: `[0]` (no length: the solution's scale is arbitrary until a later step, the floor's
/// L-frame, sets it); two markers: `[0, D]`; three collinear: `[0, D1, D2]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Wand {
    pub offsets_m: Vec<f64>,
}

impl Wand {
    /// A wand of two markers `length_m` apart.
    pub fn two(length_m: f64) -> Result<Self, GeometryError> {
        Wand::new(vec![0.0, length_m])
    }

    /// A wand of one marker (a single LED or ball): no scale.
    pub fn one() -> Self {
        Wand {
            offsets_m: vec![0.0],
        }
    }

    /// Markers at these distances from the first (which is at 0), all different, at most 3.
    pub fn new(offsets_m: Vec<f64>) -> Result<Self, GeometryError> {
        if offsets_m.is_empty() || offsets_m.len() > 3 {
            return Err(GeometryError::Degenerate(format!(
                "a wand has 1, 2 or 3 markers, not {}",
                offsets_m.len()
            )));
        }
        if offsets_m.iter().any(|d| !d.is_finite() || *d < 0.0)
            || offsets_m[0] != 0.0
            || offsets_m.windows(2).any(|w| w[1] <= w[0])
        {
            return Err(GeometryError::Degenerate(format!(
                "wand distances {offsets_m:?} must start at 0 and grow (metres)"
            )));
        }
        Ok(Wand { offsets_m })
    }

    pub fn markers(&self) -> usize {
        self.offsets_m.len()
    }

    /// The full length, first marker to last (0 for one marker).
    pub fn length_m(&self) -> f64 {
        self.offsets_m[self.offsets_m.len() - 1]
    }

    /// Whether the wand has a length to set the scale (two or three markers).
    pub fn has_length(&self) -> bool {
        self.markers() > 1
    }
}

/// One frame: each camera's blob centroids (pixels as observed), unlabelled.
#[derive(Debug, Clone, PartialEq)]
pub struct WandFrame {
    pub frame: u64,
    pub pixels: Vec<Vec<Point2<f64>>>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WandConfig {
    /// RANSAC draws per camera pair.
    pub ransac_iterations: usize,
    /// RANSAC inlier bound on the Sampson distance, pixels.
    pub inlier_px: f64,
    /// After the adjustment, a frame whose RMS residual exceeds this many times the median's
    /// (and 1 px) is an outlier: dropped, and the adjustment run again.
    pub outlier_factor: f64,
    pub max_iterations: usize,
    pub seed: u64,
    /// Adjust each camera's focal lengths and principal point with the poses (its lens
    /// distortion stays as given): for intrinsics from a few dot-grid images.
    pub refine_intrinsics: bool,
}

impl Default for WandConfig {
    fn default() -> Self {
        WandConfig {
            ransac_iterations: 500,
            inlier_px: 2.0,
            outlier_factor: 5.0,
            max_iterations: 50,
            seed: 1,
            refine_intrinsics: false,
        }
    }
}

/// What the calibration found.
#[derive(Debug, Clone, PartialEq)]
pub struct WandSolution {
    /// Each camera's pose, camera 0's frame as the world.
    pub cam_from_ref: Vec<Isometry3<f64>>,
    /// Each camera's intrinsics: adjusted with `refine_intrinsics`, else as given.
    pub intrinsics: Vec<crate::camera::Intrinsics>,
    /// The first estimate the adjustment started from (pairs' essential matrices chained
    /// along the spanning tree, scaled by the wand): for comparing other adjusters from it.
    pub initial_cam_from_ref: Vec<Isometry3<f64>>,
    /// Per camera: RMS reprojection error (pixels) and the markers' pixels used.
    pub per_camera: Vec<(f64, usize)>,
    /// Frames used, frames dropped before the adjustment (a camera pair too few, the wand
    /// partial in every camera but one) and as outliers after it.
    pub frames_used: usize,
    pub frames_unusable: usize,
    pub frames_outliers: usize,
    /// The wand's length measured by triangulating its end markers freely from the solved
    /// cameras: mean and standard deviation, metres (`None` for a one-marker wand).
    pub length_mean_m: Option<f64>,
    pub length_sd_m: Option<f64>,
    /// Whether the solution has the true scale. A one-marker wand leaves it arbitrary: the
    /// camera `scale_anchor` is then 1 unit from camera 0, and a later step (the floor's
    /// L-frame) must scale the rig.
    pub scale_known: bool,
    pub scale_anchor: usize,
    /// A three-marker wand's middle marker triangulated freely: its mean distance from the
    /// first marker, metres (the wand's `D1` when the wand is as said).
    pub middle_mean_m: Option<f64>,
    /// Each used frame's wand: where it was (its markers' mean, camera 0's frame) and its
    /// freely triangulated length, metres.
    pub lengths: Vec<(Point3<f64>, f64)>,
}

/// Each usable frame in normalised coordinates: per camera, the wand's blobs if that camera
/// saw exactly the wand's markers.
struct Normalised {
    frame: usize,
    views: Vec<Option<Vec<Vector2<f64>>>>,
}

/// The bundle adjustment: cameras 1.. as global parameters (rotation vector, translation),
/// one wand per frame (first marker's position, direction as two angles).
struct Adjustment<'a> {
    cams: &'a [Camera],
    frames: &'a [&'a WandFrame],
    wand: &'a Wand,
    /// Each camera's fx, fy, cx, cy follow the poses in the global parameters.
    refine: bool,
    /// One marker: this camera's distance from camera 0 is held at 1 (a residual in the first
    /// view), as nothing else fixes the scale.
    gauge: Option<usize>,
}

/// Camera `c` of the global parameters `g`: its pose, and with `refine` its fx, fy, cx, cy
/// (four per camera after the `(n − 1) × 6` pose parameters).
fn camera_of(cams: &[Camera], g: &[f64], c: usize, refine: bool) -> Camera {
    let mut cam = Camera {
        cam_from_world: pose_of(g, c),
        ..cams[c]
    };
    if refine {
        let k = &g[(cams.len() - 1) * 6 + 4 * c..][..4];
        cam.intrinsics.fx = k[0];
        cam.intrinsics.fy = k[1];
        cam.intrinsics.cx = k[2];
        cam.intrinsics.cy = k[3];
    }
    cam
}

fn pose_of(g: &[f64], cam: usize) -> Isometry3<f64> {
    if cam == 0 {
        return Isometry3::identity();
    }
    let p = &g[(cam - 1) * 6..cam * 6];
    Isometry3::from_parts(
        Translation3::new(p[3], p[4], p[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(p[0], p[1], p[2])),
    )
}

/// One camera's pixel residuals (x, y per marker) of the wand's `markers`: each marker takes
/// the blob nearest its projection (the wand's images are apart; the order of a view's blobs
/// says nothing). `None` when a marker is behind the camera.
fn view_residuals(
    cam: &Camera,
    blobs: &[Point2<f64>],
    markers: &[Point3<f64>],
    out: &mut Vec<f64>,
) -> Option<()> {
    for m in markers {
        let p = cam.project(m)?;
        let b = blobs
            .iter()
            .min_by(|x, y| (*x - p).norm_squared().total_cmp(&(*y - p).norm_squared()))?;
        out.push(b.x - p.x);
        out.push(b.y - p.y);
    }
    Some(())
}

fn wand_markers(wand: &Wand, v: &[f64]) -> Vec<Point3<f64>> {
    if !wand.has_length() {
        return vec![Point3::new(v[0], v[1], v[2])];
    }
    let (th, ph) = (v[3], v[4]);
    let dir = Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
    let a = Point3::new(v[0], v[1], v[2]);
    wand.offsets_m.iter().map(|d| a + dir * *d).collect()
}

impl BlockProblem for Adjustment<'_> {
    fn global_len(&self) -> usize {
        (self.cams.len() - 1) * 6 + if self.refine { 4 * self.cams.len() } else { 0 }
    }
    fn view_count(&self) -> usize {
        self.frames.len()
    }
    fn view_len(&self) -> usize {
        if self.wand.has_length() { 5 } else { 3 }
    }
    fn residuals(&self, g: &[f64], view: usize, v: &[f64], out: &mut Vec<f64>) -> Option<()> {
        if let (Some(anchor), 0) = (self.gauge, view) {
            out.push(1e3 * (pose_of(g, anchor).translation.vector.norm() - 1.0));
        }
        let markers = wand_markers(self.wand, v);
        for (c, blobs) in self.frames[view].pixels.iter().enumerate() {
            if blobs.len() != markers.len() {
                continue;
            }
            let cam = camera_of(self.cams, g, c, self.refine);
            view_residuals(&cam, blobs, &markers, out)?;
        }
        Some(())
    }
    fn global_step(&self, k: usize, _x: f64) -> f64 {
        // Poses in radians and metres; intrinsics in pixels.
        if k < (self.cams.len() - 1) * 6 {
            1e-7
        } else {
            1e-4
        }
    }
}

/// Calibrates the extrinsics of `cams` (their intrinsics and distortion are used, their poses
/// ignored) from wand frames.
pub fn calibrate_wand(
    cams: &[Camera],
    frames: &[WandFrame],
    wand: &Wand,
    cfg: &WandConfig,
) -> Result<WandSolution, GeometryError> {
    let n = cams.len();
    if n < 2 {
        return Err(GeometryError::TooFewPoints {
            what: "a wand calibration (cameras)".into(),
            needed: 2,
            got: n,
        });
    }
    // Normalise; a view counts when it holds exactly the wand's markers.
    let mut norm = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        if f.pixels.len() != n {
            return Err(GeometryError::Degenerate(format!(
                "frame {} has {} cameras' blobs, the rig {n}",
                f.frame,
                f.pixels.len()
            )));
        }
        let views: Vec<Option<Vec<Vector2<f64>>>> = f
            .pixels
            .iter()
            .zip(cams)
            .map(|(px, cam)| {
                (px.len() == wand.markers())
                    .then(|| {
                        px.iter()
                            .map(|p| cam.normalised(*p))
                            .collect::<Option<Vec<_>>>()
                    })
                    .flatten()
            })
            .collect();
        if views.iter().filter(|v| v.is_some()).count() >= 2 {
            norm.push(Normalised { frame: k, views });
        }
    }
    let unusable = frames.len() - norm.len();
    // Pairs, then a spanning tree from camera 0 by inlier count.
    let f_mean = cams
        .iter()
        .map(|c| (c.intrinsics.fx + c.intrinsics.fy) / 2.0)
        .sum::<f64>()
        / n as f64;
    let inlier = cfg.inlier_px / f_mean;
    let mut pairs: Vec<(usize, usize, PairPose)> = Vec::new();
    let mut planar_pairs: Vec<(usize, usize)> = Vec::new();
    for c1 in 0..n {
        for c2 in c1 + 1..n {
            match pair_pose(&norm, c1, c2, wand, inlier, cfg) {
                Some(Pair::Posed(p)) => pairs.push((c1, c2, p)),
                Some(Pair::Planar) => planar_pairs.push((c1, c2)),
                None => {}
            }
        }
    }
    let mut placed: Vec<Option<Isometry3<f64>>> = vec![None; n];
    placed[0] = Some(Isometry3::identity());
    loop {
        let mut candidates: Vec<&(usize, usize, PairPose)> = pairs
            .iter()
            .filter(|(a, b, _)| placed[*a].is_some() != placed[*b].is_some())
            .collect();
        candidates.sort_by_key(|(_, _, p)| std::cmp::Reverse(p.inliers));
        let only_reference = placed.iter().filter(|p| p.is_some()).count() == 1;
        let next = candidates.into_iter().find_map(|(a, b, p)| {
            // (the placed camera, the new one, new_from_placed)
            let (from, to, mut rel) = if placed[*a].is_some() {
                (*a, *b, p.cam2_from_cam1)
            } else {
                (*b, *a, p.cam2_from_cam1.inverse())
            };
            if !wand.has_length() && !only_reference {
                rel.translation.vector *= pair_scale(&norm, &placed, from, to, &rel)?;
            }
            Some((to, rel * placed[from]?))
        });
        let Some((to, pose)) = next else { break };
        placed[to] = Some(pose);
    }
    let missing: Vec<usize> = (0..n).filter(|&c| placed[c].is_none()).collect();
    if !missing.is_empty() && !planar_pairs.is_empty() {
        return Err(GeometryError::Degenerate(format!(
            "cameras {missing:?} cannot be placed: the wand's samples seen by the camera pairs {planar_pairs:?} lie in one plane (or those cameras are too close together to see depth). Wave the wand through the whole volume, towards and away from the cameras and up and down, not in one plane"
        )));
    }
    if !missing.is_empty() {
        return Err(GeometryError::WandUnplaced {
            cameras: missing,
            one_marker: !wand.has_length(),
        });
    }
    let mut poses: Vec<Isometry3<f64>> = placed.into_iter().flatten().collect();
    // One marker: the farthest camera from camera 0 is 1 unit away, and held there.
    let scale_anchor = if wand.has_length() {
        0
    } else {
        let anchor = (1..n)
            .max_by(|&a, &b| {
                poses[a]
                    .translation
                    .vector
                    .norm()
                    .total_cmp(&poses[b].translation.vector.norm())
            })
            .unwrap_or(1);
        let d = poses[anchor].translation.vector.norm();
        if d > 1e-12 {
            for p in &mut poses {
                p.translation.vector /= d;
            }
        }
        anchor
    };
    let initial_cam_from_ref = poses.clone();
    let mut global: Vec<f64> = poses[1..]
        .iter()
        .flat_map(|p| {
            let r = p.rotation.scaled_axis();
            let t = p.translation.vector;
            [r.x, r.y, r.z, t.x, t.y, t.z]
        })
        .collect();
    if cfg.refine_intrinsics {
        for c in cams {
            let k = &c.intrinsics;
            global.extend([k.fx, k.fy, k.cx, k.cy]);
        }
    }
    // Each frame's wand from its first two views, then adjusted with the cameras.
    let mut used: Vec<usize> = norm.iter().map(|f| f.frame).collect();
    let mut outliers = 0usize;
    let mut solution = None;
    for _round in 0..3 {
        let chosen: Vec<&WandFrame> = used.iter().map(|&k| &frames[k]).collect();
        let cams_now: Vec<Camera> = (0..n)
            .map(|c| camera_of(cams, &global, c, cfg.refine_intrinsics))
            .collect();
        let mut views: Vec<Vec<f64>> = chosen
            .iter()
            .map(|f| initial_wand(&cams_now, f, wand))
            .collect::<Option<_>>()
            .ok_or_else(|| {
                GeometryError::Degenerate("a wand frame could not be triangulated".into())
            })?;
        let problem = Adjustment {
            cams,
            frames: &chosen,
            wand,
            refine: cfg.refine_intrinsics,
            gauge: (!wand.has_length()).then_some(scale_anchor),
        };
        lm::solve(&problem, &mut global, &mut views, cfg.max_iterations);
        // Per frame RMS; drop the outliers and go again, or stop.
        let mut buf = Vec::new();
        let rms: Vec<f64> = views
            .iter()
            .enumerate()
            .map(|(i, v)| {
                buf.clear();
                problem
                    .residuals(&global, i, v, &mut buf)
                    .map_or(f64::INFINITY, |_| {
                        (buf.iter().map(|r| r * r).sum::<f64>() / buf.len().max(1) as f64).sqrt()
                    })
            })
            .collect();
        let mut sorted = rms.clone();
        sorted.sort_by(f64::total_cmp);
        let median = sorted[sorted.len() / 2];
        let bound = (median * cfg.outlier_factor).max(1.0);
        let keep: Vec<usize> = (0..used.len()).filter(|&i| rms[i] <= bound).collect();
        solution = Some((chosen.len(), views));
        if keep.len() == used.len() {
            break;
        }
        outliers += used.len() - keep.len();
        used = keep.iter().map(|&i| used[i]).collect();
        if used.len() < 8 {
            return Err(GeometryError::TooFewPoints {
                what: "a wand calibration (frames left after outliers)".into(),
                needed: 8,
                got: used.len(),
            });
        }
    }
    let (_, views) = solution.ok_or_else(|| GeometryError::Solver("no adjustment ran".into()))?;
    let chosen: Vec<&WandFrame> = used.iter().map(|&k| &frames[k]).collect();
    let cam_from_ref: Vec<Isometry3<f64>> = (0..n).map(|c| pose_of(&global, c)).collect();
    let solved: Vec<Camera> = (0..n)
        .map(|c| camera_of(cams, &global, c, cfg.refine_intrinsics))
        .collect();
    // Per camera RMS.
    let mut per_camera = vec![(0.0f64, 0usize); n];
    let mut buf = Vec::new();
    for (f, v) in chosen.iter().zip(&views) {
        let markers = wand_markers(wand, v);
        for (c, blobs) in f.pixels.iter().enumerate() {
            buf.clear();
            if blobs.len() == wand.markers()
                && view_residuals(&solved[c], blobs, &markers, &mut buf).is_some()
            {
                per_camera[c].0 += buf.iter().map(|r| r * r).sum::<f64>();
                per_camera[c].1 += wand.markers();
            }
        }
    }
    let per_camera: Vec<(f64, usize)> = per_camera
        .into_iter()
        .map(|(s, k)| ((s / (2 * k).max(1) as f64).sqrt(), k))
        .collect();
    // The wand's length, triangulated freely, with where the wand was (its markers' mean).
    let mut middles = Vec::new();
    let sampled: Vec<(Point3<f64>, f64)> = chosen
        .iter()
        .zip(&views)
        .filter_map(|(f, v)| {
            let m = wand_markers(wand, v);
            let centre =
                Point3::from(m.iter().map(|p| p.coords).sum::<Vector3<f64>>() / m.len() as f64);
            let free = free_markers(&solved, f, wand, v)?;
            if free.len() == 3 {
                middles.push((free[1] - free[0]).norm());
            }
            Some((centre, (free[free.len() - 1] - free[0]).norm()))
        })
        .collect();
    let middle_mean_m =
        (!middles.is_empty()).then(|| middles.iter().sum::<f64>() / middles.len() as f64);
    let lengths: Vec<f64> = sampled.iter().map(|s| s.1).collect();
    let (mean, sd) = if lengths.is_empty() {
        (None, None)
    } else {
        let mean = lengths.iter().sum::<f64>() / lengths.len() as f64;
        let sd = (lengths.iter().map(|l| (l - mean).powi(2)).sum::<f64>()
            / (lengths.len().max(2) - 1) as f64)
            .sqrt();
        (Some(mean), Some(sd))
    };
    Ok(WandSolution {
        cam_from_ref,
        intrinsics: solved.iter().map(|c| c.intrinsics).collect(),
        initial_cam_from_ref,
        per_camera,
        frames_used: chosen.len(),
        frames_unusable: unusable,
        frames_outliers: outliers,
        length_mean_m: mean,
        length_sd_m: sd,
        scale_known: wand.has_length(),
        scale_anchor,
        middle_mean_m,
        lengths: sampled,
    })
}

/// A frame's wand parameters from its views: the end markers triangulated from every view
/// that saw the whole wand (each view's ends matched to the first view's by the nearer
/// epipolar fit), then the first marker and the direction.
fn initial_wand(cams: &[Camera], f: &WandFrame, wand: &Wand) -> Option<Vec<f64>> {
    use crate::triangulate::{Observation, triangulate_dlt};
    if !wand.has_length() {
        let obs: Vec<Observation> = f
            .pixels
            .iter()
            .enumerate()
            .filter(|(_, px)| px.len() == 1)
            .map(|(c, px)| Observation {
                camera: c,
                pixel: px[0],
            })
            .collect();
        let p = triangulate_dlt(cams, &obs).ok()?;
        return Some(vec![p.x, p.y, p.z]);
    }
    let views: Vec<Ends> = f
        .pixels
        .iter()
        .enumerate()
        .filter(|(_, px)| px.len() == wand.markers())
        .map(|(c, px)| {
            let v: Vec<Vector2<f64>> = px.iter().map(|p| p.coords).collect();
            let (a, b) = ends(&v);
            (c, (Point2::from(a), Point2::from(b)))
        })
        .collect();
    if views.len() < 2 {
        return None;
    }
    // Try both orders of each later view against the first; keep the combination whose two
    // points fit best (views are few: at most 2^(n−1) combinations, capped at 8 cameras).
    let mut best: Option<(f64, Point3<f64>, Point3<f64>)> = None;
    let k = views.len() - 1;
    for mask in 0..(1u32 << k.min(7)) {
        let mut obs_a = Vec::new();
        let mut obs_b = Vec::new();
        for (i, (c, (a, b))) in views.iter().enumerate() {
            let flip = i > 0 && mask & (1 << (i - 1)) != 0;
            let (a, b) = if flip { (*b, *a) } else { (*a, *b) };
            obs_a.push(Observation {
                camera: *c,
                pixel: a,
            });
            obs_b.push(Observation {
                camera: *c,
                pixel: b,
            });
        }
        let (Ok(pa), Ok(pb)) = (triangulate_dlt(cams, &obs_a), triangulate_dlt(cams, &obs_b))
        else {
            continue;
        };
        let err: f64 = obs_a
            .iter()
            .map(|o| (o, pa))
            .chain(obs_b.iter().map(|o| (o, pb)))
            .map(|(o, p)| {
                cams[o.camera]
                    .project(&p)
                    .map_or(f64::INFINITY, |q| (q - o.pixel).norm_squared())
            })
            .sum();
        if best.as_ref().is_none_or(|b| err < b.0) {
            best = Some((err, pa, pb));
        }
    }
    let (_, pa, pb) = best?;
    let d = (pb - pa).normalize();
    Some(vec![
        pa.x,
        pa.y,
        pa.z,
        d.z.clamp(-1.0, 1.0).acos(),
        d.y.atan2(d.x),
    ])
}

/// The wand's markers triangulated each on its own from the solved cameras (each blob taken by
/// the nearer adjusted marker), in the wand's order.
fn free_markers(
    cams: &[Camera],
    f: &WandFrame,
    wand: &Wand,
    v: &[f64],
) -> Option<Vec<Point3<f64>>> {
    use crate::triangulate::{Observation, triangulate};
    if !wand.has_length() {
        return None;
    }
    let mut pts = Vec::new();
    for m in wand_markers(wand, v) {
        let obs: Vec<Observation> = f
            .pixels
            .iter()
            .enumerate()
            .filter(|(_, px)| px.len() == wand.markers())
            .filter_map(|(c, px)| {
                let q = cams[c].project(&m)?;
                let b = px
                    .iter()
                    .min_by(|x, y| (*x - q).norm_squared().total_cmp(&(*y - q).norm_squared()))?;
                Some(Observation {
                    camera: c,
                    pixel: *b,
                })
            })
            .collect();
        if obs.len() < 2 {
            return None;
        }
        pts.push(triangulate(cams, &obs).ok()?.point_world);
    }
    Some(pts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::camera_pose_error;

    fn ring() -> Vec<Camera> {
        crate::synthetic::wand_rig_cameras()
    }

    /// Every camera within 1 mm and 0.05° of the truth, the first camera's frame the world.
    fn assert_placed(truth: &[Camera], sol: &WandSolution) {
        let ref_from_world = truth[0].cam_from_world;
        for (c, cam) in truth.iter().enumerate() {
            let want = cam.cam_from_world * ref_from_world.inverse();
            let (dpos, drot) = camera_pose_error(&sol.cam_from_ref[c], &want);
            assert!(dpos < 1e-3, "camera {c}: {:.3} mm off", dpos * 1e3);
            assert!(drot < 0.05, "camera {c}: {drot:.4}° off");
        }
    }

    fn frames(cams: &[Camera], wand: &Wand, count: usize, noise_px: f64) -> Vec<WandFrame> {
        crate::synthetic::wand_frames(cams, &wand.offsets_m, count, noise_px, 7)
            .into_iter()
            .enumerate()
            .map(|(k, pixels)| WandFrame {
                frame: k as u64,
                pixels,
            })
            .collect()
    }

    #[test]
    fn a_ring_of_four_cameras_is_placed_by_a_two_marker_wand() {
        let truth = ring();
        let wand = Wand::two(0.5).unwrap();
        let mut fs = frames(&truth, &wand, 600, 0.2);
        // A few frames where a reflection took a marker's place in one view.
        for f in fs.iter_mut().step_by(50) {
            if let Some(p) = f.pixels[1].first_mut() {
                *p += Vector2::new(40.0, -25.0);
            }
        }
        let sol = calibrate_wand(&truth, &fs, &wand, &WandConfig::default()).unwrap();
        assert_placed(&truth, &sol);
        // Each end triangulated on its own: with 0.2 px at 3 m and f = 600 px, about 0.6 mm
        // a point, so the length's spread is of that order; its mean is the wand's.
        assert!((sol.length_mean_m.unwrap() - 0.5).abs() < 2e-4, "{sol:?}");
        assert!(sol.length_sd_m.unwrap() < 1.2e-3, "{sol:?}");
        assert!(sol.frames_outliers >= 10, "{sol:?}");
        for (rms, k) in &sol.per_camera {
            assert!(*rms < 0.3 && *k > 100, "{sol:?}");
        }
    }

    /// Intrinsics a few percent off (what a handful of dot-grid images can leave): with
    /// `refine_intrinsics` the adjustment finds the focal lengths and principal points again
    /// and places the cameras; without, it cannot place them as well.
    #[test]
    fn intrinsics_a_few_percent_off_are_refined_with_the_poses() {
        let truth = ring();
        let wand = Wand::two(0.5).unwrap();
        let fs = frames(&truth, &wand, 800, 0.2);
        let mut given = truth.clone();
        for (c, cam) in given.iter_mut().enumerate().skip(1) {
            let k = &mut cam.intrinsics;
            k.fx *= 1.0 + 0.02 * c as f64;
            k.fy *= 1.0 + 0.02 * c as f64;
            k.cx += 6.0;
            k.cy -= 4.0;
        }
        let fixed = calibrate_wand(&given, &fs, &wand, &WandConfig::default()).unwrap();
        let worst = |sol: &WandSolution| {
            let ref_from_world = truth[0].cam_from_world;
            truth
                .iter()
                .enumerate()
                .map(|(c, cam)| {
                    camera_pose_error(
                        &sol.cam_from_ref[c],
                        &(cam.cam_from_world * ref_from_world.inverse()),
                    )
                    .0
                })
                .fold(0.0f64, f64::max)
        };
        // 2 to 6 % off in focal length: the cameras 0.18 m off.
        assert!(worst(&fixed) > 0.1, "{} m", worst(&fixed));
        let cfg = WandConfig {
            refine_intrinsics: true,
            ..WandConfig::default()
        };
        let refined = calibrate_wand(&given, &fs, &wand, &cfg).unwrap();
        // Focal lengths within 0.15 %, principal points within 1.5 px, reprojection at the
        // noise; the cameras within 10 mm (the intrinsics' own uncertainty at 0.2 px moves
        // them by millimetres: with good dot-grid intrinsics, keep them fixed).
        for (got, want) in refined.intrinsics.iter().zip(&truth) {
            let w = &want.intrinsics;
            assert!((got.fx / w.fx - 1.0).abs() < 1.5e-3, "{got:?} {w:?}");
            assert!((got.fy / w.fy - 1.0).abs() < 1.5e-3, "{got:?} {w:?}");
            assert!(
                (got.cx - w.cx).abs() < 1.5 && (got.cy - w.cy).abs() < 1.5,
                "{got:?} {w:?}"
            );
        }
        for (rms, _) in &refined.per_camera {
            assert!(*rms < 0.2, "{:?}", refined.per_camera);
        }
        assert!(worst(&refined) < 0.01, "{} m", worst(&refined));
    }

    /// The usual three-marker wand (250 and 500 mm from one end), with some views missing a
    /// marker (those views are left out, the frame kept while two cameras saw it whole).
    #[test]
    fn a_three_marker_wand_with_partial_views() {
        let truth = ring();
        let wand = Wand::new(vec![0.0, 0.25, 0.5]).unwrap();
        let mut fs = frames(&truth, &wand, 400, 0.2);
        for f in fs.iter_mut().step_by(7) {
            f.pixels[2].pop();
        }
        let sol = calibrate_wand(&truth, &fs, &wand, &WandConfig::default()).unwrap();
        assert_placed(&truth, &sol);
        assert!((sol.length_mean_m.unwrap() - 0.5).abs() < 2e-4, "{sol:?}");
    }

    #[test]
    fn a_camera_that_never_saw_the_wand_is_named() {
        let truth = ring();
        let wand = Wand::two(0.5).unwrap();
        let mut fs = frames(&truth, &wand, 100, 0.2);
        for f in &mut fs {
            f.pixels[3].clear();
        }
        let err = calibrate_wand(&truth, &fs, &wand, &WandConfig::default()).unwrap_err();
        assert!(err.to_string().contains("cameras [3]"), "{err}");
        assert!(Wand::new(vec![0.0, 0.5, 0.25]).is_err());
        assert!(Wand::new(vec![0.5]).is_err());
        assert!(Wand::new(vec![]).is_err());
        assert_eq!(Wand::new(vec![0.0]).unwrap(), Wand::one());
        assert!(Wand::two(f64::NAN).is_err());
    }

    /// One marker: the cameras placed as with a longer wand but for the scale, which is
    /// arbitrary (the anchor camera 1 unit from camera 0); scaled by the true distance of the
    /// anchor, every camera within 1 mm and 0.05°.
    #[test]
    fn a_one_marker_wand_places_the_cameras_up_to_scale() {
        let truth = ring();
        let wand = Wand::one();
        let mut fs = frames(&truth, &wand, 800, 0.2);
        // A reflection in place of the marker in some views: outliers.
        for f in fs.iter_mut().step_by(60) {
            if let Some(p) = f.pixels[2].first_mut() {
                *p += Vector2::new(-30.0, 35.0);
            }
        }
        let sol = calibrate_wand(&truth, &fs, &wand, &WandConfig::default()).unwrap();
        assert!(!sol.scale_known && sol.length_mean_m.is_none(), "{sol:?}");
        assert!(sol.frames_outliers >= 5, "{sol:?}");
        let ref_from_world = truth[0].cam_from_world;
        let want: Vec<Isometry3<f64>> = truth
            .iter()
            .map(|c| c.cam_from_world * ref_from_world.inverse())
            .collect();
        let got_anchor = sol.cam_from_ref[sol.scale_anchor].translation.vector.norm();
        assert!((got_anchor - 1.0).abs() < 1e-6, "{got_anchor}");
        let scale = want[sol.scale_anchor].translation.vector.norm();
        for (c, w) in want.iter().enumerate() {
            let mut got = sol.cam_from_ref[c];
            got.translation.vector *= scale;
            let (dpos, drot) = camera_pose_error(&got, w);
            assert!(dpos < 1e-3, "camera {c}: {:.3} mm off", dpos * 1e3);
            assert!(drot < 0.05, "camera {c}: {drot:.4}° off");
        }
        for (rms, k) in &sol.per_camera {
            assert!(*rms < 0.3 && *k > 100, "{sol:?}");
        }
    }

    /// A wand waved in one vertical plane: every pair's samples fit a homography, so no pose is
    /// determined; the error says so and what to do instead of returning a wrong rig.
    #[test]
    fn a_wand_waved_in_one_plane_is_refused_with_advice() {
        let truth = ring();
        let wand = Wand::two(0.5).unwrap();
        let mut rng = SplitMix64::new(11);
        let fs: Vec<WandFrame> = (0..600)
            .map(|k| {
                let a = Point3::new(rng.range(-0.6, 0.6), 0.05, rng.range(0.5, 1.5));
                let t = rng.range(0.0, std::f64::consts::TAU);
                let d = Vector3::new(t.cos(), 0.0, t.sin());
                let pixels = truth
                    .iter()
                    .map(|c| {
                        [a, a + d * 0.5]
                            .iter()
                            .filter_map(|m| c.project(m))
                            .map(|p| p + Vector2::new(rng.normal(), rng.normal()) * 0.2)
                            .collect()
                    })
                    .collect();
                WandFrame { frame: k, pixels }
            })
            .collect();
        let err = calibrate_wand(&truth, &fs, &wand, &WandConfig::default()).unwrap_err();
        assert!(err.to_string().contains("lie in one plane"), "{err}");
    }

    /// A three-marker wand whose middle marker is not where the user said: the frames do not
    /// fit (residuals of pixels), and the middle marker triangulated freely is far from where
    /// the wand puts it (the CLI refuses it, naming the wand).
    #[test]
    fn a_three_marker_wand_of_other_distances_does_not_fit() {
        let truth = ring();
        let fs = frames(&truth, &Wand::new(vec![0.0, 0.25, 0.5]).unwrap(), 400, 0.2);
        let said = Wand::new(vec![0.0, 0.15, 0.5]).unwrap();
        let sol = calibrate_wand(&truth, &fs, &said, &WandConfig::default()).unwrap();
        let worst = sol.per_camera.iter().map(|c| c.0).fold(0.0, f64::max);
        let middle = sol.middle_mean_m.unwrap();
        assert!(worst > 2.0, "{worst} px");
        assert!((middle - 0.15).abs() > 0.05, "{middle} m");
        // As said, the middle marker is where it should be.
        let right = Wand::new(vec![0.0, 0.25, 0.5]).unwrap();
        let sol = calibrate_wand(&truth, &fs, &right, &WandConfig::default()).unwrap();
        assert!((sol.middle_mean_m.unwrap() - 0.25).abs() < 5e-4, "{sol:?}");
    }
}
