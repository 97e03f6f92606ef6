//! The pinhole camera with lens distortion.
//!
//! Thesis: Eq. 2.4–2.6 (world → camera: `cam_from_world`), Eq. 2.7 (perspective projection
//! `x_i = f·x_c/z_c`), Eq. 2.8 (to pixels: `x_d = x_i/d_x + c_x`, so `fx = f/d_x`,
//! `fy = f/d_y` and the pixel aspect ratio PAR = d_x/d_y = fy/fx). The thesis ignores lens
//! distortion (§2.2.2); here the usual Brown–Conrady terms are added (radial k1 k2 k3,
//! tangential p1 p2, the same parametrisation as OpenCV), applied to normalised coordinates
//! between Eq. 2.7 and Eq. 2.8.
//!
//! Frames: camera x right, y down, z forward; pixels as in `docs/conventions.md` (centres at
//! integers). A pixel `(u, v)` is `u = fx·x_d + cx`, `v = fy·y_d + cy` where `(x_d, y_d)` is
//! the distorted normalised coordinate of `(x/z, y/z)`.

use crate::error::GeometryError;
use nalgebra::{Isometry3, Matrix2, Matrix3, Point2, Point3, Unit, Vector2, Vector3};

/// Focal lengths and principal point in pixels, and the image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Checks every value: focal lengths finite and positive, principal point finite, size
    /// non-zero.
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
    ) -> Result<Self, GeometryError> {
        for (field, v) in [("fx", fx), ("fy", fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(GeometryError::InvalidCamera {
                    field,
                    value: v,
                    reason: "must be a finite number above zero",
                });
            }
        }
        for (field, v) in [("cx", cx), ("cy", cy)] {
            if !v.is_finite() {
                return Err(GeometryError::InvalidCamera {
                    field,
                    value: v,
                    reason: "must be finite",
                });
            }
        }
        if width == 0 || height == 0 {
            return Err(GeometryError::InvalidCamera {
                field: "image_size",
                value: (width.min(height)) as f64,
                reason: "width and height must be at least 1",
            });
        }
        Ok(Intrinsics {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
        })
    }

    /// Eq. 2.8: from the focal length and the pixel pitch (same length unit), principal point
    /// at the image centre unless given.
    pub fn from_focal_length(
        focal_length: f64,
        pixel_width: f64,
        pixel_height: f64,
        width: u32,
        height: u32,
        principal_point: Option<(f64, f64)>,
    ) -> Result<Self, GeometryError> {
        for (field, v) in [
            ("focal_length", focal_length),
            ("pixel_width", pixel_width),
            ("pixel_height", pixel_height),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(GeometryError::InvalidCamera {
                    field,
                    value: v,
                    reason: "must be a finite number above zero",
                });
            }
        }
        let (cx, cy) =
            principal_point.unwrap_or(((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0));
        Self::new(
            focal_length / pixel_width,
            focal_length / pixel_height,
            cx,
            cy,
            width,
            height,
        )
    }

    /// Pixel aspect ratio, pixel width / pixel height = fy / fx.
    pub fn par(&self) -> f64 {
        self.fy / self.fx
    }

    /// The camera matrix K.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    pub fn to_pixel(&self, normalised: Vector2<f64>) -> Point2<f64> {
        Point2::new(
            self.fx * normalised.x + self.cx,
            self.fy * normalised.y + self.cy,
        )
    }

    pub fn to_normalised(&self, pixel: Point2<f64>) -> Vector2<f64> {
        Vector2::new((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy)
    }
}

/// Brown–Conrady lens distortion on normalised coordinates (OpenCV's k1 k2 p1 p2 k3).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub k3: f64,
    pub p1: f64,
    pub p2: f64,
}

