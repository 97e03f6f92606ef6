//! What a synthetic scene holds: targets (shapes with a pose and a brightness), static bright
//! distractors, and the background's light.
//!
//! Shapes are given in their own body frame (metres): the thesis's target is
//! [`Shape::DoubleSphere`], two 40 mm ping-pong balls glued together along the body's x axis;
//! a marker on a VR helmet is a flat [`Shape::Disc`] or [`Shape::Rectangle`] in the body's xy
//! plane; a rigid body is several spheres at fixed offsets.

use nalgebra::{Isometry3, Point3, Unit, Vector3};

/// A target's geometry in its body frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A sphere centred on the body origin.
    Sphere { radius_m: f64 },
    /// Two spheres touching at the body origin, centres at `(±radius, 0, 0)` (the thesis's
    /// double ping-pong ball; its long axis is the body's x axis).
    DoubleSphere { radius_m: f64 },
    /// A flat disc in the body's xy plane, centred on the origin, seen from both sides.
    Disc { radius_m: f64 },
    /// A flat rectangle in the body's xy plane, `2·half_x` along x.
    Rectangle { half_x_m: f64, half_y_m: f64 },
    /// Spheres at offsets in the body frame (a multi-marker rigid body).
    Markers { spheres: Vec<(Vector3<f64>, f64)> },
    /// Flat dots in the body's xy plane (a calibration dot grid): centre and radius of each.
    Dots { dots: Vec<(Vector3<f64>, f64)> },
}

impl Shape {
    /// The spheres making up the shape (centre in the body frame, radius), if it is made of
    /// spheres.
    pub fn spheres(&self) -> Vec<(Vector3<f64>, f64)> {
        match self {
            Shape::Sphere { radius_m } => vec![(Vector3::zeros(), *radius_m)],
            Shape::DoubleSphere { radius_m } => {
                vec![
                    (Vector3::new(-radius_m, 0.0, 0.0), *radius_m),
                    (Vector3::new(*radius_m, 0.0, 0.0), *radius_m),
                ]
            }
            Shape::Markers { spheres } => spheres.clone(),
            Shape::Disc { .. } | Shape::Rectangle { .. } | Shape::Dots { .. } => Vec::new(),
        }
    }

    /// Radius of a sphere around the body origin that holds the whole shape.
    pub fn bounding_radius(&self) -> f64 {
        match self {
            Shape::Sphere { radius_m } => *radius_m,
            Shape::DoubleSphere { radius_m } => 2.0 * radius_m,
            Shape::Disc { radius_m } => *radius_m,
            Shape::Rectangle { half_x_m, half_y_m } => {
                (half_x_m * half_x_m + half_y_m * half_y_m).sqrt()
            }
            Shape::Markers { spheres: parts } | Shape::Dots { dots: parts } => {
                parts.iter().map(|(c, r)| c.norm() + r).fold(0.0, f64::max)
            }
        }
    }
}

/// One target: a shape, where it is, and how bright it is.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    pub shape: Shape,
    pub world_from_body: Isometry3<f64>,
    /// Brightness above the background where fully lit, grey levels.
    pub contrast: f64,
}

/// A static bright spot (a reflection): a small sphere that is not a target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distractor {
    pub position_world: Point3<f64>,
    pub radius_m: f64,
    pub contrast: f64,
}

/// The dark background: a level, and a gradient across the image (uneven light), in grey
/// levels and grey levels per pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Background {
    pub level: f64,
    pub gradient_per_px: (f64, f64),
}

impl Default for Background {
    fn default() -> Self {
        Background {
            level: 20.0,
            gradient_per_px: (0.0, 0.0),
        }
    }
}

/// The scene's light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Light {
    /// One distant lamp: the direction towards it, world frame (a room's ceiling light, the
    /// thesis's lab). A sphere's image is brightest on its lit side, so a thresholded blob's
    /// centroid leans that way.
    Overhead { towards: Unit<Vector3<f64>> },
    /// A ring light around each camera's lens (every motion-capture camera has one): each view
    /// sees its markers lit along its own rays, symmetric about the line of sight.
    Ring,
}

impl Light {
    /// The unit direction towards the light from a surface hit by a ray of direction `ray`.
    pub fn towards(&self, ray: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Light::Overhead { towards } => towards.into_inner(),
            Light::Ring => -ray,
        }
    }
}

/// Everything in view.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    pub targets: Vec<Target>,
    pub distractors: Vec<Distractor>,
    pub background: Background,
    /// Where the light comes from (for shading spheres and flat markers).
    pub light: Light,
    /// Fraction of the light that reaches surfaces turned away from the light (0–1).
    pub ambient: f64,
}

impl Default for Scene {
    fn default() -> Self {
        Scene {
            targets: Vec::new(),
            distractors: Vec::new(),
            background: Background::default(),
            light: Light::Overhead {
                towards: Vector3::z_axis(),
            },
            ambient: 0.6,
        }
    }
}
