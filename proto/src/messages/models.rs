//! Kinematic models' messages (`docs/models.md`, `docs/protocol.md`): a model's joints and
//! links in a pose frame, and on its own key.

use super::{Checked, Checker, limits};
use serde::{Deserialize, Serialize};

/// One kinematic model in one frame (`docs/models.md`): every joint's value and every link's
/// pose from one fit of the whole chain to the triangulated markers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelPose {
    /// The model's name from the rig's `[[model]]` table.
    pub name: String,
    /// At least three markers, the base determined, and the RMS within the model's
    /// `max_rms`. A frame that is not valid carries the last values, to be shown, not used.
    pub valid: bool,
    /// RMS distance between the measured markers and the fitted model's, millimetres.
    pub rms_mm: f64,
    /// Markers found in this frame, and how many the model has.
    pub markers_seen: u32,
    pub markers: u32,
    /// In the model's tree order (a joint after the joint carrying its parent).
    pub joints: Vec<JointState>,
    /// `world_from_link` for every link, root first.
    pub links: Vec<LinkPose>,
}

/// One joint's value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointState {
    pub name: String,
    /// `revolute` / `continuous`: `[angle_rad]`, not wrapped; `prismatic`: `[offset_m]`;
    /// `universal`: `[angle0_rad, angle1_rad]`; `spherical`: the child's rotation in the
    /// joint's frame `[x, y, z, w]`; `fixed`: `[]`.
    pub values: Vec<f64>,
    /// The markers determine every degree of freedom of the joint; when false the values are
    /// the last determined ones, held.
    pub determined: bool,
    /// A limit held the value.
    pub at_limit: bool,
    /// RMS residual of the child link's visible markers, millimetres (`None`: none visible).
    pub residual_mm: Option<f64>,
}

/// One link's pose: `world_from_link`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkPose {
    pub name: String,
    pub position_m: [f64; 3],
    /// Unit quaternion, x, y, z, w.
    pub orientation_xyzw: [f64; 4],
}

/// Which model, link and marker a triangulated point was fitted as: the rig's names
/// (`[[model]]`'s `name`, the link's, `[[model.marker]]`'s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelLabel {
    pub name: String,
    pub link: String,
    pub marker: String,
}

impl ModelLabel {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("name", &self.name)?;
        c.name("link", &self.link)?;
        c.name("marker", &self.marker)
    }
}

/// One model on its own key (`stereoscope/<rig>/models/<name>`), with the times of the frame
/// set it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelUpdate {
    pub schema: u32,
    pub rig: String,
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub frame_published_ns: u64,
    pub published_ns: u64,
    pub model: ModelPose,
}

impl ModelPose {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("name", &self.name)?;
        c.range("rms_mm", self.rms_mm, 0.0, f64::MAX)?;
        c.range(
            "markers_seen",
            self.markers_seen as f64,
            0.0,
            self.markers as f64,
        )?;
        c.count("joints", self.joints.len(), limits::MAX_MODEL_JOINTS)?;
        for (i, j) in self.joints.iter().enumerate() {
            c.within(format!("joints[{i}]"), |c| {
                c.name("name", &j.name)?;
                c.count("values", j.values.len(), 4)?;
                c.finite("values", &j.values)?;
                if let Some(r) = j.residual_mm {
                    c.range("residual_mm", r, 0.0, f64::MAX)?;
                }
                Ok(())
            })?;
        }
        c.count("links", self.links.len(), limits::MAX_MODEL_LINKS)?;
        for (i, l) in self.links.iter().enumerate() {
            c.within(format!("links[{i}]"), |c| {
                c.name("name", &l.name)?;
                c.finite("position_m", &l.position_m)?;
                c.finite("orientation_xyzw", &l.orientation_xyzw)?;
                let n: f64 = l.orientation_xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
                c.range("orientation_xyzw", n, 1.0 - 1e-6, 1.0 + 1e-6)
            })?;
        }
        Ok(())
    }
}

impl ModelUpdate {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.within("model".into(), |c| self.model.validate(c))
    }
}
