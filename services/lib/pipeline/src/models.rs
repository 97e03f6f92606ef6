//! Fusion's kinematic models (`docs/models.md`): each set's triangulated markers are given to
//! the rig's models and each model's chain is fitted (`stereoscope_kinematics::fit_chain`,
//! thesis §5.3).
//!
//! Which point is which model marker: while a model's last frame was valid, each marker is
//! expected where the last fit puts it and the points are assigned to the markers by one
//! minimum-cost assignment, each within [`PREDICTION_GATE_M`] of its marker (a marker moving at
//! 1 m/s moves 8 mm between frames at 120 fps). Without a valid last frame — at the start, or
//! after a frame the fit refused — the model is found from nothing: every link with three or
//! more markers is a rigid cluster, and the clusters are identified together among the points
//! by their pairwise distances (`stereoscope_bodies::identify`, within the model's
//! `tolerance`); the chain is fitted to them, then the markers of the links that have fewer
//! are assigned by prediction and the chain fitted again. Points labelled as a rigid body's
//! markers are not used, nor a point twice across models. The points of a valid fit are
//! labelled with their model, link and marker (`Pose::model`): exports name them so.

use nalgebra::Point3;
use stereoscope_bodies::{BodyDef, identify};
use stereoscope_kinematics::{ChainFit, ChainState, FitOptions, JointValue, Model, fit_chain};
use stereoscope_proto::messages::{JointState, LinkPose, ModelLabel, ModelPose, Pose, PoseMethod};
use stereoscope_rig::models::RigModel;

/// How far a point may be from where the last fit expects a marker.
pub const PREDICTION_GATE_M: f64 = 0.03;

/// A point this far from where the fit puts its marker is not taken as that marker: the
/// chain is fitted again without it. Noise puts a marker 0.1–0.5 mm off at the demo rigs'
/// 640 × 480; a point 3 mm off or more is another marker, or blobs of two merged in a view,
/// which a fit within `max_rms` would otherwise keep and label (the robot-arm demo's C3D
/// export had points 9 mm off their link's other markers).
pub const MARKER_OUTLIER_M: f64 = 0.003;

#[derive(Debug, Clone)]
struct Entry {
    def: RigModel,
    /// Links with three or more markers as rigid clusters: the definitions and, for each, the
    /// model's marker indices in order.
    clusters: Vec<BodyDef>,
    cluster_markers: Vec<Vec<usize>>,
    /// The last valid frame's state.
    state: Option<ChainState>,
    /// The last fit (valid or not), for the values a frame without a fit carries.
    last: Option<ChainFit>,
}

/// The rig's models followed over sets.
#[derive(Debug, Clone, Default)]
pub struct Models {
    entries: Vec<Entry>,
}

impl Models {
    pub fn new(models: Vec<RigModel>) -> Models {
        let entries = models
            .into_iter()
            .map(|def| {
                let m = &def.model;
                let mut clusters = Vec::new();
                let mut cluster_markers = Vec::new();
                for (l, link) in m.links.iter().enumerate() {
                    let on: Vec<usize> = (0..m.markers.len())
                        .filter(|&k| m.markers[k].link == l)
                        .collect();
                    if on.len() >= 3 && on.len() <= stereoscope_bodies::MAX_MARKERS {
                        clusters.push(BodyDef {
                            name: format!("{}/{}", m.name, link.name),
                            markers_m: on.iter().map(|&k| m.markers[k].in_link_m).collect(),
                            tolerance_m: def.tolerance_m,
                        });
                        cluster_markers.push(on);
                    }
                }
                Entry {
                    def,
                    clusters,
                    cluster_markers,
                    state: None,
                    last: None,
                }
            })
            .collect();
        Models { entries }
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Fits every model to the set's triangulated poses not labelled as a body's markers,
    /// and labels the poses a valid fit placed. A model never found yet is absent from the
    /// result.
    pub fn update(&mut self, poses: &mut [Pose]) -> Vec<ModelPose> {
        if self.entries.is_empty() {
            return Vec::new();
        }
        let of_point: Vec<usize> = (0..poses.len())
            .filter(|&i| poses[i].method == PoseMethod::Triangulated && poses[i].body.is_none())
            .collect();
        let points: Vec<Point3<f64>> = of_point
            .iter()
            .map(|&i| Point3::from(poses[i].position_m))
            .collect();
        let mut used = vec![false; points.len()];
        let mut out = Vec::new();
        for e in &mut self.entries {
            let Some((f, at)) = e.update(&points, &mut used) else {
                continue;
            };
            let m = &e.def.model;
            for (marker, point) in m.markers.iter().zip(&at) {
                if let Some(&i) = point.and_then(|p| of_point.get(p)) {
                    poses[i].model = Some(ModelLabel {
                        name: m.name.clone(),
                        link: m.links[marker.link].name.clone(),
                        marker: marker.name.clone(),
                    });
                }
            }
            out.push(model_pose(m, &f));
        }
        out
    }
}

impl Entry {
    fn opts(&self) -> FitOptions {
        FitOptions {
            max_rms_m: self.def.max_rms_m,
            ..FitOptions::default()
        }
    }