impl Distortion {
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.k3 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0
    }

    pub fn validate(&self) -> Result<(), GeometryError> {
        for (field, v) in [
            ("k1", self.k1),
            ("k2", self.k2),
            ("k3", self.k3),
            ("p1", self.p1),
            ("p2", self.p2),
        ] {
            if !v.is_finite() {
                return Err(GeometryError::InvalidCamera {
                    field,
                    value: v,
                    reason: "must be finite",
                });
            }
        }
        Ok(())
    }

    /// Ideal normalised coordinate → distorted.
    pub fn distort(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Jacobian of [`Distortion::distort`].
    pub fn jacobian(&self, p: Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (p.x, p.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let dr = self.k1 + 2.0 * self.k2 * r2 + 3.0 * self.k3 * r2 * r2; // d radial / d r2
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        )
    }

    /// Distorted normalised coordinate → ideal, by Newton's method (converges to machine
    /// precision inside the lens's monotonic range). `None` if it does not converge.
    pub fn undistort(&self, d: Vector2<f64>) -> Option<Vector2<f64>> {
        if self.is_zero() {
            return Some(d);
        }
        let mut p = d;
        for _ in 0..50 {
            let e = self.distort(p) - d;
            if e.norm() < 1e-15 {
                return Some(p);
            }
            let step = self.jacobian(p).try_inverse()? * e;
            p -= step;
            if !p.x.is_finite() || !p.y.is_finite() {
                return None;
            }
        }
        ((self.distort(p) - d).norm() < 1e-10).then_some(p)
    }
}

/// A calibrated camera: intrinsics, distortion and where it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub intrinsics: Intrinsics,
    pub distortion: Distortion,
    pub cam_from_world: Isometry3<f64>,
}

impl Camera {
    pub fn new(
        intrinsics: Intrinsics,
        distortion: Distortion,
        cam_from_world: Isometry3<f64>,
    ) -> Result<Self, GeometryError> {
        distortion.validate()?;
        Ok(Camera {
            intrinsics,
            distortion,
            cam_from_world,
        })
    }

    /// The optical centre in world coordinates.
    pub fn position_world(&self) -> Point3<f64> {
        self.cam_from_world.inverse() * Point3::origin()
    }

    /// Eq. 2.7 + distortion + Eq. 2.8 for a point in camera coordinates; `None` behind the
    /// camera (z ≤ 0).
    pub fn project_cam(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        if !(p.z > 0.0) {
            return None;
        }
        let n = Vector2::new(p.x / p.z, p.y / p.z);
        Some(self.intrinsics.to_pixel(self.distortion.distort(n)))
    }

    /// Eq. 2.4–2.8 for a point in world coordinates.
    pub fn project(&self, p_world: &Point3<f64>) -> Option<Point2<f64>> {
        self.project_cam(&(self.cam_from_world * p_world))
    }

    /// The ideal (undistorted) normalised coordinate `(x/z, y/z)` of a pixel.
    pub fn normalised(&self, pixel: Point2<f64>) -> Option<Vector2<f64>> {
        self.distortion
            .undistort(self.intrinsics.to_normalised(pixel))
    }

    /// Where the pixel would be without lens distortion.
    pub fn undistort_pixel(&self, pixel: Point2<f64>) -> Option<Point2<f64>> {
        self.normalised(pixel).map(|n| self.intrinsics.to_pixel(n))
    }

    /// The ray through a pixel: the optical centre and the unit direction, in world
    /// coordinates.
    pub fn ray_world(&self, pixel: Point2<f64>) -> Option<(Point3<f64>, Unit<Vector3<f64>>)> {
        let n = self.normalised(pixel)?;
        let world_from_cam = self.cam_from_world.inverse();
        let dir = world_from_cam.rotation * Vector3::new(n.x, n.y, 1.0);
        Some((world_from_cam * Point3::origin(), Unit::new_normalize(dir)))
    }

