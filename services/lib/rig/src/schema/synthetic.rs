//! `[synthetic]`: the scene the synthetic cameras render — its targets, their shapes and
//! motions, the light (docs/rig.md, docs/render.md).

use serde::{Deserialize, Serialize};

/// A synthetic target's shape.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetShape {
    Sphere,
    /// The thesis's two glued ping-pong balls.
    DoubleSphere,
    /// A flat disc facing up.
    Disc,
    /// A rigid body's markers (spheres of `radius` at the `[[body]]`'s marker positions).
    Body,
    /// A flat rectangle facing up, `radius` half its length and half as wide as long (2:1; the
    /// thesis's helmet target), its length along the heading.
    Rectangle,
    /// A kinematic model's markers: spheres of `radius` at every marker of the `[[model]]`
    /// named by `model`, each on its link, the model moved by a `joints` motion.
    Model,
    /// A calibration dot grid (what `stereoscope target dot-grid` prints): `grid`'s columns and
    /// rows of flat dots of `radius`, `grid.spacing` apart, the origin dot 1.5× larger, centred
    /// on the target's position in its xy plane (white dots on the dark background).
    DotGrid,
}

/// A synthetic dot grid's layout (`[[synthetic.target]] grid`), in the file's unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    pub cols: u32,
    pub rows: u32,
    pub spacing: f64,
}

/// A model target's link hidden periodically (`motion = { kind = "joints", …, hide = { link,
/// every_s, for_s } }`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HideSpec {
    pub link: String,
    pub every_s: f64,
    pub for_s: f64,
}

/// The scene synthetic cameras render (lengths in the file's unit).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SyntheticSpec {
    #[serde(default)]
    pub seed: u64,
    /// Read noise, grey levels (default 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_sigma: Option<f64>,
    /// Defocus blur, pixels (default 0.6).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub blur_sigma_px: Option<f64>,
    /// Background grey level (default 20).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub background: Option<f64>,
    /// Supersampling per axis near targets (default 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<u32>,
    /// The light: `"overhead"` (a lamp above, the default: the thesis's lab) or `"ring"` (a
    /// ring light at each camera, as motion-capture cameras carry).
    #[serde(default, skip_serializing_if = "is_default")]
    pub light: SyntheticLight,
    #[serde(rename = "target", default)]
    pub targets: Vec<SyntheticTarget>,
}

/// Where a synthetic scene's light is (`[synthetic] light`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SyntheticLight {
    /// One lamp straight above the world's origin (towards +z).
    #[default]
    Overhead,
    /// A ring light around each camera's lens: every view sees its markers lit along its rays.
    Ring,
}

fn is_default<T: Default + PartialEq>(v: &T) -> bool {
    *v == T::default()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticTarget {
    /// "sphere", "double_sphere" (the thesis's two glued balls) or "disc".
    pub shape: TargetShape,
    pub radius: f64,
    /// For shape "body": the `[[body]]` whose markers this target carries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body: Option<String>,
    /// For shape "model": the `[[model]]` whose markers this target carries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<String>,
    /// Brightness above the background, grey levels (default 180).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contrast: Option<f64>,
    /// For shape "dot_grid": its columns, rows and spacing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<GridSpec>,
    pub motion: MotionSpec,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MotionSpec {
    Static {
        position: [f64; 3],
        #[serde(default)]
        heading_deg: f64,
    },
    Line {
        from: [f64; 3],
        to: [f64; 3],
        period_s: f64,
    },
    Circle {
        centre: [f64; 3],
        radius: f64,
        period_s: f64,
    },
    Spin {
        position: [f64; 3],
        deg_per_s: f64,
    },
    Wander {
        centre: [f64; 3],
        extent: [f64; 3],
        #[serde(default)]
        seed: u64,
    },
    /// A kinematic model moved joint by joint (shape "model" only): its root at `base` (file
    /// unit) turned by `base_rpy_deg` (roll, pitch, yaw about the fixed x, y, z), and each
    /// degree of freedom, in the model's tree order, on `[centre, amplitude, hz, phase_deg]`
    /// (degrees for angles, the file unit for slides; missing ones at zero; joint limits
    /// hold).
    Joints {
        base: [f64; 3],
        #[serde(default)]
        base_rpy_deg: [f64; 3],
        #[serde(default)]
        swing: Vec<[f64; 4]>,
        /// One link's markers hidden for a while, again and again (what a hand over a link
        /// does): scene time `t` with `t mod every_s < for_s`.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        hide: Option<HideSpec>,
    },
    /// A head: round a horizontal circle, turning through 360° every `turn_period_s`, nodding
    /// and tilting by up to `nod_deg`.
    Head {
        centre: [f64; 3],
        radius: f64,
        period_s: f64,
        turn_period_s: f64,
        #[serde(default)]
        nod_deg: f64,
    },
}
