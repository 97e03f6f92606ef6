//! The rig file's kinematic models (`[[model]]`, `docs/models.md`): a URDF's links and joints,
//! or joints given here, with the markers on the links. Read with the rest of the schema;
//! built and checked by `crate::models`.

use serde::{Deserialize, Serialize};

/// A model: `urdf` (a path, relative to the rig file) or `joint` tables, not both; markers on
/// its links; a floating base unless `fixed_base` places the root.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSpec {
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub urdf: Option<String>,
    #[serde(rename = "joint", default, skip_serializing_if = "Vec::is_empty")]
    pub joints: Vec<ModelJointSpec>,
    #[serde(rename = "marker", default)]
    pub markers: Vec<ModelMarkerSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fixed_base: Option<FixedBaseSpec>,
    /// How far a measured distance between two markers of one link may be from the model's,
    /// when the links are found from nothing (file unit, default 3 mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    /// A frame whose markers' RMS residual is above this is not valid (file unit, default
    /// 5 mm).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_rms: Option<f64>,
}

/// A joint given in the rig (URDF has no universal joint).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelJointSpec {
    pub name: String,
    /// `revolute`, `continuous`, `prismatic`, `fixed`, `universal` or `spherical`.
    #[serde(rename = "type")]
    pub kind: String,
    pub parent: String,
    pub child: String,
    /// The joint's origin in the parent link's frame (file unit).
    #[serde(default)]
    pub origin: [f64; 3],
    /// Its frame's roll, pitch and yaw about the parent's fixed x, y, z, degrees.
    #[serde(default)]
    pub rpy_deg: [f64; 3],
    /// The axis of a revolute, continuous or prismatic joint.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<[f64; 3]>,
    /// A universal joint's two axes, the first nearer the parent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axes: Option<[[f64; 3]; 2]>,
    /// Lower and upper limit: degrees for a revolute joint, the file unit for a prismatic one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits: Option<[f64; 2]>,
    /// A universal joint's limits per axis, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axes_limits_deg: Option<[[f64; 2]; 2]>,
}

/// A marker on a link, at `position` in the link's frame (file unit).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelMarkerSpec {
    pub name: String,
    pub link: String,
    pub position: [f64; 3],
}

/// A surveyed root: its position (file unit) and rotation (unit quaternion x, y, z, w).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedBaseSpec {
    pub position: [f64; 3],
    #[serde(default = "identity_xyzw")]
    pub orientation_xyzw: [f64; 4],
}

fn identity_xyzw() -> [f64; 4] {
    [0.0, 0.0, 0.0, 1.0]
}
