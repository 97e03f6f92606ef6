//! An object's heading in the world from its blob's principal axis in one or more cameras.
//!
//! Thesis: §4.1.1 recovers the orientation as the image angle of Eq. 4.14b; that is the
//! heading only for a camera looking straight down with square pixels. Here the blob's major
//! axis (angle from `stereoscope_vision::moments`, PAR-corrected, counter-clockwise on screen)
//! is back-projected onto the horizontal plane through the object's recovered 3D point: two
//! image points along the axis, their rays cut with the plane `z = z_object`, and the direction
//! between the cuts is the heading — degrees counter-clockwise from the world +x axis seen from
//! above (+z up), `docs/geometry.md`. Views from several cameras are fused by a weighted
//! circular mean: of the doubled angles for axes (which have no direction), of the angles
//! themselves when a view knows the direction (third-order moments).

use crate::camera::Camera;
use nalgebra::{Point2, Point3, Vector2};

/// The pixel-space direction of a major axis at `angle_deg` (CCW on screen, measured on
/// physical pixel units) for pixels with aspect ratio `par` (width / height).
pub fn axis_pixel_direction(angle_deg: f64, par: f64) -> Vector2<f64> {
    let t = angle_deg.to_radians();
    Vector2::new(t.cos() / par, -t.sin()).normalize()
}

/// The world heading, in [0, 360), of the direction `axis_px` (pixels) from `centroid_px`, for
/// an object at `point_world`. `None` when the view is edge-on to the horizontal plane.
pub fn world_direction_deg(
    camera: &Camera,
    centroid_px: Point2<f64>,
    axis_px: Vector2<f64>,
    point_world: &Point3<f64>,
) -> Option<f64> {
    let cut = |px: Point2<f64>| -> Option<Point3<f64>> {
        let (o, d) = camera.ray_world(px)?;
        if d.z.abs() < 1e-9 {
            return None;
        }
        let t = (point_world.z - o.z) / d.z;
        (t > 0.0).then(|| o + d.into_inner() * t)
    };
    let step = 5.0;
    let (a, b) = (
        cut(centroid_px - axis_px * step)?,
        cut(centroid_px + axis_px * step)?,
    );
    let v = b - a;
    if v.xy().norm() < 1e-12 {
        return None;
    }
    Some(v.y.atan2(v.x).to_degrees().rem_euclid(360.0))
}

/// One camera's view of the object's axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisView {
    pub camera: usize,
    pub centroid_px: Point2<f64>,
    /// Major-axis angle in the image, degrees CCW on screen (PAR-corrected), or the direction
    /// in [0, 360) when `directed`.
    pub angle_deg: f64,
    pub directed: bool,
    /// Confidence, e.g. 1 − roundness; 0 ignores the view.
    pub weight: f64,
}

/// A fused world heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldHeading {
    /// Degrees: [0, 360) when `directed`, else [0, 180) (an axis).
    pub heading_deg: f64,
    pub directed: bool,
    /// Weighted circular spread of the views, degrees (0 when they agree).
    pub spread_deg: f64,
    pub views_used: usize,
}

