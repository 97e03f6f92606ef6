//! 3D points from several calibrated cameras, and the thesis's parallel two-camera rig.
//!
//! Thesis: Eq. 4.28–4.38 (depth from disparity for two parallel, non-identical cameras:
//! focal lengths λ0 ≠ λ1, baseline B, axial offset Δd). The thesis's derivation and its code
//! disagree on the sign of image x and on the offset term (the code adds 2Δd where Eq. 4.38 has
//! Δd/2); [`parallel_rig_point`] is derived once here for the pinhole model and checked against
//! general triangulation on the same rig. Beyond the thesis: [`triangulate`] works for any 2 to
//! 16 calibrated cameras in any poses — linear (DLT) on undistorted normalised coordinates,
//! then Gauss–Newton on the reprojection error in pixels, distortion included.
//!
//! Parallel rig, in camera 0's frame (x right, y down, z forward): camera 1 has the same
//! orientation and its optical centre at `(B, 0, Δd)`. With normalised image coordinates
//! `x_i = (u_i − cx_i)/fx_i`: `x0 = X/Z`, `x1 = (X − B)/(Z − Δd)`, so
//! `Z = (B − x1·Δd)/(x0 − x1)`, `X = x0·Z`, and `Y` is the mean of `y0·Z` and `y1·(Z − Δd)`.
//! The depth from the system reference point midway between the optical centres is
//! `Z − Δd/2`.

use crate::camera::{Camera, Intrinsics};
use crate::error::GeometryError;
use nalgebra::{Matrix2, Matrix2x3, Matrix3, Matrix4, Point2, Point3, Vector2, Vector3};

/// One camera's view of a point: the camera's index and the pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    pub camera: usize,
    pub pixel: Point2<f64>,
}

/// A triangulated point and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct Triangulated {
    pub point_world: Point3<f64>,
    /// RMS reprojection error over the cameras used, pixels.
    pub rms_px: f64,
    /// Reprojection error per observation, pixels, in the order given.
    pub residuals_px: Vec<f64>,
    /// The cameras used.
    pub cameras: Vec<usize>,
}

/// Most cameras a point may be triangulated from.
pub const MAX_CAMERAS: usize = 16;

fn check_observations(cams: &[Camera], obs: &[Observation]) -> Result<(), GeometryError> {
    if obs.len() < 2 {
        return Err(GeometryError::TooFewPoints {
            what: "triangulation (cameras seeing the point)".into(),
            needed: 2,
            got: obs.len(),
        });
    }
    if obs.len() > MAX_CAMERAS {
        return Err(GeometryError::Degenerate(format!(
            "{} observations; at most {MAX_CAMERAS} cameras",
            obs.len()
        )));
    }
    for (i, o) in obs.iter().enumerate() {
        if o.camera >= cams.len() {
            return Err(GeometryError::Degenerate(format!(
                "observation {i} names camera {} of {}",
                o.camera,
                cams.len()
            )));
        }
        if !(o.pixel.x.is_finite() && o.pixel.y.is_finite()) {
            return Err(GeometryError::NotFinite {
                what: "an observed pixel",
            });
        }
        if obs[..i].iter().any(|p| p.camera == o.camera) {
            return Err(GeometryError::Degenerate(format!(
                "camera {} observes the point twice",
                o.camera
            )));
        }
    }
    Ok(())
}

/// Linear triangulation (DLT) on undistorted normalised coordinates; each camera's two rows
/// are scaled by its focal length so the algebraic error is roughly in pixels. The solution
/// is the eigenvector of AᵀA (4 × 4) with the smallest eigenvalue.
pub fn triangulate_dlt(cams: &[Camera], obs: &[Observation]) -> Result<Point3<f64>, GeometryError> {
    check_observations(cams, obs)?;
    let mut ata = Matrix4::<f64>::zeros();
    for o in obs {
        let cam = &cams[o.camera];
        let n = cam.normalised(o.pixel).ok_or_else(|| {
            GeometryError::Degenerate(format!(
                "pixel {:?} of camera {} cannot be undistorted",
                o.pixel, o.camera
            ))
        })?;
        let p = cam.cam_from_world.to_homogeneous();
        let s = 0.5 * (cam.intrinsics.fx + cam.intrinsics.fy);
        let r0 = (p.row(2) * n.x - p.row(0)) * s;
        let r1 = (p.row(2) * n.y - p.row(1)) * s;
        ata += r0.transpose() * r0 + r1.transpose() * r1;
    }
    let eig = ata.symmetric_eigen();
    let imin = crate::index_of_min(eig.eigenvalues.iter().copied());
    let x = eig.eigenvectors.column(imin);
    if x[3].abs() < 1e-12 * x.norm() {
        return Err(GeometryError::Degenerate(
            "the rays are parallel (point at infinity)".into(),
        ));
    }
    Ok(Point3::new(x[0] / x[3], x[1] / x[3], x[2] / x[3]))
}

