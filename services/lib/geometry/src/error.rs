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
    #[error("the point is behind camera {camera}")]
    BehindCamera { camera: usize },
    #[error("{0}")]
    Solver(String),
    #[error("depth model: {0}")]
    DepthModel(String),
}
