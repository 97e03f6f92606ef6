//! The demo's scoring of kinematic models (`docs/models.md`): each fitted model's joints
//! against the joint truth of the synthetic scene, and its last link (the tool) in the world.

use std::collections::BTreeMap;
use stereoscope_proto::messages::{PoseFrame, Truth};

/// Error statistics of one kinematic model: its joints against the scene's truth (degrees;
/// millimetres for a slide) in the frames the fit called valid, and its last link's origin
/// (the tool) in the world.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ModelStats {
    pub name: String,
    /// Pose frames scored (the model's truth known), and those with a valid fit.
    pub frames: u64,
    pub valid: u64,
    /// Valid frames with every joint determined: the tool's frames.
    pub whole: u64,
    /// Each joint's name and RMS error over the frames it was determined in; `None` for a
    /// fixed joint.
    pub joints_rms: Vec<(String, Option<f64>)>,
    pub tool_rms_m: f64,
}

/// The scene's truth for the rig's kinematic models: how each moves, and the truth camera's
/// frame rate and loop (a looped camera's frame `k` shows the scene at `k / fps`).
pub(crate) struct ModelTruth {
    pub(crate) motions: Vec<stereoscope_rig::models::ModelMotion>,
    pub(crate) fps: f64,
    pub(crate) loop_frames: Option<u32>,
}

#[derive(Default)]
pub(crate) struct ModelAcc {
    frames: u64,
    valid: u64,
    /// Valid frames with every joint determined (the tool scored).
    whole: u64,
    joint_sq: Vec<f64>,
    joint_n: Vec<u64>,
    tool_sq: f64,
}

/// Scores each fitted model of `p` against its truth at `t`'s frame.
pub(crate) fn score_models(
    p: &PoseFrame,
    t: &Truth,
    mt: &ModelTruth,
    acc: &mut BTreeMap<String, ModelAcc>,
) {
    use stereoscope_kinematics::JointValue;
    if mt.fps <= 0.0 {
        return;
    }
    // A live synthetic camera renders the scene at its frame's nominal time (seconds since the
    // epoch); a looped one plays its first frames, frame k at k / fps.
    let t_s = match mt.loop_frames.filter(|n| *n > 0) {
        Some(n) => (t.sequence % u64::from(n)) as f64 / mt.fps,
        None => t.timestamp_ns as f64 * 1e-9,
    };
    for m in &mt.motions {
        let model = &m.model;
        let a = acc.entry(model.name.clone()).or_default();
        a.frames += 1;
        let Some(fit) = p.models.iter().find(|f| f.name == model.name && f.valid) else {
            continue;
        };
        a.valid += 1;
        a.joint_sq.resize(model.joints.len(), 0.0);
        a.joint_n.resize(model.joints.len(), 0);
        let truth = model.swing_values(&m.swings, t_s);
        for (j, (tv, js)) in truth.iter().zip(&fit.joints).enumerate() {
            if !js.determined {
                continue;
            }
            let v = &js.values;
            let e = match (tv, v.as_slice()) {
                (JointValue::Angle(x), [y]) => Some((y - x).to_degrees()),
                (JointValue::Offset(x), [y]) => Some((y - x) * 1e3),
                (JointValue::Angles([x0, x1]), [y0, y1]) => {
                    Some(((y0 - x0).powi(2) + (y1 - x1).powi(2)).sqrt().to_degrees())
                }
                (JointValue::Rotation(q), [x, y, z, w]) => {
                    let f = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                        *w, *x, *y, *z,
                    ));
                    Some(f.angle_to(q).to_degrees())
                }
                _ => None,
            };
            if let Some(e) = e {
                a.joint_sq[j] += e * e;
                a.joint_n[j] += 1;
            }
        }
        // The tool's place is measured only when every joint is.
        if !fit.joints.iter().all(|j| j.determined) {
            continue;
        }
        a.whole += 1;
        let mut poses = Vec::new();
        model.forward(&m.world_from_root, &truth, &mut poses);
        if let (Some(tool), Some(last)) = (poses.last(), fit.links.last()) {
            let d: f64 = (0..3)
                .map(|i| (last.position_m[i] - tool.translation.vector[i]).powi(2))
                .sum();
            a.tool_sq += d;
        }
    }
}

/// The models' statistics from what scoring gathered.
pub(crate) fn stats(truth: &ModelTruth, acc: BTreeMap<String, ModelAcc>) -> Vec<ModelStats> {
    acc.into_iter()
        .map(|(name, a)| {
            let joints: Vec<String> = truth
                .motions
                .iter()
                .find(|m| m.model.name == name)
                .map(|m| m.model.joints.iter().map(|j| j.name.clone()).collect())
                .unwrap_or_default();
            ModelStats {
                joints_rms: joints
                    .into_iter()
                    .enumerate()
                    .map(|(j, n)| {
                        let (sq, k) = (
                            a.joint_sq.get(j).copied().unwrap_or(0.0),
                            a.joint_n.get(j).copied().unwrap_or(0),
                        );
                        (n, (k > 0).then(|| (sq / k as f64).sqrt()))
                    })
                    .collect(),
                tool_rms_m: if a.whole > 0 {
                    (a.tool_sq / a.whole as f64).sqrt()
                } else {
                    f64::NAN
                },
                whole: a.whole,
                name,
                frames: a.frames,
                valid: a.valid,
            }
        })
        .collect()
}