/// The normal equations JᵀJ, Jᵀr and the cost Σr² of the reprojection error (pixels) at `p`,
/// or `None` if `p` is behind a camera.
fn normal_equations(
    cams: &[Camera],
    obs: &[Observation],
    p: &Point3<f64>,
) -> Option<(Matrix3<f64>, Vector3<f64>, f64)> {
    let (mut jtj, mut jtr, mut cost) = (Matrix3::zeros(), Vector3::zeros(), 0.0);
    for o in obs {
        let cam = &cams[o.camera];
        let pc = cam.cam_from_world * p;
        if !(pc.z > 0.0) {
            return None;
        }
        let n = Vector2::new(pc.x / pc.z, pc.y / pc.z);
        let px = cam.intrinsics.to_pixel(cam.distortion.distort(n));
        let r = Vector2::new(px.x - o.pixel.x, px.y - o.pixel.y);
        // d pixel / d p_world = diag(fx, fy) · J_dist · d n / d p_cam · R
        let dn = Matrix2x3::new(
            1.0 / pc.z,
            0.0,
            -pc.x / (pc.z * pc.z),
            0.0,
            1.0 / pc.z,
            -pc.y / (pc.z * pc.z),
        );
        let k = Matrix2::new(cam.intrinsics.fx, 0.0, 0.0, cam.intrinsics.fy);
        let rot: Matrix3<f64> = *cam.cam_from_world.rotation.to_rotation_matrix().matrix();
        let j = k * cam.distortion.jacobian(n) * dn * rot;
        jtj += j.transpose() * j;
        jtr += j.transpose() * r;
        cost += r.norm_squared();
    }
    Some((jtj, jtr, cost))
}

/// Gauss–Newton (with step halving) on the reprojection error in pixels.
pub fn refine_point(
    cams: &[Camera],
    obs: &[Observation],
    initial: Point3<f64>,
) -> Result<Point3<f64>, GeometryError> {
    check_observations(cams, obs)?;
    let mut p = initial;
    let (mut jtj, mut jtr, mut c) =
        normal_equations(cams, obs, &p).ok_or(GeometryError::BehindCamera {
            camera: obs[0].camera,
        })?;
    for _ in 0..30 {
        let Some(step) = jtj.cholesky().map(|ch| ch.solve(&jtr)) else {
            break;
        };
        let mut t = 1.0;
        let mut improved = false;
        for _ in 0..10 {
            let cand = p - step * t;
            if let Some((a, b, cc)) = normal_equations(cams, obs, &cand)
                && cc <= c
            {
                let done = (c - cc) <= 1e-14 * c.max(1e-30);
                (p, jtj, jtr, c) = (cand, a, b, cc);
                improved = !done;
                break;
            }
            t *= 0.5;
        }
        if !improved {
            break;
        }
    }
    Ok(p)
}

/// Triangulates one point seen by 2–16 cameras: DLT, refined on the reprojection error.
pub fn triangulate(cams: &[Camera], obs: &[Observation]) -> Result<Triangulated, GeometryError> {
    let initial = triangulate_dlt(cams, obs)?;
    let point_world = refine_point(cams, obs, initial).unwrap_or(initial);
    let mut residuals_px = Vec::with_capacity(obs.len());
    for o in obs {
        let cam = &cams[o.camera];
        let px = cam
            .project(&point_world)
            .ok_or(GeometryError::BehindCamera { camera: o.camera })?;
        residuals_px.push((px - o.pixel).norm());
    }
    let rms_px =
        (residuals_px.iter().map(|r| r * r).sum::<f64>() / residuals_px.len() as f64).sqrt();
    Ok(Triangulated {
        point_world,
        rms_px,
        residuals_px,
        cameras: obs.iter().map(|o| o.camera).collect(),
    })
}

