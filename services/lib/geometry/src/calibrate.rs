//! Camera calibration from known target points and their pixels, for one camera or a rig.
//!
//! Thesis: §2.2.3 names the parameters to calibrate (Eq. 2.4–2.8: the camera's rotation and
//! position, focal length, pixel pitch and image centre); the thesis measured them with a grid
//! board of 10 cm lines. Here they are estimated from correspondences, as a user would with
//! that board or a dot grid:
//!
//! 1. a linear start — Zhang's closed form from the homographies of two or more views of a
//!    planar target (zero skew), or the DLT and an RQ decomposition for a non-planar target —
//!    and each view's pose from it;
//! 2. Levenberg–Marquardt over the intrinsics, the distortion (radial k1 k2 k3, tangential p1
//!    p2) and every view's pose (`lm.rs`), minimising the reprojection error in pixels;
//! 3. the RMS and per-point residuals, and the parameters' standard deviations from the
//!    inverse Gauss–Newton matrix scaled by the residual variance.
//!
//! Several cameras seeing the same target views are refined jointly: their intrinsics, their
//! poses relative to camera 0 (the stereo extrinsics) and the target's pose in each view.
//!
//! Degenerate input (too few points in a view, collinear points, a single planar view for a
//! full model, non-finite values, cameras with no view in common) is an error that says which.

use crate::camera::{Distortion, Intrinsics};
use crate::error::GeometryError;
use crate::lm::{self, BlockProblem};
use nalgebra::{
    DMatrix, Isometry3, Matrix3, Matrix3x4, Point2, Point3, Rotation3, SVD, Translation3,
    UnitQuaternion, Vector3,
};

/// Which distortion terms are estimated (the others stay zero).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DistortionModel {
    /// No distortion (the thesis's model).
    None,
    /// k1, k2.
    Radial,
    /// k1, k2, p1, p2 with k3 fixed at 0 (OpenCV with `CALIB_FIX_K3`; the Bouguet toolbox's
    /// default): for lenses where k3 only fits noise.
    Tangential,
    /// k1, k2, p1, p2, k3 (OpenCV's default set).
    #[default]
    Full,
}

impl DistortionModel {
    fn len(self) -> usize {
        match self {
            DistortionModel::None => 0,
            DistortionModel::Radial => 2,
            DistortionModel::Tangential => 4,
            DistortionModel::Full => 5,
        }
    }
}

/// One view of the target: target coordinates and the observed pixel, per camera.
#[derive(Debug, Clone, PartialEq)]
pub struct RigView {
    /// Target points in the target's own frame.
    pub target: Vec<Point3<f64>>,
    /// `(camera, point index, pixel)`.
    pub observations: Vec<(usize, usize, Point2<f64>)>,
}

/// One camera's calibrated parameters and their standard deviations.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibratedCamera {
    pub intrinsics: Intrinsics,
    pub distortion: Distortion,
    /// Standard deviations, in the order fx, fy, cx, cy, k1, k2, p1, p2, k3 (`None` for
    /// parameters held fixed).
    pub std_dev: [Option<f64>; 9],
    /// RMS reprojection error of this camera's observations, pixels.
    pub rms_px: f64,
    /// Pose relative to camera 0 (`cam_from_cam0`; identity for camera 0).
    pub cam_from_cam0: Isometry3<f64>,
}

/// One observation's reprojection error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointResidual {
    pub view: usize,
    pub camera: usize,
    pub point: usize,
    pub du_px: f64,
    pub dv_px: f64,
}

/// The result of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub cameras: Vec<CalibratedCamera>,
    /// The target's pose in camera 0's frame, per view.
    pub cam0_from_target: Vec<Isometry3<f64>>,
    pub rms_px: f64,
    pub residuals: Vec<PointResidual>,
    pub iterations: usize,
}

// ---------------------------------------------------------------------------------------------
// Linear estimates.