    /// Each marker's point (by prediction from `state`), among points not `used`.
    fn by_prediction(
        &self,
        state: &ChainState,
        points: &[Point3<f64>],
        used: &[bool],
        known: &[Option<usize>],
    ) -> Vec<Option<usize>> {
        let m = &self.def.model;
        let mut poses = Vec::new();
        m.forward(&state.world_from_root, &state.values, &mut poses);
        let expected = m.marker_positions(&poses);
        let taken: Vec<bool> = (0..points.len())
            .map(|i| used[i] || known.contains(&Some(i)))
            .collect();
        let cost: Vec<Vec<f64>> = expected
            .iter()
            .enumerate()
            .map(|(k, e)| {
                points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let d = (p - e).norm();
                        if known[k].is_some() || taken[i] || d > PREDICTION_GATE_M {
                            f64::INFINITY
                        } else {
                            d
                        }
                    })
                    .collect()
            })
            .collect();
        let assigned = stereoscope_numeric::assign::assign_min_cost(&cost);
        (0..expected.len())
            .map(|k| known[k].or(assigned.get(k).copied().flatten()))
            .collect()
    }

    /// The fit again without the points more than [`MARKER_OUTLIER_M`] from where `f` puts
    /// their markers, when there are any and the new fit is valid (or `f` was not).
    fn without_outliers(
        &self,
        mut at: Vec<Option<usize>>,
        f: ChainFit,
        points: &[Point3<f64>],
        opts: &FitOptions,
    ) -> (Vec<Option<usize>>, ChainFit) {
        let model = &self.def.model;
        let mut dropped = false;
        for (k, m) in model.markers.iter().enumerate() {
            let Some(i) = at[k] else { continue };
            let Some(pose) = f.world_from_link.get(m.link) else {
                continue;
            };
            if (points[i] - pose * m.in_link_m).norm() > MARKER_OUTLIER_M {
                at[k] = None;
                dropped = true;
            }
        }
        if !dropped {
            return (at, f);
        }
        match fit_chain(model, &self.observed(&at, points), Some(&f.state), opts) {
            Ok(again) if again.valid || !f.valid => (at, again),
            _ => (at, f),
        }
    }

    fn observed(&self, at: &[Option<usize>], points: &[Point3<f64>]) -> Vec<Option<Point3<f64>>> {
        at.iter().map(|p| p.map(|i| points[i])).collect()
    }

    /// The links' clusters identified among the points not `used`.
    fn found_from_nothing(&self, points: &[Point3<f64>], used: &[bool]) -> Vec<Option<usize>> {
        let free: Vec<usize> = (0..points.len()).filter(|&i| !used[i]).collect();
        let pts: Vec<Point3<f64>> = free.iter().map(|&i| points[i]).collect();
        let mut at = vec![None; self.def.model.markers.len()];
        for found in identify(&self.clusters, &pts) {
            for (k, p) in found.markers.iter().enumerate() {
                if let Some(p) = p {
                    at[self.cluster_markers[found.body][k]] = Some(free[*p]);
                }
            }
        }
        at
    }

    /// The fit, and which point each marker is when it is valid (none otherwise).
    fn update(
        &mut self,
        points: &[Point3<f64>],
        used: &mut [bool],
    ) -> Option<(ChainFit, Vec<Option<usize>>)> {
        let model = &self.def.model;
        let opts = self.opts();
        let none = vec![None; model.markers.len()];
        // By prediction from the last valid frame.
        let mut fit = self.state.as_ref().and_then(|s| {
            let at = self.by_prediction(s, points, used, &none);
            let f = fit_chain(model, &self.observed(&at, points), Some(s), &opts).ok()?;
            Some((at, f))
        });
        // From nothing too when prediction did not place every marker: a wrong state (a link
        // turned by a mislabelled marker) would otherwise hold itself, its links' markers
        // predicted where they are not. A valid fit by prediction stays unless the other places
        // more markers; otherwise the fit that places more markers wins (then the lower RMS),
        // valid before not valid.
        let complete = fit
            .as_ref()
            .is_some_and(|(_, f)| f.valid && f.markers_used == model.markers.len());
        if !complete {
            let at = self.found_from_nothing(points, used);
            if let Ok(first) = fit_chain(model, &self.observed(&at, points), None, &opts) {
                // The links without a cluster, by prediction from that fit.
                let all = self.by_prediction(&first.state, points, used, &at);
                let f = fit_chain(
                    model,
                    &self.observed(&all, points),
                    Some(&first.state),
                    &opts,
                )
                .unwrap_or(first);
                let better = |a: &ChainFit, b: &ChainFit| {
                    (
                        a.valid,
                        a.markers_used,
                        std::cmp::Reverse(a.rms_m.to_bits()),
                    ) > (
                        b.valid,
                        b.markers_used,
                        std::cmp::Reverse(b.rms_m.to_bits()),
                    )
                };
                // A valid fit by prediction is given up only for one that places more
                // markers: with as many, a lower RMS is no reason to jump (with a link hidden,
                // clusters found from nothing fitted the arm 98–208° off at a lower RMS).
                let replace = match fit.as_ref() {
                    None => true,
                    Some((_, old)) if old.valid => f.valid && f.markers_used > old.markers_used,
                    Some((_, old)) => better(&f, old),
                };
                if replace {
                    fit = Some((all, f));
                }
            }
        }
        let fit = fit.map(|(at, f)| self.without_outliers(at, f, points, &opts));
        let Some((at, f)) = fit else {
            // Not found: the last fit, marked not valid, while there is one.
            let mut last = self.last.clone()?;
            last.valid = false;
            last.markers_used = 0;
            self.state = None;
            return Some((last, Vec::new()));
        };
        let at = if f.valid {
            for i in at.iter().flatten() {
                used[*i] = true;
            }
            self.state = Some(f.state.clone());
            at
        } else {
            self.state = None;
            Vec::new()
        };
        self.last = Some(f.clone());
        Some((f, at))
    }
}