/// Fuses the views of one object at `point_world` (module docs).
pub fn fuse(
    cams: &[Camera],
    views: &[AxisView],
    point_world: &Point3<f64>,
) -> Option<WorldHeading> {
    let mut per_view = Vec::new();
    for v in views {
        if !(v.weight > 0.0) || v.camera >= cams.len() {
            continue;
        }
        let cam = &cams[v.camera];
        let dir = axis_pixel_direction(v.angle_deg, cam.intrinsics.par());
        if let Some(h) = world_direction_deg(cam, v.centroid_px, dir, point_world) {
            per_view.push((h, v.directed, v.weight));
        }
    }
    if per_view.is_empty() {
        return None;
    }
    let directed = per_view.iter().any(|v| v.1);
    let mean = |items: &[(f64, f64)], factor: f64| -> (f64, f64) {
        let (mut s, mut c, mut w) = (0.0, 0.0, 0.0);
        for &(a, wt) in items {
            let r = (a * factor).to_radians();
            s += wt * r.sin();
            c += wt * r.cos();
            w += wt;
        }
        let r = (s * s + c * c).sqrt() / w;
        let spread = (-2.0 * r.max(1e-300).ln()).sqrt().to_degrees() / factor;
        (
            (s.atan2(c).to_degrees() / factor).rem_euclid(360.0 / factor),
            spread,
        )
    };
    let (heading_deg, spread_deg) = if directed {
        let dir_views: Vec<(f64, f64)> = per_view
            .iter()
            .filter(|v| v.1)
            .map(|v| (v.0, v.2))
            .collect();
        let (ref_dir, _) = mean(&dir_views, 1.0);
        // Axis views take the half turn nearest the directed mean.
        let all: Vec<(f64, f64)> = per_view
            .iter()
            .map(|&(h, d, w)| {
                if d {
                    (h, w)
                } else {
                    let diff = (h - ref_dir + 180.0).rem_euclid(360.0) - 180.0;
                    (if diff.abs() > 90.0 { h + 180.0 } else { h }, w)
                }
            })
            .collect();
        mean(&all, 1.0)
    } else {
        let axes: Vec<(f64, f64)> = per_view.iter().map(|v| (v.0, v.2)).collect();
        mean(&axes, 2.0)
    };
    Some(WorldHeading {
        heading_deg,
        directed,
        spread_deg,
        views_used: per_view.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Distortion, Intrinsics};
    use crate::transform::look_at;
    use nalgebra::Vector3;

    fn cams() -> Vec<Camera> {
        let intr = Intrinsics::new(581.0, 500.0, 159.5, 119.5, 320, 240).unwrap(); // PAR 0.86
        let down = look_at(
            Point3::new(0.0, 0.0, 2.775),
            Point3::new(0.0, 0.0, 0.0),
            Vector3::y(),
        )
        .unwrap();
        let oblique = look_at(
            Point3::new(1.5, -1.0, 2.0),
            Point3::new(0.0, 0.0, 0.0),
            Vector3::z(),
        )
        .unwrap();
        vec![
            Camera::new(intr, Distortion::default(), down.inverse()).unwrap(),
            Camera::new(
                intr,
                Distortion {
                    k1: -0.1,
                    ..Default::default()
                },
                oblique.inverse(),
            )
            .unwrap(),
        ]
    }

    /// The image angle (CCW on screen, PAR-corrected) of a world segment, as moments would
    /// measure it.
    fn image_view(cam: &Camera, p: &Point3<f64>, heading_deg: f64) -> (Point2<f64>, f64) {
        let h = heading_deg.to_radians();
        let d = Vector3::new(h.cos(), h.sin(), 0.0) * 0.01;
        let (a, b) = (
            cam.project(&(p - d)).unwrap(),
            cam.project(&(p + d)).unwrap(),
        );
        let par = cam.intrinsics.par();
        let angle = (-(b.y - a.y)).atan2((b.x - a.x) * par).to_degrees();
        (cam.project(p).unwrap(), angle)
    }

    #[test]
    fn heading_is_recovered_from_down_and_oblique_cameras() {
        let cams = cams();
        let p = Point3::new(0.2, 0.1, 0.3);
        for heading in [0.0, 17.0, 45.0, 90.0, 133.0, 200.0, 300.0] {
            for (ci, cam) in cams.iter().enumerate() {
                let (c, angle) = image_view(cam, &p, heading);
                let got = world_direction_deg(
                    cam,
                    c,
                    axis_pixel_direction(angle, cam.intrinsics.par()),
                    &p,
                )
                .unwrap();
                let diff = ((got - heading) % 360.0 + 360.0) % 360.0;
                // The oblique camera has distortion: a straight edge images slightly curved.
                assert!(
                    diff < 1e-3 || (diff - 360.0).abs() < 1e-3,
                    "camera {ci} heading {heading}: {got}"
                );
            }
        }
    }

    #[test]
    fn fusion_of_axes_and_of_directions() {
        let cams = cams();
        let p = Point3::new(-0.1, 0.2, 0.1);
        let heading = 250.0;
        let views: Vec<AxisView> = cams
            .iter()
            .enumerate()
            .map(|(i, cam)| {
                let (c, angle) = image_view(cam, &p, heading);
                // As moments give it: an axis in (−90, 90].
                let axis = if angle > 90.0 {
                    angle - 180.0
                } else if angle <= -90.0 {
                    angle + 180.0
                } else {
                    angle
                };
                AxisView {
                    camera: i,
                    centroid_px: c,
                    angle_deg: axis,
                    directed: false,
                    weight: 1.0,
                }
            })
            .collect();
        let f = fuse(&cams, &views, &p).unwrap();
        assert!(
            !f.directed && (f.heading_deg - 70.0).abs() < 1e-3 && f.spread_deg < 1e-3,
            "{f:?}"
        );
        // One camera knows the direction: the fused heading takes the right half turn.
        let mut v2 = views.clone();
        let (c, angle) = image_view(&cams[1], &p, heading);
        v2[1] = AxisView {
            camera: 1,
            centroid_px: c,
            angle_deg: angle.rem_euclid(360.0),
            directed: true,
            weight: 1.0,
        };
        let f = fuse(&cams, &v2, &p).unwrap();
        assert!(f.directed && (f.heading_deg - 250.0).abs() < 1e-3, "{f:?}");
        assert_eq!(fuse(&cams, &[], &p), None);
    }
}