/// Hartley normalisation of 2D points: returns T (3×3) with T·p having centroid 0 and mean
/// distance √2.
fn normalising_transform(pts: &[Point2<f64>]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.x / n, a.1 + p.y / n));
    let d = pts
        .iter()
        .map(|p| ((p.x - mx).powi(2) + (p.y - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if d > 0.0 {
        std::f64::consts::SQRT_2 / d
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

fn apply(t: &Matrix3<f64>, p: &Point2<f64>) -> Point2<f64> {
    let v = t * Vector3::new(p.x, p.y, 1.0);
    Point2::new(v.x / v.z, v.y / v.z)
}

/// The homography taking plane points to pixels (normalised DLT, ≥ 4 points).
pub fn homography(plane: &[Point2<f64>], pixels: &[Point2<f64>]) -> Option<Matrix3<f64>> {
    if plane.len() < 4 || plane.len() != pixels.len() {
        return None;
    }
    let (ta, tb) = (normalising_transform(plane), normalising_transform(pixels));
    let mut a = DMatrix::<f64>::zeros(2 * plane.len(), 9);
    for (i, (p, q)) in plane.iter().zip(pixels).enumerate() {
        let (p, q) = (apply(&ta, p), apply(&tb, q));
        let row0 = [p.x, p.y, 1.0, 0.0, 0.0, 0.0, -q.x * p.x, -q.x * p.y, -q.x];
        let row1 = [0.0, 0.0, 0.0, p.x, p.y, 1.0, -q.y * p.x, -q.y * p.y, -q.y];
        for c in 0..9 {
            a[(2 * i, c)] = row0[c];
            a[(2 * i + 1, c)] = row1[c];
        }
    }
    let h = smallest_right_singular_vector(&a)?;
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let hm = tb.try_inverse()? * hn * ta;
    (hm[(2, 2)].abs() > 1e-300).then(|| hm / hm[(2, 2)])
}

fn smallest_right_singular_vector(a: &DMatrix<f64>) -> Option<Vec<f64>> {
    // Through AᵀA so that short matrices still give the full right basis.
    let ata = a.transpose() * a;
    let eig = ata.symmetric_eigen();
    let imin = crate::index_of_min(eig.eigenvalues.iter().copied());
    let v: Vec<f64> = eig.eigenvectors.column(imin).iter().copied().collect();
    v.iter().all(|x| x.is_finite()).then_some(v)
}

/// The 3×4 projection matrix from ≥ 6 non-coplanar points (normalised DLT).
pub fn dlt_projection(points: &[Point3<f64>], pixels: &[Point2<f64>]) -> Option<Matrix3x4<f64>> {
    if points.len() < 6 || points.len() != pixels.len() {
        return None;
    }
    let n = points.len() as f64;
    let c = points
        .iter()
        .fold(Vector3::zeros(), |a, p| a + p.coords / n);
    let d = points.iter().map(|p| (p.coords - c).norm()).sum::<f64>() / n;
    let s = if d > 0.0 { 3f64.sqrt() / d } else { 1.0 };
    let mut t3 = nalgebra::Matrix4::<f64>::identity() * s;
    t3[(3, 3)] = 1.0;
    t3.fixed_view_mut::<3, 1>(0, 3).copy_from(&(-c * s));
    let tb = normalising_transform(pixels);
    let mut a = DMatrix::<f64>::zeros(2 * points.len(), 12);
    for (i, (p, q)) in points.iter().zip(pixels).enumerate() {
        let pn = t3 * nalgebra::Vector4::new(p.x, p.y, p.z, 1.0);
        let q = apply(&tb, q);
        for k in 0..4 {
            a[(2 * i, k)] = pn[k];
            a[(2 * i, 8 + k)] = -q.x * pn[k];
            a[(2 * i + 1, 4 + k)] = pn[k];
            a[(2 * i + 1, 8 + k)] = -q.y * pn[k];
        }
    }
    let h = smallest_right_singular_vector(&a)?;
    let pn = Matrix3x4::from_row_slice(&h);
    Some(tb.try_inverse()? * pn * t3)
}

/// RQ decomposition of a 3×3 matrix: M = K·R, K upper triangular with positive diagonal,
/// R orthogonal.
fn rq3(m: &Matrix3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let flip = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (flip * m).transpose().qr();
    let (q, r) = (qr.q(), qr.r());
    let mut k = flip * r.transpose() * flip;
    let mut rot = flip * q.transpose();
    for i in 0..3 {
        if k[(i, i)] < 0.0 {
            for row in 0..3 {
                k[(row, i)] = -k[(row, i)];
            }
            for col in 0..3 {
                rot[(i, col)] = -rot[(i, col)];
            }
        }
    }
    (k, rot)
}

/// The nearest rotation to a 3×3 matrix (SVD), with determinant +1.
fn nearest_rotation(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let svd = SVD::new(*m, true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut r = u * vt;
    if r.determinant() < 0.0 {
        let mut u2 = u;
        for row in 0..3 {
            u2[(row, 2)] = -u2[(row, 2)];
        }
        r = u2 * vt;
    }
    Some(r)
}

fn isometry(r: &Matrix3<f64>, t: Vector3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r)),
    )
}

/// Zhang's closed form for fx, fy, cx, cy (zero skew) from ≥ 2 plane homographies.
pub fn zhang_intrinsics(hs: &[Matrix3<f64>]) -> Option<(f64, f64, f64, f64)> {
    let v = |h: &Matrix3<f64>, i: usize, j: usize| -> [f64; 6] {
        let (hi, hj) = (h.column(i), h.column(j));
        [
            hi[0] * hj[0],
            hi[0] * hj[1] + hi[1] * hj[0],
            hi[1] * hj[1],
            hi[2] * hj[0] + hi[0] * hj[2],
            hi[2] * hj[1] + hi[1] * hj[2],
            hi[2] * hj[2],
        ]
    };
    let mut a = DMatrix::<f64>::zeros(2 * hs.len() + 1, 6);
    for (k, h) in hs.iter().enumerate() {
        // Scale each homography so the constraints weigh alike.
        let h = h / h.column(0).norm().max(1e-300);
        let v12 = v(&h, 0, 1);
        let (v11, v22) = (v(&h, 0, 0), v(&h, 1, 1));
        for c in 0..6 {
            a[(2 * k, c)] = v12[c];
            a[(2 * k + 1, c)] = v11[c] - v22[c];
        }
    }
    // Zero skew: B12 = 0.
    let scale = a.norm().max(1.0);
    a[(2 * hs.len(), 1)] = scale;
    let b = smallest_right_singular_vector(&a)?;
    let (mut b11, mut b12, mut b22, mut b13, mut b23, mut b33) =
        (b[0], b[1], b[2], b[3], b[4], b[5]);
    if b11 < 0.0 {
        (b11, b12, b22, b13, b23, b33) = (-b11, -b12, -b22, -b13, -b23, -b33);
    }
    let den = b11 * b22 - b12 * b12;
    if den <= 0.0 || b11 <= 0.0 {
        return None;
    }
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    if lambda / b11 <= 0.0 {
        return None;
    }
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    [alpha, beta, u0, v0]
        .iter()
        .all(|x| x.is_finite())
        .then_some((alpha, beta, u0, v0))
}

/// `cam_from_plane` from a homography and K (Zhang).
fn pose_from_homography(k: &Matrix3<f64>, h: &Matrix3<f64>) -> Option<Isometry3<f64>> {
    let kinv = k.try_inverse()?;
    let (h1, h2, h3) = (kinv * h.column(0), kinv * h.column(1), kinv * h.column(2));
    let mut lambda = 1.0 / h1.norm();
    // The target must be in front of the camera.
    if (h3 * lambda).z < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2) = (h1 * lambda, h2 * lambda);
    let r = nearest_rotation(&Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]))?;
    Some(isometry(&r, h3 * lambda))
}

