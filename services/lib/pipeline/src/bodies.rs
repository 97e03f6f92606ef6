//! Fusion's rigid bodies: each set's triangulated objects go to the body tracker
//! (`stereoscope_bodies::tracker`); the bodies found label their markers' poses (body name and
//! marker index) and become the frame's `bodies` (`docs/bodies.md`).

use nalgebra::{Isometry3, Point3};
use stereoscope_bodies::tracker::{BodyTracker, TrackedBody};
use stereoscope_proto::messages::{BodyLabel, BodyPose, MAX_BODY_MARKERS, Pose, PoseMethod};

use crate::fuser::{MarkerMotion, SetSightings};

// The protocol's bound on a body's markers is the library's.
const _: () = assert!(stereoscope_bodies::MAX_MARKERS as u32 == MAX_BODY_MARKERS);

/// What one set's update found: the bodies' poses, and the found bodies' markers that no
/// camera saw (world position and velocity).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BodiesFound {
    pub bodies: Vec<BodyPose>,
    pub unseen: Vec<MarkerMotion>,
}

/// The rig's bodies followed over sets.
#[derive(Debug, Clone)]
pub struct Bodies {
    tracker: BodyTracker,
    /// Each body's markers in its own frame (the refinement reads them while the tracker is
    /// borrowed).
    markers_m: Vec<Vec<Point3<f64>>>,
}