/// The thesis's two-camera rig: parallel optical axes, camera 1 at `(B, 0, Δd)` in camera 0's
/// frame, each camera with its own intrinsics (pixels are taken as undistorted).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParallelRig {
    pub cam0: Intrinsics,
    pub cam1: Intrinsics,
    pub baseline_m: f64,
    pub axial_offset_m: f64,
}

/// A point recovered by the parallel rig.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParallelRigPoint {
    /// In camera 0's frame.
    pub point_cam0: Point3<f64>,
    /// Depth from the system reference point midway between the optical centres (Eq. 4.38,
    /// corrected): `Z − Δd/2`.
    pub depth_from_midpoint_m: f64,
}

/// Eq. 4.28–4.38 derived for the pinhole model (module docs).
pub fn parallel_rig_point(
    rig: &ParallelRig,
    pixel0: Point2<f64>,
    pixel1: Point2<f64>,
) -> Result<ParallelRigPoint, GeometryError> {
    let n0 = rig.cam0.to_normalised(pixel0);
    let n1 = rig.cam1.to_normalised(pixel1);
    let disparity = n0.x - n1.x;
    if !(disparity.is_finite()) || disparity.abs() < 1e-12 {
        return Err(GeometryError::Degenerate(
            "zero disparity: the point is at infinity".into(),
        ));
    }
    let z = (rig.baseline_m - n1.x * rig.axial_offset_m) / disparity;
    if !(z > rig.axial_offset_m.max(0.0)) {
        return Err(GeometryError::BehindCamera {
            camera: if z <= 0.0 { 0 } else { 1 },
        });
    }
    let x = n0.x * z;
    let y = 0.5 * (n0.y * z + n1.y * (z - rig.axial_offset_m));
    Ok(ParallelRigPoint {
        point_cam0: Point3::new(x, y, z),
        depth_from_midpoint_m: z - rig.axial_offset_m / 2.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;
    use nalgebra::{Isometry3, Vector3};
    use stereoscope_numeric::SplitMix64;

    fn ring(n: usize, dist: Distortion) -> Vec<Camera> {
        (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                let pos = Point3::new(3.0 * a.cos(), 3.0 * a.sin(), 2.0 + 0.3 * (i % 3) as f64);
                let w = crate::transform::look_at(pos, Point3::new(0.0, 0.0, 0.5), Vector3::z())
                    .unwrap();
                let intr = Intrinsics::new(800.0 + 10.0 * i as f64, 790.0, 320.0, 240.0, 640, 480)
                    .unwrap();
                Camera::new(intr, dist, w.inverse()).unwrap()
            })
            .collect()
    }

    #[test]
    fn exact_from_2_to_16_cameras_and_with_cameras_missing() {
        let dist = Distortion {
            k1: -0.1,
            k2: 0.02,
            ..Default::default()
        };
        for n in [2, 3, 4, 8, 16] {
            let cams = ring(n, dist);
            let p = Point3::new(0.2, -0.3, 0.8);
            // Every other camera only.
            let obs: Vec<Observation> = (0..n)
                .filter(|i| n == 2 || i % 2 == 0)
                .map(|i| Observation {
                    camera: i,
                    pixel: cams[i].project(&p).unwrap(),
                })
                .collect();
            let t = triangulate(&cams, &obs).unwrap();
            assert!(
                (t.point_world - p).norm() < 1e-9,
                "{n} cameras: {:?}",
                t.point_world
            );
            assert!(t.rms_px < 1e-6);
            assert_eq!(t.cameras.len(), obs.len());
        }
    }

    #[test]
    fn refinement_lowers_the_error_on_noisy_views() {
        let cams = ring(
            4,
            Distortion {
                k1: -0.15,
                k2: 0.05,
                ..Default::default()
            },
        );
        let mut rng = SplitMix64::new(3);
        let (mut dlt_err, mut ref_err) = (0.0, 0.0);
        for _ in 0..300 {
            let p = Point3::new(
                rng.range(-0.5, 0.5),
                rng.range(-0.5, 0.5),
                rng.range(0.2, 1.2),
            );
            let obs: Vec<Observation> = (0..4)
                .map(|i| {
                    let px = cams[i].project(&p).unwrap();
                    Observation {
                        camera: i,
                        pixel: Point2::new(px.x + 0.5 * rng.normal(), px.y + 0.5 * rng.normal()),
                    }
                })
                .collect();
            dlt_err += (triangulate_dlt(&cams, &obs).unwrap() - p).norm_squared();
            ref_err += (triangulate(&cams, &obs).unwrap().point_world - p).norm_squared();
        }
        assert!(ref_err < dlt_err, "refined {ref_err} vs DLT {dlt_err}");
    }

    #[test]
    fn parallel_rig_formula_agrees_with_general_triangulation() {
        // The thesis's lab: 12.5 mm lenses on different cameras, 20 cm baseline, Δd 2.5 cm.
        let cam0 = Intrinsics::from_focal_length(0.0125, 21.5e-6, 25e-6, 320, 240, None).unwrap();
        let cam1 =
            Intrinsics::from_focal_length(0.0131, 21.5e-6, 25e-6, 320, 240, Some((161.0, 118.0)))
                .unwrap();
        let rig = ParallelRig {
            cam0,
            cam1,
            baseline_m: 0.20,
            axial_offset_m: 0.025,
        };
        let c0 = Camera::new(cam0, Distortion::default(), Isometry3::identity()).unwrap();
        let c1 = Camera::new(
            cam1,
            Distortion::default(),
            Isometry3::translation(-0.20, 0.0, -0.025),
        )
        .unwrap();
        let cams = [c0, c1];
        for &(x, y, z) in &[
            (0.1, 0.05, 2.7),
            (-0.4, 0.3, 1.2),
            (0.5, -0.5, 2.0),
            (0.0, 0.0, 0.8),
        ] {
            let p = Point3::new(x, y, z);
            let (p0, p1) = (c0.project(&p).unwrap(), c1.project(&p).unwrap());
            let r = parallel_rig_point(&rig, p0, p1).unwrap();
            assert!(
                (r.point_cam0 - p).norm() < 1e-9,
                "{:?} vs {p:?}",
                r.point_cam0
            );
            assert!((r.depth_from_midpoint_m - (z - 0.0125)).abs() < 1e-9);
            let g = triangulate(
                &cams,
                &[
                    Observation {
                        camera: 0,
                        pixel: p0,
                    },
                    Observation {
                        camera: 1,
                        pixel: p1,
                    },
                ],
            )
            .unwrap();
            assert!((g.point_world - r.point_cam0).norm() < 1e-9);
        }
        // Zero disparity is an error, not infinity.
        let p = Point2::new(100.0, 100.0);
        let same = ParallelRig {
            cam1: cam0,
            axial_offset_m: 0.0,
            ..rig
        };
        assert!(parallel_rig_point(&same, p, p).is_err());
    }

    #[test]
    fn bad_observations_are_named() {
        let cams = ring(3, Distortion::default());
        let px = Point2::new(1.0, 2.0);
        let one = [Observation {
            camera: 0,
            pixel: px,
        }];
        assert!(matches!(
            triangulate(&cams, &one),
            Err(GeometryError::TooFewPoints {
                needed: 2,
                got: 1,
                ..
            })
        ));
        let twice = [
            Observation {
                camera: 1,
                pixel: px,
            },
            Observation {
                camera: 1,
                pixel: px,
            },
        ];
        assert!(
            triangulate(&cams, &twice)
                .unwrap_err()
                .to_string()
                .contains("camera 1 observes the point twice")
        );
        let missing = [
            Observation {
                camera: 0,
                pixel: px,
            },
            Observation {
                camera: 7,
                pixel: px,
            },
        ];
        assert!(
            triangulate(&cams, &missing)
                .unwrap_err()
                .to_string()
                .contains("camera 7")
        );
        let nan = [
            Observation {
                camera: 0,
                pixel: px,
            },
            Observation {
                camera: 1,
                pixel: Point2::new(f64::NAN, 0.0),
            },
        ];
        assert!(triangulate(&cams, &nan).is_err());
        let _ = Vector3::<f64>::zeros();
    }
}
