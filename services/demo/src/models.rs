//! The demo's scoring of kinematic models (`docs/models.md`): each fitted model's joints
//! against the joint truth of the synthetic scene, and its last link (the tool) in the world;
//! the frames in which the scene hid a link's markers scored apart.

use std::collections::{BTreeMap, BTreeSet};
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
    /// The frames a link's markers were hidden in (the scene's `hide`), scored apart.
    pub hidden: Option<HiddenStats>,
    /// Fusion's object ids against the model's true markers (a point within `ID_MATCH_M` of
    /// one): ids seen on two or more different markers (an id passed from marker to marker),
    /// and the mean number of ids a marker was seen under (1: never renumbered).
    pub ids_passed: usize,
    pub ids_per_marker: f64,
}

/// A point this close to a model's true marker is that marker, for the id scoring.
pub const ID_MATCH_M: f64 = 0.005;

/// How a model did while one link's markers were all hidden: each joint's worst error in the
/// frames it was published as determined, how often it was flagged instead, and how many
/// determined values were more than `GUESS_DEG` off (guesses published as measurements).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HiddenStats {
    pub link: String,
    pub frames: u64,
    /// The most markers any of those frames' fits found (the hidden ones cannot be among them).
    pub markers_seen_max: u32,
    /// Per joint: name, worst error while determined (`None`: never determined), frames flagged.
    pub joints: Vec<(String, Option<f64>, u64)>,
    pub guesses: u64,
}

/// A determined joint further than this from the truth while a link is hidden is a guess.
pub const GUESS_DEG: f64 = 0.5;

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
    hidden: Option<HiddenStats>,
    /// Per object id, the true markers (indices) it was seen on.
    id_markers: BTreeMap<u32, BTreeSet<usize>>,
}

/// A joint's error against the truth: degrees (millimetres for a slide); `None` where the
/// value's form does not match the truth's.
fn joint_error(tv: &stereoscope_kinematics::JointValue, v: &[f64]) -> Option<f64> {
    use stereoscope_kinematics::JointValue;
    match (tv, v) {
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
    }
}

/// Scores a frame in which `link` was hidden.
fn score_hidden(
    a: &mut ModelAcc,
    model: &stereoscope_kinematics::Model,
    link: usize,
    fit: Option<&stereoscope_proto::messages::ModelPose>,
    truth: &[stereoscope_kinematics::JointValue],
) {
    let h = a.hidden.get_or_insert_with(|| HiddenStats {
        link: model.links[link].name.clone(),
        joints: model
            .joints
            .iter()
            .map(|j| (j.name.clone(), None, 0))
            .collect(),
        ..HiddenStats::default()
    });
    h.frames += 1;
    let Some(fit) = fit else {
        h.joints.iter_mut().for_each(|j| j.2 += 1);
        return;
    };
    h.markers_seen_max = h.markers_seen_max.max(fit.markers_seen);
    for ((tv, js), slot) in truth.iter().zip(&fit.joints).zip(h.joints.iter_mut()) {
        if !fit.valid || !js.determined {
            slot.2 += 1;
            continue;
        }
        if let Some(e) = joint_error(tv, &js.values).map(f64::abs) {
            slot.1 = Some(slot.1.unwrap_or(0.0).max(e));
            if e > GUESS_DEG {
                h.guesses += 1;
            }
        }
    }
}

