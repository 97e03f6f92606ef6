//! The rig file: one TOML file describing a rig's cameras, read by every service and command
//! that needs them. This module is the file's schema (unknown keys are rejected); turning it
//! into cameras, with every value checked, is `stereoscope_geometry::rig`. Every key is
//! documented in `docs/rig.md`, with the thesis's lab as a worked example.

use serde::{Deserialize, Serialize};

/// A whole rig file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// A name for the rig (used in network keys later).
    pub name: String,
    /// The length unit of every position, translation and depth in the file: "m", "cm" or "mm".
    pub units: String,
    #[serde(rename = "camera", default)]
    pub cameras: Vec<CameraSpec>,
}

/// One camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Unique name of the camera.
    pub id: String,
    /// `[width, height]` in pixels.
    pub image_size: [u32; 2],
    /// Focal length in pixels along x (give `fx` and `fy`, or `focal_length_mm` and
    /// `pixel_pitch_um`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    /// Lens focal length, millimetres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_length_mm: Option<f64>,
    /// Pixel pitch `[width, height]`, micrometres (their ratio is the pixel aspect ratio).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_pitch_um: Option<[f64; 2]>,
    /// Principal point `[cx, cy]` in pixels; the image centre if absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub principal_point: Option<[f64; 2]>,
    /// Lens distortion; none if absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<DistortionSpec>,
    pub pose: PoseSpec,
    /// Single-camera depth from blob area, if calibrated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_from_area: Option<DepthFromAreaSpec>,
}

/// Brown–Conrady coefficients (OpenCV's k1 k2 p1 p2 k3); absent ones are zero.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistortionSpec {
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub k3: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
}

/// Where the camera is: either `position`, `look_at` and `up` (the thesis's construction,
/// §2.3.1), or `cam_from_world_rotation` and `cam_from_world_translation`. World coordinates
/// in the file's unit.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
    /// Rows of the rotation taking world coordinates into camera coordinates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cam_from_world_rotation: Option<[[f64; 3]; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cam_from_world_translation: Option<[f64; 3]>,
}

/// `AREA = a / (D² + b·D + c)` ("three_parameter") or `AREA = a / (D + b)²`
/// ("two_parameter"), D the distance along the optical axis in the file's unit, AREA in pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthFromAreaSpec {
    pub model: String,
    pub a: f64,
    pub b: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub c: Option<f64>,
    /// The calibrated distance range `[near, far]`, file unit.
    pub range: [f64; 2],
}

impl RigFile {
    /// Parses a rig file's text. The error names the key and line of the problem.
    pub fn from_toml(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }
}

impl CameraSpec {
    /// One camera as TOML (a `[[camera]]` table), e.g. for a calibration's output.
    pub fn to_toml_table(&self) -> Result<String, toml::ser::Error> {
        #[derive(Serialize)]
        struct One<'a> {
            camera: [&'a CameraSpec; 1],
        }
        toml::to_string(&One { camera: [self] })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAB: &str = r#"
name = "lab"
units = "cm"

[[camera]]
id = "cam0"
image_size = [320, 240]
focal_length_mm = 12.5
pixel_pitch_um = [21.5, 25.0]
pose = { position = [0.0, 0.0, 277.5], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }

[[camera]]
id = "cam1"
image_size = [320, 240]
fx = 600.0
fy = 520.0
distortion = { k1 = -0.1 }
pose = { cam_from_world_rotation = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], cam_from_world_translation = [-20.0, 0.0, 280.0] }
depth_from_area = { model = "three_parameter", a = 1.0e6, b = 0.0, c = -4.0, range = [75.0, 275.0] }
"#;

    #[test]
    fn parses_and_round_trips() {
        let rig = RigFile::from_toml(LAB).unwrap();
        assert_eq!(rig.cameras.len(), 2);
        assert_eq!(rig.cameras[1].distortion.unwrap().k1, -0.1);
        let back = RigFile::from_toml(&rig.to_toml().unwrap()).unwrap();
        assert_eq!(back, rig);
        let one = rig.cameras[0].to_toml_table().unwrap();
        assert!(one.contains("[[camera]]"), "{one}");
    }

    #[test]
    fn unknown_and_missing_keys_are_named() {
        let err = RigFile::from_toml(&LAB.replace("focal_length_mm", "focal_lenght_mm"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("focal_lenght_mm"), "{err}");
        let err = RigFile::from_toml(&LAB.replace("units = \"cm\"\n", ""))
            .unwrap_err()
            .to_string();
        assert!(err.contains("units"), "{err}");
        let err = RigFile::from_toml(&LAB.replace("image_size = [320, 240]\nfx", "fx"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("image_size"), "{err}");
    }
}