/// `cam_from_target` for non-planar points with K known: DLT on normalised coordinates.
fn pose_from_points(
    k: &Matrix3<f64>,
    points: &[Point3<f64>],
    pixels: &[Point2<f64>],
) -> Option<Isometry3<f64>> {
    let kinv = k.try_inverse()?;
    let norm: Vec<Point2<f64>> = pixels.iter().map(|p| apply(&kinv, p)).collect();
    let p = dlt_projection(points, &norm)?;
    let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let mut s = m.determinant().cbrt();
    if s == 0.0 {
        return None;
    }
    // In front of the camera: the centroid's depth positive.
    let c = points.iter().fold(Vector3::zeros(), |a, q| a + q.coords) / points.len() as f64;
    let depth = (p * nalgebra::Vector4::new(c.x, c.y, c.z, 1.0)).z / s;
    if depth < 0.0 {
        s = -s;
    }
    let r = nearest_rotation(&(m / s))?;
    Some(isometry(&r, p.column(3) / s))
}

/// Shape of a view's target points.
enum Shape {
    /// Planar: `plane_from_target` maps target points onto z = 0.
    Planar(Isometry3<f64>),
    NonPlanar,
}

fn shape_of(points: &[Point3<f64>], view: usize) -> Result<Shape, GeometryError> {
    let n = points.len() as f64;
    let c = points
        .iter()
        .fold(Vector3::zeros(), |a, p| a + p.coords / n);
    let mut m = DMatrix::<f64>::zeros(points.len(), 3);
    for (i, p) in points.iter().enumerate() {
        for k in 0..3 {
            m[(i, k)] = p.coords[k] - c[k];
        }
    }
    let cov = m.transpose() * &m;
    let eig = nalgebra::SymmetricEigen::new(Matrix3::from_iterator(cov.iter().copied()));
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (l0, l1, l2) = (
        eig.eigenvalues[order[0]],
        eig.eigenvalues[order[1]],
        eig.eigenvalues[order[2]],
    );
    if !(l0 > 0.0) || l1 <= 1e-12 * l0 {
        return Err(GeometryError::Degenerate(format!(
            "view {view}: the target points are collinear (or all the same)"
        )));
    }
    if l2 <= 1e-10 * l0 {
        let (e0, e1) = (
            eig.eigenvectors.column(order[0]).into_owned(),
            eig.eigenvectors.column(order[1]).into_owned(),
        );
        let e2 = e0.cross(&e1);
        let target_from_plane = isometry(&Matrix3::from_columns(&[e0, e1, e2]), c);
        Ok(Shape::Planar(target_from_plane.inverse()))
    } else {
        Ok(Shape::NonPlanar)
    }
}

