//! Poses scored against a synthetic scene's truth: where every body marker truly is, and which
//! published poses are ghosts (no target there). Shared by `stereoscope demo`, the in-process
//! ghost sweep (`services/lib/pipeline/examples/ghosts.rs`) and the fusion tests, so that each counts
//! ghosts the same way.

use nalgebra::{Point3, Quaternion, UnitQuaternion};
use stereoscope_proto::messages::{Pose, TargetTruth};

/// A pose farther than this from every target it could be is a ghost, metres.
pub const GHOST_DISTANCE_M: f64 = 0.05;

/// The rig's bodies: each name with its markers in the body frame, metres.
#[derive(Debug, Clone, Default)]
pub struct Layouts(Vec<(String, Vec<Point3<f64>>)>);

impl Layouts {
    pub fn of_rig(file: &crate::RigFile) -> Self {
        Layouts(
            crate::body_defs(file)
                .into_iter()
                .map(|d| (d.name, d.markers_m))
                .collect(),
        )
    }

    /// [`Layouts::of_rig`] and each kinematic model's links that carry markers, named
    /// `<model>/<link>` as the synthetic cameras' truth names them.
    pub fn of(rig: &crate::Rig) -> Self {
        let mut l = Self::of_rig(&rig.spec);
        for m in &rig.models {
            let model = &m.model;
            for (i, link) in model.links.iter().enumerate() {
                let pts: Vec<Point3<f64>> = model
                    .markers
                    .iter()
                    .filter(|k| k.link == i)
                    .map(|k| k.in_link_m)
                    .collect();
                if !pts.is_empty() {
                    l.0.push((format!("{}/{}", model.name, link.name), pts));
                }
            }
        }
        l
    }

    /// Every body marker's world position in this truth: (body, marker index, position).
    pub fn markers<'a>(&'a self, targets: &'a [TargetTruth]) -> Vec<(&'a str, u32, Point3<f64>)> {
        let mut out = Vec::new();
        for tt in targets {
            let (Some(name), Some([x, y, z, w])) = (&tt.body, tt.orientation_xyzw) else {
                continue;
            };
            let Some((_, layout)) = self.0.iter().find(|(n, _)| n == name) else {
                continue;
            };
            let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
            let at = Point3::from(tt.position_m);
            for (k, m) in layout.iter().enumerate() {
                out.push((name.as_str(), k as u32, at + q * m.coords));
            }
        }
        out
    }

    /// The poses that are no target: a loose pose more than [`GHOST_DISTANCE_M`] from every
    /// loose target and every body marker (a wrong correspondence, a merged image), or a
    /// body's marker that far from where the body's truth puts that marker (a wrong label).
    pub fn ghosts<'p>(&self, poses: &'p [Pose], targets: &[TargetTruth]) -> Vec<&'p Pose> {
        let markers = self.markers(targets);
        let near = |a: &[f64; 3], b: &Point3<f64>| (Point3::from(*a) - b).norm() < GHOST_DISTANCE_M;
        poses
            .iter()
            .filter(|pose| match &pose.body {
                Some(b) => !markers
                    .iter()
                    .any(|(n, k, m)| *n == b.name && *k == b.marker && near(&pose.position_m, m)),
                None => {
                    !targets.iter().any(|tt| {
                        tt.body.is_none() && near(&pose.position_m, &Point3::from(tt.position_m))
                    }) && !markers.iter().any(|(_, _, m)| near(&pose.position_m, m))
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{BodyLabel, PoseMethod};

    fn truth(position_m: [f64; 3], body: Option<&str>, q: Option<[f64; 4]>) -> TargetTruth {
        TargetTruth {
            target: 0,
            position_m,
            heading_deg: 0.0,
            has_axis: false,
            symmetric: true,
            visible: true,
            area_px: 50.0,
            centroid_px: [0.0, 0.0],
            body: body.map(String::from),
            orientation_xyzw: q,
        }
    }

    fn pose(position_m: [f64; 3], body: Option<(&str, u32)>) -> Pose {
        Pose {
            object_id: 1,
            position_m,
            velocity_m_per_s: [0.0; 3],
            heading_deg: None,
            heading_directed: false,
            method: PoseMethod::Triangulated,
            cameras: vec![],
            residual_px: 0.1,
            out_of_range: false,
            body: body.map(|(n, m)| BodyLabel {
                name: n.into(),
                marker: m,
            }),
            model: None,
        }
    }

    #[test]
    fn ghosts_are_poses_far_from_every_target_and_labels_far_from_their_marker() {
        let layouts = Layouts(vec![(
            "head".into(),
            vec![Point3::origin(), Point3::new(0.18, 0.0, 0.0)],
        )]);
        // The head at (1, 0, 0) turned 90° about z: marker 1 at (1, 0.18, 0).
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let targets = vec![
            truth([1.0, 0.0, 0.0], Some("head"), Some([0.0, 0.0, s, s])),
            truth([0.0, 0.0, 1.0], None, None),
        ];
        let m1 = [1.0, 0.18, 0.0];
        let poses = vec![
            pose(m1, Some(("head", 1))),
            pose(m1, Some(("head", 0))),
            pose(m1, None),
            pose([0.0, 0.0, 1.04], None),
            pose([0.0, 0.0, 1.06], None),
            pose([1.18, 0.0, 0.0], None),
        ];
        let ghosts = layouts.ghosts(&poses, &targets);
        let at: Vec<usize> = ghosts
            .iter()
            .map(|g| poses.iter().position(|p| std::ptr::eq(p, *g)).unwrap_or(99))
            .collect();
        // Marker 1 labelled 0, the loose pose 6 cm from the loose target, and a pose where
        // marker 1 would be unturned.
        assert_eq!(at, vec![1, 4, 5]);
    }
}