/// Scores each fitted model of `p` against its truth at `t`'s frame.
pub(crate) fn score_models(
    p: &PoseFrame,
    t: &Truth,
    mt: &ModelTruth,
    acc: &mut BTreeMap<String, ModelAcc>,
) {
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
        note_ids(
            a,
            m,
            p.poses.iter().map(|q| (q.object_id, q.position_m)),
            t_s,
        );
        if let Some(link) = m.hidden_at(t_s) {
            let truth = model.swing_values(&m.swings, t_s);
            let fit = p.models.iter().find(|f| f.name == model.name);
            score_hidden(a, model, link, fit, &truth);
            continue;
        }
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
            if let Some(e) = joint_error(tv, &js.values) {
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

/// Notes which true marker each of a frame's points (object id, world position) is: the
/// nearest within [`ID_MATCH_M`].
fn note_ids(
    a: &mut ModelAcc,
    m: &stereoscope_rig::models::ModelMotion,
    points: impl Iterator<Item = (u32, [f64; 3])>,
    t_s: f64,
) {
    let model = &m.model;
    let truth = model.swing_values(&m.swings, t_s);
    let mut poses = Vec::new();
    model.forward(&m.world_from_root, &truth, &mut poses);
    let markers: Vec<nalgebra::Point3<f64>> = model
        .markers
        .iter()
        .filter_map(|k| poses.get(k.link).map(|pose| pose * k.in_link_m))
        .collect();
    for (id, position_m) in points {
        let at = nalgebra::Point3::from(position_m);
        let nearest = markers
            .iter()
            .enumerate()
            .map(|(i, k)| (i, (k - at).norm()))
            .min_by(|x, y| x.1.total_cmp(&y.1));
        if let Some((i, d)) = nearest
            && d < ID_MATCH_M
        {
            a.id_markers.entry(id).or_default().insert(i);
        }
    }
}

impl HiddenStats {
    /// As JSON: `{"link", "frames", "markers_seen_max", "guesses", "joints": [{"name",
    /// "worst", "flagged"}]}`.
    pub fn json(&self) -> String {
        let joints: Vec<String> = self
            .joints
            .iter()
            .map(|(n, w, f)| {
                format!(
                    "{{\"name\":{},\"worst\":{},\"flagged\":{f}}}",
                    serde_json::to_string(n).unwrap_or_default(),
                    w.filter(|w| w.is_finite())
                        .map_or("null".to_string(), |w| format!("{w:.4}"))
                )
            })
            .collect();
        format!(
            "{{\"link\":{},\"frames\":{},\"markers_seen_max\":{},\"guesses\":{},\"joints\":[{}]}}",
            serde_json::to_string(&self.link).unwrap_or_default(),
            self.frames,
            self.markers_seen_max,
            self.guesses,
            joints.join(",")
        )
    }

    /// For people: "upper_arm hidden in 60 frames: worst while determined shoulder_pan 0.12°,
    /// …; flagged elbow 60, …; 0 guesses".
    pub fn line(&self) -> String {
        let worst: Vec<String> = self
            .joints
            .iter()
            .filter_map(|(n, w, _)| w.map(|w| format!("{n} {w:.3}")))
            .collect();
        let flagged: Vec<String> = self
            .joints
            .iter()
            .filter(|(_, _, f)| *f > 0)
            .map(|(n, _, f)| format!("{n} {f}"))
            .collect();
        format!(
            "{} hidden in {} frames: worst while determined (degrees; mm for a slide) {}; frames flagged {}; {} guesses over {GUESS_DEG}°",
            self.link,
            self.frames,
            if worst.is_empty() {
                "none".into()
            } else {
                worst.join(", ")
            },
            if flagged.is_empty() {
                "none".into()
            } else {
                flagged.join(", ")
            },
            self.guesses
        )
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
                hidden: a.hidden,
                ids_passed: a.id_markers.values().filter(|s| s.len() > 1).count(),
                ids_per_marker: {
                    let mut per: BTreeMap<usize, usize> = BTreeMap::new();
                    for s in a.id_markers.values() {
                        for &k in s {
                            *per.entry(k).or_default() += 1;
                        }
                    }
                    if per.is_empty() {
                        f64::NAN
                    } else {
                        per.values().sum::<usize>() as f64 / per.len() as f64
                    }
                },
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The leg's true markers as points: ids kept score no pass and one id per marker; two ids
    /// traded between markers score two passes, a marker seen under a second id one more id.
    #[test]
    fn ids_passed_between_markers_are_counted() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/rigs/leg.toml");
        let rig = stereoscope_rig::Rig::load(std::path::Path::new(path)).unwrap();
        let motions = stereoscope_rig::models::model_motions(&rig.spec, &rig.models);
        let m = &motions[0];
        let at = |t_s: f64| -> Vec<[f64; 3]> {
            let truth = m.model.swing_values(&m.swings, t_s);
            let mut poses = Vec::new();
            m.model.forward(&m.world_from_root, &truth, &mut poses);
            m.model
                .markers
                .iter()
                .map(|k| (poses[k.link] * k.in_link_m).coords.into())
                .collect()
        };
        let mut a = ModelAcc::default();
        let n = m.model.markers.len();
        for f in 0..10 {
            let t = f as f64 / 30.0;
            note_ids(
                &mut a,
                m,
                at(t)
                    .into_iter()
                    .enumerate()
                    .map(|(i, p)| (i as u32 + 1, p)),
                t,
            );
        }
        let score = |a: &ModelAcc| {
            let s = stats(
                &ModelTruth {
                    motions: motions.clone(),
                    fps: 30.0,
                    loop_frames: None,
                },
                BTreeMap::from([(
                    "leg".to_string(),
                    ModelAcc {
                        id_markers: a.id_markers.clone(),
                        ..ModelAcc::default()
                    },
                )]),
            );
            (s[0].ids_passed, s[0].ids_per_marker)
        };
        assert_eq!(score(&a), (0, 1.0));
        // Ids 1 and 2 traded; marker 3 under a new id.
        let mut p = at(0.5);
        p.swap(0, 1);
        let points = p.into_iter().enumerate().map(|(i, q)| {
            let id = if i == 2 { 99 } else { i as u32 + 1 };
            (id, q)
        });
        note_ids(&mut a, m, points, 0.5);
        let (passed, per_marker) = score(&a);
        assert_eq!(passed, 2);
        assert!(
            (per_marker - (n as f64 + 3.0) / n as f64).abs() < 1e-9,
            "{per_marker}"
        );
        // A point off every marker is no one's.
        note_ids(&mut a, m, std::iter::once((7, [9.0, 9.0, 9.0])), 0.5);
        assert_eq!(score(&a).0, 2);
    }
}