/// One view's target points and their pixels.
type ViewPoints = (Vec<Point3<f64>>, Vec<Point2<f64>>);

/// Intrinsics and per-view `cam_from_target` from linear estimates, for one camera.
fn initial_camera(
    views: &[ViewPoints],
    camera: usize,
) -> Result<(Matrix3<f64>, Vec<Isometry3<f64>>), GeometryError> {
    let mut shapes = Vec::with_capacity(views.len());
    for (i, (pts, px)) in views.iter().enumerate() {
        let shape = shape_of(pts, i)?;
        let needed = if matches!(shape, Shape::Planar(_)) {
            4
        } else {
            6
        };
        if pts.len() < needed {
            return Err(GeometryError::TooFewPoints {
                what: format!("view {i} of camera {camera}"),
                needed,
                got: pts.len(),
            });
        }
        let ppx: Vec<Point2<f64>> = px.to_vec();
        let spread = {
            let t = normalising_transform(&ppx);
            t[(0, 0)]
        };
        if !spread.is_finite() || spread > 1e9 {
            return Err(GeometryError::Degenerate(format!(
                "view {i} of camera {camera}: all pixels are the same"
            )));
        }
        shapes.push(shape);
    }
    // K from a non-planar view if there is one (the one with most points), else Zhang.
    let best_3d = views
        .iter()
        .enumerate()
        .filter(|(i, _)| matches!(shapes[*i], Shape::NonPlanar))
        .max_by_key(|(_, v)| v.0.len())
        .map(|(i, _)| i);
    let k = if let Some(i) = best_3d {
        let p = dlt_projection(&views[i].0, &views[i].1).ok_or_else(|| {
            GeometryError::Solver(format!("camera {camera}: the DLT of view {i} failed"))
        })?;
        let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
        let (mut k, _) = rq3(&m);
        k /= k[(2, 2)];
        k[(0, 1)] = 0.0;
        k
    } else {
        let mut hs = Vec::new();
        for (i, (pts, px)) in views.iter().enumerate() {
            if let Shape::Planar(plane_from_target) = &shapes[i] {
                let plane: Vec<Point2<f64>> =
                    pts.iter().map(|p| (plane_from_target * p).xy()).collect();
                hs.push(homography(&plane, px).ok_or_else(|| {
                    GeometryError::Solver(format!("camera {camera}: homography of view {i} failed"))
                })?);
            }
        }
        if hs.len() < 2 {
            return Err(GeometryError::Degenerate(format!(
                "camera {camera}: a single planar view cannot determine a full camera model; give two or more views of the target at different orientations, or a non-planar target"
            )));
        }
        let (fx, fy, cx, cy) = zhang_intrinsics(&hs).ok_or_else(|| {
            GeometryError::Degenerate(format!(
                "camera {camera}: the planar views are too alike to determine the intrinsics (tilt the target differently between views)"
            ))
        })?;
        Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0)
    };
    if !(k[(0, 0)] > 0.0 && k[(1, 1)] > 0.0 && k.iter().all(|v| v.is_finite())) {
        return Err(GeometryError::Degenerate(format!(
            "camera {camera}: the linear estimate gave an impossible camera matrix {k:?}"
        )));
    }
    let mut poses = Vec::with_capacity(views.len());
    for (i, (pts, px)) in views.iter().enumerate() {
        let pose = match &shapes[i] {
            Shape::Planar(plane_from_target) => {
                let plane: Vec<Point2<f64>> =
                    pts.iter().map(|p| (plane_from_target * p).xy()).collect();
                homography(&plane, px)
                    .and_then(|h| pose_from_homography(&k, &h))
                    .map(|cam_from_plane| cam_from_plane * plane_from_target)
            }
            Shape::NonPlanar => pose_from_points(&k, pts, px),
        };
        poses.push(pose.ok_or_else(|| {
            GeometryError::Solver(format!("camera {camera}: the pose of view {i} failed"))
        })?);
    }
    Ok((k, poses))
}

// ---------------------------------------------------------------------------------------------
// The joint refinement.

fn pose_to_params(p: &Isometry3<f64>) -> [f64; 6] {
    let r = p.rotation.scaled_axis();
    [
        r.x,
        r.y,
        r.z,
        p.translation.x,
        p.translation.y,
        p.translation.z,
    ]
}

fn params_to_pose(v: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[3], v[4], v[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[0], v[1], v[2])),
    )
}

struct RigProblem<'a> {
    views: &'a [RigView],
    cameras: usize,
    model: DistortionModel,
}