impl Bodies {
    /// `defs` followed over sets, each held for `hold_ns` while unseen.
    pub fn new(defs: Vec<stereoscope_bodies::BodyDef>, hold_ns: u64) -> Self {
        Bodies {
            markers_m: defs.iter().map(|d| d.markers_m.clone()).collect(),
            tracker: BodyTracker::new(defs, hold_ns),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.tracker.defs().is_empty()
    }

    /// The bodies' names, in the rig's order.
    pub fn names(&self) -> Vec<&str> {
        self.tracker
            .defs()
            .iter()
            .map(|d| d.name.as_str())
            .collect()
    }

    /// Finds the bodies among `poses` (only triangulated ones: depth from area is too coarse to
    /// match distances), labels their markers, and returns the bodies' poses (Kabsch on the
    /// triangulated markers).
    pub fn update(&mut self, poses: &mut [Pose], timestamp_ns: u64) -> Vec<BodyPose> {
        self.update_with(poses, timestamp_ns, None).bodies
    }

    /// [`Bodies::update`] with each body's pose refined on the cameras' pixels of its markers
    /// (`seen`: what the cameras saw of each object in the set just fused;
    /// `stereoscope_bodies::refine_reprojection`), and where each found body's unseen markers
    /// are (their positions and velocities from the body's pose), for the fuser to expect
    /// next set ([`crate::fuser::Fuser::expect_unseen`]).
    pub fn update_refined(
        &mut self,
        poses: &mut [Pose],
        timestamp_ns: u64,
        seen: SetSightings<'_>,
    ) -> BodiesFound {
        self.update_with(poses, timestamp_ns, Some(seen))
    }

    fn update_with(
        &mut self,
        poses: &mut [Pose],
        timestamp_ns: u64,
        seen: Option<SetSightings<'_>>,
    ) -> BodiesFound {
        if self.is_empty() {
            return BodiesFound::default();
        }
        let index: Vec<usize> = (0..poses.len())
            .filter(|&i| poses[i].method == PoseMethod::Triangulated)
            .collect();
        let points: Vec<Point3<f64>> = index
            .iter()
            .map(|&i| Point3::from(poses[i].position_m))
            .collect();
        let defs_now = &self.markers_m;
        let ids: Vec<u32> = index.iter().map(|&i| poses[i].object_id).collect();
        let mut refine = |body: usize, markers: &[Option<usize>], pose: &Isometry3<f64>| {
            let seen = seen?;
            let cams = seen.cameras;
            let projections: Vec<_> = cams
                .iter()
                .map(|c| move |p: &Point3<f64>| c.project(p))
                .collect();
            let mut sightings = Vec::new();
            for (k, p) in markers.iter().enumerate() {
                let Some(p) = p else { continue };
                for (cam, pixel) in seen.pixels_of(ids[*p]) {
                    sightings.push(stereoscope_bodies::Sighting {
                        marker_body: defs_now[body][k],
                        project: &projections[*cam],
                        pixel: *pixel,
                    });
                }
            }
            stereoscope_bodies::refine_reprojection(pose, &sightings, 10).map(|(p, _)| p)
        };
        let found = self
            .tracker
            .update_refined(&points, timestamp_ns, &mut refine);
        let unseen = unseen_markers(&found, &self.markers_m);
        let defs = self.tracker.defs();
        let bodies = found
            .iter()
            .map(|b| {
                let def = &defs[b.body];
                for (k, p) in b.markers.iter().enumerate() {
                    if let Some(p) = p {
                        poses[index[*p]].body = Some(BodyLabel {
                            name: def.name.clone(),
                            marker: k as u32,
                        });
                    }
                }
                body_pose(def, b)
            })
            .collect();
        BodiesFound { bodies, unseen }
    }
}

/// Each found body's markers not seen this set: world position and velocity (metres, metres
/// per second).
fn unseen_markers(found: &[TrackedBody], markers_m: &[Vec<Point3<f64>>]) -> Vec<MarkerMotion> {
    let mut out = Vec::new();
    for b in found.iter().filter(|b| !b.held) {
        for (k, m) in b.markers.iter().enumerate() {
            let Some(body_m) = markers_m.get(b.body).and_then(|d| d.get(k)) else {
                continue;
            };
            if m.is_some() {
                continue;
            }
            let arm = b.world_from_body.rotation * body_m.coords;
            out.push((
                b.world_from_body * body_m,
                b.velocity_m_per_s + b.angular_velocity_rad_per_s.cross(&arm),
            ));
        }
    }
    out
}

fn body_pose(def: &stereoscope_bodies::BodyDef, b: &TrackedBody) -> BodyPose {
    let t = b.world_from_body.translation.vector;
    let q = b.world_from_body.rotation;
    let (v, w) = (b.velocity_m_per_s, b.angular_velocity_rad_per_s);
    BodyPose {
        name: def.name.clone(),
        position_m: [t.x, t.y, t.z],
        orientation_xyzw: [q.i, q.j, q.k, q.w],
        velocity_m_per_s: [v.x, v.y, v.z],
        angular_velocity_rad_per_s: [w.x, w.y, w.z],
        residual_mm: b.residual_m * 1e3,
        markers_seen: b.markers.iter().filter(|m| m.is_some()).count() as u32,
        markers: def.markers_m.len() as u32,
        held: b.held,
        roll_unobservable: def.markers_m.len() == 2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use stereoscope_proto::messages::{Message, PoseFrame, SCHEMA_VERSION};

    fn pose(id: u32, p: Point3<f64>) -> Pose {
        Pose {
            object_id: id,
            position_m: [p.x, p.y, p.z],
            velocity_m_per_s: [0.0; 3],
            heading_deg: None,
            heading_directed: false,
            method: PoseMethod::Triangulated,
            cameras: vec!["cam0".into(), "cam1".into()],
            residual_px: 0.1,
            out_of_range: false,
            body: None,
            model: None,
        }
    }

    /// A body among loose markers: its markers labelled, the loose one not, and the frame with
    /// the body passes the protocol's own checks.
    #[test]
    fn markers_are_labelled_and_the_body_posed() {
        let def = stereoscope_bodies::BodyDef {
            name: "head".into(),
            markers_m: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(0.09, 0.0, 0.0),
                Point3::new(0.0, 0.06, 0.0),
                Point3::new(0.02, 0.03, 0.045),
            ],
            tolerance_m: 0.003,
        };
        let world = Isometry3::from_parts(
            Translation3::new(0.1, -0.2, 0.9),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 2.5),
        );
        let mut poses: Vec<Pose> = def
            .markers_m
            .iter()
            .rev()
            .enumerate()
            .map(|(i, m)| pose(i as u32 + 1, world * m))
            .collect();
        poses.push(pose(9, Point3::new(0.5, 0.5, 0.5)));
        let mut b = Bodies::new(vec![def], 250_000_000);
        let bodies = b.update(&mut poses, 1);
        assert_eq!(bodies.len(), 1);
        let got = &bodies[0];
        assert_eq!((got.markers_seen, got.markers, got.held), (4, 4, false));
        assert!((Point3::from(got.position_m) - Point3::new(0.1, -0.2, 0.9)).norm() < 1e-9);
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            got.orientation_xyzw[3],
            got.orientation_xyzw[0],
            got.orientation_xyzw[1],
            got.orientation_xyzw[2],
        ));
        assert!(q.angle_to(&world.rotation) < 1e-9);
        // Listed in reverse: object 1 is marker 3.
        let label = poses[0].body.as_ref().unwrap();
        assert_eq!((label.name.as_str(), label.marker), ("head", 3));
        assert!(poses[4].body.is_none());
        let frame = PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            sequence: 0,
            timestamp_ns: 1,
            frame_published_ns: 1,
            published_ns: 1,
            cameras: vec![],
            poses,
            bodies,
            models: Vec::new(),
        };
        assert_eq!(PoseFrame::from_json(&frame.to_json()).unwrap(), frame);
        assert_eq!(PoseFrame::from_binary(&frame.to_binary()).unwrap(), frame);
    }
}