    /// The 3×4 projection matrix K·[R|t] of the undistorted camera.
    pub fn projection_matrix(&self) -> nalgebra::Matrix3x4<f64> {
        let rt = self
            .cam_from_world
            .to_homogeneous()
            .fixed_view::<3, 4>(0, 0)
            .into_owned();
        self.intrinsics.k() * rt
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::look_at;

    fn camera(dist: Distortion) -> Camera {
        let intr =
            Intrinsics::from_focal_length(0.0125, 0.0000215, 0.000025, 320, 240, None).unwrap();
        let world_from_cam = look_at(
            Point3::new(0.1, 0.0, 2.775),
            Point3::new(0.1, 0.0, 0.0),
            Vector3::y(),
        )
        .unwrap();
        Camera::new(intr, dist, world_from_cam.inverse()).unwrap()
    }

    #[test]
    fn eq_2_8_focal_length_and_pitch_give_pixels_and_par() {
        let c = camera(Distortion::default());
        assert!((c.intrinsics.fx - 0.0125 / 0.0000215).abs() < 1e-9);
        assert!((c.intrinsics.par() - 0.86).abs() < 1e-12);
        // The point below the camera images at the principal point.
        let p = c.project(&Point3::new(0.1, 0.0, 0.0)).unwrap();
        assert!((p.x - 159.5).abs() < 1e-9 && (p.y - 119.5).abs() < 1e-9);
    }

    #[test]
    fn project_and_back_project_round_trip_with_distortion() {
        let dist = Distortion {
            k1: -0.21,
            k2: 0.08,
            k3: -0.01,
            p1: 0.0012,
            p2: -0.0007,
        };
        let c = camera(dist);
        for &(x, y, z) in &[
            (0.0, 0.0, 0.0),
            (0.4, 0.3, 0.1),
            (-0.5, 0.45, 0.6),
            (0.6, -0.5, 1.5),
        ] {
            let p = Point3::new(x, y, z);
            let px = c.project(&p).unwrap();
            let (o, d) = c.ray_world(px).unwrap();
            // The point lies on the ray.
            let v = p - o;
            let off = (v - d.into_inner() * v.dot(&d)).norm();
            assert!(off < 1e-9, "{off}");
        }
        // Undistort ∘ distort is the identity over the image.
        for &(u, v) in &[(0.0, 0.0), (319.0, 239.0), (10.0, 200.0), (160.0, 120.0)] {
            let px = Point2::new(u, v);
            let ideal = c.undistort_pixel(px).unwrap();
            let n = c.intrinsics.to_normalised(ideal);
            let back = c.intrinsics.to_pixel(c.distortion.distort(n));
            assert!((back - px).norm() < 1e-9);
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let d = Distortion {
            k1: -0.3,
            k2: 0.1,
            k3: 0.02,
            p1: 0.003,
            p2: -0.002,
        };
        let p = Vector2::new(0.31, -0.22);
        let j = d.jacobian(p);
        let h = 1e-7;
        for k in 0..2 {
            let mut dp = Vector2::zeros();
            dp[k] = h;
            let num = (d.distort(p + dp) - d.distort(p - dp)) / (2.0 * h);
            assert!((num - j.column(k)).norm() < 1e-7);
        }
    }

    #[test]
    fn behind_the_camera_does_not_project_and_bad_values_are_named() {
        let c = camera(Distortion::default());
        assert!(c.project(&Point3::new(0.1, 0.0, 3.0)).is_none());
        let e = Intrinsics::new(-5.0, 10.0, 1.0, 1.0, 10, 10).unwrap_err();
        assert!(e.to_string().contains("fx = -5"));
        assert!(
            Intrinsics::new(5.0, f64::NAN, 1.0, 1.0, 10, 10)
                .unwrap_err()
                .to_string()
                .contains("fy")
        );
        assert!(Intrinsics::new(5.0, 5.0, 1.0, 1.0, 0, 10).is_err());
        assert!(
            Intrinsics::from_focal_length(0.0, 1.0, 1.0, 10, 10, None)
                .unwrap_err()
                .to_string()
                .contains("focal_length")
        );
        let bad = Distortion {
            k1: f64::INFINITY,
            ..Default::default()
        };
        assert!(
            Camera::new(c.intrinsics, bad, c.cam_from_world)
                .unwrap_err()
                .to_string()
                .contains("k1")
        );
    }
}