impl RigProblem<'_> {
    fn per_camera(&self) -> usize {
        4 + self.model.len()
    }

    fn camera_params(&self, g: &[f64], c: usize) -> (Intrinsics, Distortion) {
        let o = c * self.per_camera();
        let intr = Intrinsics {
            fx: g[o],
            fy: g[o + 1],
            cx: g[o + 2],
            cy: g[o + 3],
            width: 1,
            height: 1,
        };
        let d = &g[o + 4..o + self.per_camera()];
        let dist = match self.model {
            DistortionModel::None => Distortion::default(),
            DistortionModel::Radial => Distortion {
                k1: d[0],
                k2: d[1],
                ..Default::default()
            },
            DistortionModel::Tangential => Distortion {
                k1: d[0],
                k2: d[1],
                p1: d[2],
                p2: d[3],
                k3: 0.0,
            },
            DistortionModel::Full => Distortion {
                k1: d[0],
                k2: d[1],
                p1: d[2],
                p2: d[3],
                k3: d[4],
            },
        };
        (intr, dist)
    }

    fn cam_from_cam0(&self, g: &[f64], c: usize) -> Isometry3<f64> {
        if c == 0 {
            return Isometry3::identity();
        }
        let o = self.cameras * self.per_camera() + 6 * (c - 1);
        params_to_pose(&g[o..o + 6])
    }
}

impl BlockProblem for RigProblem<'_> {
    fn global_len(&self) -> usize {
        self.cameras * self.per_camera() + 6 * (self.cameras - 1)
    }

    fn view_count(&self) -> usize {
        self.views.len()
    }

    fn view_len(&self) -> usize {
        6
    }

    fn residuals(&self, g: &[f64], view: usize, v: &[f64], out: &mut Vec<f64>) -> Option<()> {
        let cam0_from_target = params_to_pose(v);
        let rv = &self.views[view];
        for &(c, i, px) in &rv.observations {
            let (intr, dist) = self.camera_params(g, c);
            let pc = self.cam_from_cam0(g, c) * (cam0_from_target * rv.target[i]);
            if !(pc.z > 0.0) {
                return None;
            }
            let d = dist.distort(nalgebra::Vector2::new(pc.x / pc.z, pc.y / pc.z));
            out.push(intr.fx * d.x + intr.cx - px.x);
            out.push(intr.fy * d.y + intr.cy - px.y);
        }
        Some(())
    }

    fn global_step(&self, k: usize, x: f64) -> f64 {
        let pc = self.per_camera();
        if k < self.cameras * pc && k % pc >= 4 {
            1e-7 // distortion coefficients
        } else {
            1e-6 * x.abs().max(1e-3)
        }
    }
}