/// The protocol's form of a fit.
pub fn model_pose(model: &Model, f: &ChainFit) -> ModelPose {
    let quat = |q: &nalgebra::UnitQuaternion<f64>| [q.i, q.j, q.k, q.w];
    ModelPose {
        name: model.name.clone(),
        valid: f.valid,
        rms_mm: if f.rms_m.is_finite() {
            f.rms_m * 1e3
        } else {
            0.0
        },
        markers_seen: f.markers_used as u32,
        markers: model.markers.len() as u32,
        joints: model
            .joints
            .iter()
            .zip(&f.state.values)
            .zip(&f.joints)
            .map(|((j, v), jf)| JointState {
                name: j.name.clone(),
                values: match v {
                    JointValue::Fixed => Vec::new(),
                    JointValue::Angle(a) | JointValue::Offset(a) => vec![*a],
                    JointValue::Angles(a) => a.to_vec(),
                    JointValue::Rotation(q) => quat(q).to_vec(),
                },
                determined: jf.determined,
                at_limit: jf.at_limit,
                residual_mm: jf.residual_m.map(|r| r * 1e3),
            })
            .collect(),
        links: model
            .links
            .iter()
            .zip(&f.world_from_link)
            .map(|(l, p)| LinkPose {
                name: l.name.clone(),
                position_m: p.translation.vector.into(),
                orientation_xyzw: quat(&p.rotation),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_kinematics::synthetic::{arm6, arm6_base, arm6_values};
    use stereoscope_numeric::random::SplitMix64;

    fn pose(id: u32, p: Point3<f64>) -> Pose {
        Pose {
            object_id: id,
            position_m: p.into(),
            velocity_m_per_s: [0.0; 3],
            heading_deg: None,
            heading_directed: false,
            method: PoseMethod::Triangulated,
            cameras: vec!["a".into(), "b".into()],
            residual_px: 0.1,
            out_of_range: false,
            body: None,
            model: None,
        }
    }

    /// The arm among loose markers: found from nothing in the first set, followed by
    /// prediction, lost while hidden (the last values, not valid) and found again; the angles
    /// within 0.5° of the truth at 0.3 mm of noise whenever valid, every marker's point
    /// labelled with its link and name.
    #[test]
    fn the_arm_is_found_followed_lost_and_found_again_among_loose_markers() {
        let model = arm6().unwrap();
        let mut models = Models::new(vec![RigModel {
            model: model.clone(),
            tolerance_m: 0.003,
            max_rms_m: 0.005,
        }]);
        let mut rng = SplitMix64::new(9);
        let mut poses_buf = Vec::new();
        let mut worst = 0.0f64;
        for k in 0..480 {
            let t = k as f64 / 120.0;
            let truth = arm6_values(t);
            model.forward(&arm6_base(), &truth, &mut poses_buf);
            let mut poses: Vec<Pose> = Vec::new();
            let hidden = (200..230).contains(&k);
            if !hidden {
                for (i, p) in model.marker_positions(&poses_buf).iter().enumerate() {
                    let n = Point3::new(
                        p.x + 0.3e-3 * rng.normal(),
                        p.y + 0.3e-3 * rng.normal(),
                        p.z + 0.3e-3 * rng.normal(),
                    );
                    poses.push(pose(i as u32, n));
                }
            }
            // Loose markers elsewhere in the volume.
            for j in 0..6 {
                let a = t * 0.5 + j as f64;
                poses.push(pose(
                    100 + j,
                    Point3::new(1.5 + 0.3 * a.cos(), -1.0 + 0.3 * a.sin(), 0.2 * j as f64),
                ));
            }
            // Shuffled: the order of fusion's poses says nothing.
            for i in (1..poses.len()).rev() {
                let j = (rng.next_u64() % (i as u64 + 1)) as usize;
                poses.swap(i, j);
            }
            let out = models.update(&mut poses);
            if k == 0 {
                assert!(
                    out.len() == 1 && out[0].valid,
                    "not found from nothing: {out:?}"
                );
            }
            if hidden {
                assert!(out.len() == 1 && !out[0].valid, "frame {k}: {out:?}");
                continue;
            }
            let m = &out[0];
            assert!(m.valid, "frame {k}: {m:?}");
            assert_eq!(m.markers_seen, 28, "frame {k}");
            // Every marker's point labelled as that marker of its link; the loose ones not.
            for p in &poses {
                let want = model
                    .markers
                    .get(p.object_id as usize)
                    .map(|mk| ModelLabel {
                        name: model.name.clone(),
                        link: model.links[mk.link].name.clone(),
                        marker: mk.name.clone(),
                    });
                assert_eq!(p.model, want, "frame {k}, object {}", p.object_id);
            }
            for (j, js) in m.joints.iter().take(6).enumerate() {
                let JointValue::Angle(a) = truth[j] else {
                    unreachable!()
                };
                worst = worst.max((js.values[0] - a).abs().to_degrees());
            }
        }
        assert!(worst < 0.5, "worst {worst}°");
    }

    /// A point 8 mm from where its marker should be (blobs of two markers merged in a view)
    /// is neither labelled as the marker nor kept in the fit: the angles are those of the
    /// other 27 markers.
    #[test]
    fn a_point_far_from_its_marker_is_left_out_and_not_labelled() {
        let model = arm6().unwrap();
        let mut models = Models::new(vec![RigModel {
            model: model.clone(),
            tolerance_m: 0.003,
            max_rms_m: 0.005,
        }]);
        let mut buf = Vec::new();
        let truth = arm6_values(0.5);
        model.forward(&arm6_base(), &truth, &mut buf);
        let at = model.marker_positions(&buf);
        let clean: Vec<Pose> = at
            .iter()
            .enumerate()
            .map(|(i, p)| pose(i as u32, *p))
            .collect();
        // Found from nothing on clean markers first, then one marker 8 mm off.
        models.update(&mut clean.clone());
        let mut poses = clean.clone();
        let off = 20;
        poses[off].position_m[0] += 0.008;
        let out = models.update(&mut poses);
        let m = &out[0];
        assert!(m.valid, "{m:?}");
        assert_eq!(m.markers_seen, 27);
        assert_eq!(poses[off].model, None);
        assert!(poses.iter().filter(|p| p.model.is_some()).count() == 27);
        for (j, js) in m.joints.iter().take(6).enumerate() {
            let JointValue::Angle(a) = truth[j] else {
                unreachable!()
            };
            assert!((js.values[0] - a).abs() < 1e-6, "joint {j}: {js:?}");
        }
    }
}
