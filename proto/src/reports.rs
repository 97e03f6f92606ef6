//! JSON printed by `stereoscope calibrate`, `fit-depth` and `triangulate` with `--json`
//! (`docs/protocol.md`). Lengths are in the unit the command was given (`units`).

use serde::{Deserialize, Serialize};

/// `stereoscope calibrate --json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationReport {
    pub image_size: [u32; 2],
    pub units: String,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// k1, k2, p1, p2, k3 (OpenCV's order).
    pub distortion: [f64; 5],
    /// Standard deviations in the order fx, fy, cx, cy, k1, k2, p1, p2, k3; null when fixed.
    pub std_dev: [Option<f64>; 9],
    pub rms_px: f64,
    pub views: Vec<ViewReport>,
    /// Reprojection error per point: `[view, point, du_px, dv_px]`.
    pub residuals: Vec<(usize, usize, f64, f64)>,
    /// The calibrated camera as a rig-file `[[camera]]` table; its world frame is the target's
    /// frame in the first view.
    pub camera_toml: String,
}

/// The target's pose in one calibration view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewReport {
    /// The view's label from the input.
    pub view: String,
    pub points: usize,
    pub rms_px: f64,
    /// Rotation of `cam_from_target` as a rotation vector, degrees.
    pub rotation_deg: [f64; 3],
    /// Translation of `cam_from_target`, in `units`.
    pub translation: [f64; 3],
}

/// `stereoscope fit-depth --json`: one entry per model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthFitReport {
    /// "two_parameter" (AREA = a/(D + b)²) or "three_parameter" (AREA = a/(D² + bD + c)).
    pub model: String,
    pub a: f64,
    pub b: f64,
    pub c: Option<f64>,
    /// Calibrated distance range `[near, far]`.
    pub range: [f64; 2],
    pub rms: f64,
    /// Per sample: `[area_px, distance, fitted distance, residual]`.
    pub samples: Vec<[f64; 4]>,
}

/// `stereoscope triangulate --json`: one line per point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriangulatedPoint {
    pub point: String,
    /// World position in the rig file's unit.
    pub position: [f64; 3],
    pub rms_px: f64,
    /// Camera ids used, and each one's reprojection error in pixels.
    pub cameras: Vec<String>,
    pub residuals_px: Vec<f64>,
}