/// Calibrates a rig of `sizes.len()` cameras (image sizes in pixels) from views of a target.
pub fn calibrate_rig(
    sizes: &[(u32, u32)],
    views: &[RigView],
    model: DistortionModel,
) -> Result<Calibration, GeometryError> {
    let cams = sizes.len();
    if cams == 0 {
        return Err(GeometryError::TooFewPoints {
            what: "calibration (cameras)".into(),
            needed: 1,
            got: 0,
        });
    }
    if views.is_empty() {
        return Err(GeometryError::TooFewPoints {
            what: "calibration (views)".into(),
            needed: 1,
            got: 0,
        });
    }
    for (vi, v) in views.iter().enumerate() {
        for (i, p) in v.target.iter().enumerate() {
            if !p.coords.iter().all(|x| x.is_finite()) {
                return Err(GeometryError::Degenerate(format!(
                    "view {vi}: target point {i} is not finite"
                )));
            }
        }
        for &(c, i, px) in &v.observations {
            if c >= cams {
                return Err(GeometryError::Degenerate(format!(
                    "view {vi}: observation of camera {c}, but the rig has {cams}"
                )));
            }
            if i >= v.target.len() {
                return Err(GeometryError::Degenerate(format!(
                    "view {vi}: observation of point {i}, but the view has {}",
                    v.target.len()
                )));
            }
            if !(px.x.is_finite() && px.y.is_finite()) {
                return Err(GeometryError::Degenerate(format!(
                    "view {vi}: the pixel of point {i} in camera {c} is not finite"
                )));
            }
        }
    }
    // Linear start per camera, over the views it sees.
    let mut ks = Vec::with_capacity(cams);
    let mut cam_from_target: Vec<Vec<Option<Isometry3<f64>>>> = vec![vec![None; views.len()]; cams];
    for c in 0..cams {
        let seen: Vec<usize> = (0..views.len())
            .filter(|&v| views[v].observations.iter().any(|o| o.0 == c))
            .collect();
        let data: Vec<ViewPoints> = seen
            .iter()
            .map(|&v| {
                let obs: Vec<&(usize, usize, Point2<f64>)> =
                    views[v].observations.iter().filter(|o| o.0 == c).collect();
                (
                    obs.iter().map(|o| views[v].target[o.1]).collect(),
                    obs.iter().map(|o| o.2).collect(),
                )
            })
            .collect();
        if data.is_empty() {
            return Err(GeometryError::Degenerate(format!(
                "camera {c} has no observations"
            )));
        }
        let (k, poses) = initial_camera(&data, c)?;
        for (&v, p) in seen.iter().zip(poses) {
            cam_from_target[c][v] = Some(p);
        }
        ks.push(k);
    }
    // Camera c relative to camera 0, from the shared view with most observations.
    let mut rel = vec![Isometry3::identity(); cams];
    for c in 1..cams {
        let best = (0..views.len())
            .filter(|&v| cam_from_target[0][v].is_some() && cam_from_target[c][v].is_some())
            .max_by_key(|&v| {
                views[v]
                    .observations
                    .iter()
                    .filter(|o| o.0 == 0 || o.0 == c)
                    .count()
            })
            .ok_or_else(|| {
                GeometryError::Degenerate(format!(
                    "camera {c} shares no view with camera 0: their relative pose is unknown"
                ))
            })?;
        if let (Some(a), Some(b)) = (cam_from_target[c][best], cam_from_target[0][best]) {
            rel[c] = a * b.inverse();
        }
    }
    let mut vparams: Vec<Vec<f64>> = Vec::with_capacity(views.len());
    for v in 0..views.len() {
        let pose = (0..cams)
            .find_map(|c| cam_from_target[c][v].map(|p| rel[c].inverse() * p))
            .ok_or_else(|| GeometryError::Degenerate(format!("view {v} is seen by no camera")))?;
        vparams.push(pose_to_params(&pose).to_vec());
    }
    let problem = RigProblem {
        views,
        cameras: cams,
        model,
    };
    let mut g = Vec::with_capacity(problem.global_len());
    for k in &ks {
        g.extend_from_slice(&[k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]]);
        g.extend(std::iter::repeat_n(0.0, model.len()));
    }
    for r in rel.iter().skip(1) {
        g.extend_from_slice(&pose_to_params(r));
    }
    let report = lm::solve(&problem, &mut g, &mut vparams, 200);
    if !report.final_cost.is_finite() {
        return Err(GeometryError::Solver(
            "the refinement met a point behind a camera at the start".into(),
        ));
    }
    // Residuals and statistics.
    let mut residuals = Vec::new();
    let mut buf = Vec::new();
    for (v, vp) in vparams.iter().enumerate() {
        buf.clear();
        problem
            .residuals(&g, v, vp, &mut buf)
            .ok_or_else(|| GeometryError::Solver(format!("view {v} ended behind a camera")))?;
        for (k, &(c, i, _)) in views[v].observations.iter().enumerate() {
            residuals.push(PointResidual {
                view: v,
                camera: c,
                point: i,
                du_px: buf[2 * k],
                dv_px: buf[2 * k + 1],
            });
        }
    }
    let sq = |r: &PointResidual| r.du_px * r.du_px + r.dv_px * r.dv_px;
    let rms_px = (residuals.iter().map(sq).sum::<f64>() / residuals.len().max(1) as f64).sqrt();
    let unknowns = problem.global_len() + 6 * views.len();
    let dof = report.residual_count.saturating_sub(unknowns);
    let variance = if dof > 0 {
        report.final_cost / dof as f64
    } else {
        f64::NAN
    };
    let mut cameras = Vec::with_capacity(cams);
    for (c, &(w, h)) in sizes.iter().enumerate() {
        let (mut intr, dist) = problem.camera_params(&g, c);
        intr.width = w;
        intr.height = h;
        let intr = Intrinsics::new(intr.fx, intr.fy, intr.cx, intr.cy, w, h)?;
        let o = c * problem.per_camera();
        let sd = |k: usize| {
            report
                .global_inverse
                .as_ref()
                .map(|inv| (inv[(o + k, o + k)] * variance).max(0.0).sqrt())
                .filter(|v| v.is_finite())
        };
        let mut std_dev = [None; 9];
        for (k, slot) in std_dev.iter_mut().enumerate().take(4) {
            *slot = sd(k);
        }
        // Distortion slots: k1, k2, p1, p2, k3 in the std_dev order fx fy cx cy k1 k2 p1 p2 k3.
        for k in 0..model.len() {
            std_dev[4 + k] = sd(4 + k);
        }
        let mine: Vec<&PointResidual> = residuals.iter().filter(|r| r.camera == c).collect();
        let cam_rms = (mine.iter().map(|r| sq(r)).sum::<f64>() / mine.len().max(1) as f64).sqrt();
        cameras.push(CalibratedCamera {
            intrinsics: intr,
            distortion: dist,
            std_dev,
            rms_px: cam_rms,
            cam_from_cam0: problem.cam_from_cam0(&g, c),
        });
    }
    Ok(Calibration {
        cameras,
        cam0_from_target: vparams.iter().map(|v| params_to_pose(v)).collect(),
        rms_px,
        residuals,
        iterations: report.iterations,
    })
}

