//! The geometry library's typed errors, each naming what was wrong.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum GeometryError {
    #[error("{what} is not a finite number")]
    NotFinite { what: &'static str },
    #[error(
        "not a rotation matrix: RᵀR differs from I by {orthonormality_error:.3e}, det R = {determinant:.6}"
    )]
    NotARotation {
        orthonormality_error: f64,
        determinant: f64,
    },
    #[error("cannot place the camera: {reason}")]
    DegenerateLookAt { reason: &'static str },
    #[error("invalid camera: {field} = {value}: {reason}")]
    InvalidCamera {
        field: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("too few points: {what} needs at least {needed}, got {got}")]
    TooFewPoints {
        what: String,
        needed: usize,
        got: usize,
    },
    #[error("degenerate points: {0}")]
    Degenerate(String),
    /// Wand calibration: cameras (rig indices) that share too few usable frames with the
    /// placed ones to be placed themselves.
    #[error(
        "cameras {cameras:?} share too few wand frames (8 at least) with the others to be placed{}: wave the wand where each of them sees it together with another camera",
        if *one_marker { " (with a one-marker wand: 8 frames each seen by the camera and two placed cameras)" } else { "" }
    )]
    WandUnplaced {
        cameras: Vec<usize>,
        one_marker: bool,
    },
    /// A dot-grid target that cannot be made or was not found in an image.
    #[error("dot grid: {0}")]
    DotGrid(#[from] DotGridProblem),
    #[error("image")]
    Vision(#[from] stereoscope_vision::VisionError),
    #[error("the point is behind camera {camera}")]
    BehindCamera { camera: usize },
    #[error("{0}")]
    Solver(String),
    #[error("depth model: {0}")]
    DepthModel(String),
}

/// Why a dot grid cannot be made, or why an image does not show it.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum DotGridProblem {
    #[error("a dot grid needs at least 2 × 2 dots, not {cols} × {rows}")]
    TooSmall { cols: usize, rows: usize },
    #[error("dot spacing {spacing} must be a finite number above zero")]
    Spacing { spacing: f64 },
    #[error(
        "found {found} dots, the {cols} × {rows} grid has {} (threshold {threshold}; is the whole grid in view?)",
        .cols * .rows
    )]
    DotCount {
        found: usize,
        cols: usize,
        rows: usize,
        threshold: u32,
    },
    #[error("no dot stands out as the larger origin dot (best ratio {best_ratio:.2})")]
    NoOriginDot { best_ratio: f64 },
    #[error("the dots do not span an area")]
    NoArea,
    #[error("no grid corner found")]
    NoCorner,
    #[error("the dots do not form the expected grid")]
    NotAGrid,
    #[error("the large dot is not at a corner of the grid")]
    OriginNotAtCorner,
}