/// Calibrates one camera from views given as `(target point, pixel)` lists.
pub fn calibrate_camera(
    width: u32,
    height: u32,
    views: &[Vec<(Point3<f64>, Point2<f64>)>],
    model: DistortionModel,
) -> Result<Calibration, GeometryError> {
    let rig_views: Vec<RigView> = views
        .iter()
        .map(|v| RigView {
            target: v.iter().map(|p| p.0).collect(),
            observations: v.iter().enumerate().map(|(i, p)| (0, i, p.1)).collect(),
        })
        .collect();
    calibrate_rig(&[(width, height)], &rig_views, model)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::transform::look_at;
    use stereoscope_numeric::SplitMix64;

    use crate::synthetic::{ViewSpread, calibration_views, example_camera, grid};

    fn truth() -> Camera {
        example_camera()
    }

    /// Views of a 10 × 10 grid (10 cm) from varied poses, pixels with Gaussian noise.
    fn synthetic_views(
        cam: &Camera,
        n: usize,
        noise_px: f64,
        seed: u64,
    ) -> Vec<Vec<(Point3<f64>, Point2<f64>)>> {
        let spread = ViewSpread {
            lateral_m: 0.8,
            distance_m: (1.4, 2.2),
            aim_jitter_m: 0.1,
            roll: 0.3,
        };
        calibration_views(cam, &grid(10, 10, 0.1), n, &spread, noise_px, seed)
    }

    /// k1 k2 p1 p2 with k3 fixed (the example lens has k3 = 0): the four terms come back, k3
    /// stays exactly 0 with no uncertainty, and the fit is as good as the full model's.
    #[test]
    fn the_tangential_model_keeps_k3_at_zero() {
        let cam = truth();
        let views = synthetic_views(&cam, 12, 0.1, 7);
        let cal = calibrate_camera(640, 480, &views, DistortionModel::Tangential).unwrap();
        let c = &cal.cameras[0];
        let d = c.distortion;
        assert_eq!(d.k3, 0.0);
        assert!(
            c.std_dev[8].is_none() && c.std_dev[7].is_some(),
            "{:?}",
            c.std_dev
        );
        // Each term within four of its reported standard deviations of the lens's.
        for (k, got, want) in [
            (4, d.k1, -0.18),
            (5, d.k2, 0.07),
            (6, d.p1, 0.0008),
            (7, d.p2, -0.0005),
        ] {
            let sd = c.std_dev[k].unwrap();
            assert!(
                (got - want).abs() < 4.0 * sd,
                "term {k}: {got} vs {want} (sd {sd})"
            );
        }
        let full = calibrate_camera(640, 480, &views, DistortionModel::Full).unwrap();
        assert!(
            cal.rms_px < full.rms_px * 1.01 + 1e-6,
            "{} vs {}",
            cal.rms_px,
            full.rms_px
        );
        // Nested models: without p1 p2 the fit can only be worse.
        let radial = calibrate_camera(640, 480, &views, DistortionModel::Radial).unwrap();
        assert!(
            radial.rms_px >= cal.rms_px,
            "{} vs {}",
            radial.rms_px,
            cal.rms_px
        );
    }

    #[test]
    fn recovers_a_synthetic_camera_to_a_tenth_of_a_percent() {
        let cam = truth();
        let views = synthetic_views(&cam, 12, 0.1, 7);
        let cal = calibrate_camera(640, 480, &views, DistortionModel::Full).unwrap();
        let c = &cal.cameras[0];
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        assert!(rel(c.intrinsics.fx, 812.0) < 1e-3, "fx {}", c.intrinsics.fx);
        assert!(rel(c.intrinsics.fy, 798.0) < 1e-3, "fy {}", c.intrinsics.fy);
        assert!((c.intrinsics.cx - 322.5).abs() < 1.0 && (c.intrinsics.cy - 236.0).abs() < 1.0);
        assert!(
            (c.distortion.k1 + 0.18).abs() < 0.01,
            "k1 {}",
            c.distortion.k1
        );
        // RMS near the noise (0.1 px per axis → 0.14 px per point).
        assert!(cal.rms_px > 0.1 && cal.rms_px < 0.2, "rms {}", cal.rms_px);
        // The reported uncertainty is honest: the error is within a few standard deviations.
        let sd_fx = c.std_dev[0].unwrap();
        assert!(
            sd_fx > 0.0 && (c.intrinsics.fx - 812.0).abs() < 5.0 * sd_fx,
            "fx {} ± {sd_fx}",
            c.intrinsics.fx
        );
        assert_eq!(
            cal.residuals.len(),
            views.iter().map(|v| v.len()).sum::<usize>()
        );
    }

    #[test]
    fn non_planar_target_uses_the_dlt_start() {
        let cam = truth();
        let mut rng = SplitMix64::new(11);
        let pts: Vec<Point3<f64>> = (0..40)
            .map(|_| {
                Point3::new(
                    rng.range(-0.5, 0.5),
                    rng.range(-0.4, 0.4),
                    rng.range(-0.3, 0.3),
                )
            })
            .collect();
        let w = look_at(Point3::new(0.2, 0.1, 2.0), Point3::origin(), Vector3::y()).unwrap();
        let c = Camera {
            cam_from_world: w.inverse(),
            ..cam
        };
        let view: Vec<(Point3<f64>, Point2<f64>)> =
            pts.iter().map(|p| (*p, c.project(p).unwrap())).collect();
        let cal = calibrate_camera(640, 480, &[view], DistortionModel::Full).unwrap();
        assert!(cal.rms_px < 1e-6, "{}", cal.rms_px);
        assert!((cal.cameras[0].intrinsics.fx - 812.0).abs() < 1e-3);
    }

    #[test]
    fn stereo_rig_gives_relative_pose() {
        let cam = truth();
        let target = grid(9, 7, 0.1);
        let right_from_left = Isometry3::new(
            Vector3::new(-0.2, 0.0, -0.025),
            Vector3::new(0.0, 0.05, 0.0),
        );
        let mut rng = SplitMix64::new(5);
        let mut views = Vec::new();
        for _ in 0..8 {
            let pos = Point3::new(
                0.4 + rng.range(-0.6, 0.6),
                0.3 + rng.range(-0.6, 0.6),
                rng.range(1.5, 2.0),
            );
            let left_from_target = look_at(
                pos,
                Point3::new(0.4, 0.3, 0.0),
                Vector3::new(rng.range(-0.2, 0.2), 1.0, 0.0),
            )
            .unwrap()
            .inverse();
            let mut obs = Vec::new();
            for (c, cam_from_target) in [
                (0usize, left_from_target),
                (1, right_from_left * left_from_target),
            ] {
                let cc = Camera {
                    cam_from_world: cam_from_target,
                    ..cam
                };
                for (i, p) in target.iter().enumerate() {
                    if let Some(px) = cc.project(p) {
                        obs.push((
                            c,
                            i,
                            Point2::new(px.x + 0.1 * rng.normal(), px.y + 0.1 * rng.normal()),
                        ));
                    }
                }
            }
            views.push(RigView {
                target: target.clone(),
                observations: obs,
            });
        }
        let cal = calibrate_rig(&[(640, 480), (640, 480)], &views, DistortionModel::Full).unwrap();
        let got = cal.cameras[1].cam_from_cam0;
        assert!(
            (got.translation.vector - right_from_left.translation.vector).norm() < 2e-3,
            "{got:?}"
        );
        // 0.1 px noise over 8 views: about 0.05° of rotation.
        assert!(
            got.rotation.angle_to(&right_from_left.rotation) < 3e-3,
            "{got:?} {} {:?}",
            cal.rms_px,
            cal.cameras[1].intrinsics
        );
        assert!(cal.rms_px < 0.2);
    }

    #[test]
    fn degenerate_inputs_say_what_is_wrong() {
        let cam = truth();
        let views = synthetic_views(&cam, 3, 0.0, 1);
        let err = |r: Result<Calibration, GeometryError>| r.unwrap_err().to_string();
        // A single planar view.
        assert!(
            err(calibrate_camera(
                640,
                480,
                &views[..1],
                DistortionModel::Full
            ))
            .contains("single planar view")
        );
        // Too few points.
        let few = vec![
            vec![views[0][0], views[0][1], views[0][10]],
            views[1].clone(),
        ];
        assert!(
            err(calibrate_camera(640, 480, &few, DistortionModel::Full))
                .contains("view 0 of camera 0 needs at least 4")
        );
        // Collinear.
        let line: Vec<(Point3<f64>, Point2<f64>)> = (0..8)
            .map(|i| {
                (
                    Point3::new(i as f64, 0.0, 0.0),
                    Point2::new(10.0 * i as f64, 5.0),
                )
            })
            .collect();
        assert!(
            err(calibrate_camera(
                640,
                480,
                &[line, views[1].clone()],
                DistortionModel::Full
            ))
            .contains("collinear")
        );
        // NaN.
        let mut nan = views.clone();
        nan[1][3].1.x = f64::NAN;
        assert!(
            err(calibrate_camera(640, 480, &nan, DistortionModel::Full)).contains("not finite")
        );
        // No views.
        assert!(calibrate_camera(640, 480, &[], DistortionModel::Full).is_err());
        // Two identical views cannot fix the intrinsics.
        let same = vec![views[0].clone(), views[0].clone()];
        assert!(calibrate_camera(640, 480, &same, DistortionModel::Full).is_err());
    }
}
