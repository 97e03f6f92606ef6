//! Bodies over time: [`identify`](crate::identify) each frame, then keep each body's identity, velocity and
//! angular velocity across frames, and hold its last pose through a short full occlusion
//! (`docs/bodies.md`, "Over time").
//!
//! - A body is named by its definition, so its identity cannot change while it is seen; what
//!   this adds is the time between sightings: a body not found is reported with its last
//!   measured pose, flagged `held`, for at most `hold_ns`, then dropped until it is found again.
//! - A body seen in part can fit its points in more than one way (a pointer's two identical
//!   markers either way round; three markers of four forming a nearly isosceles triangle): the
//!   way nearest the previous pose is kept ([`crate::identify_near`]), so the pose does not
//!   flip between frames, and a body first seen that way is not reported until it is seen
//!   whole.
//! - Velocities are finite differences over consecutive sightings; after a gap longer than
//!   `hold_ns` they restart at zero.

use crate::{BodyDef, identify_near};
use nalgebra::{Isometry3, Point3, Vector3};

/// How long a body not seen keeps its identity and last pose, by default.
pub const DEFAULT_HOLD_NS: u64 = 250_000_000;

/// A pose refiner: `(body, each marker's point index, Kabsch pose)` → a better pose, or `None`
/// to keep it.
pub type Refine<'a> =
    dyn FnMut(usize, &[Option<usize>], &Isometry3<f64>) -> Option<Isometry3<f64>> + 'a;

/// One body as reported for a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedBody {
    /// Index into the definitions.
    pub body: usize,
    pub world_from_body: Isometry3<f64>,
    pub velocity_m_per_s: Vector3<f64>,
    /// World frame, radians per second.
    pub angular_velocity_rad_per_s: Vector3<f64>,
    /// RMS distance of the seen markers from the posed definition, metres.
    pub residual_m: f64,
    /// For each marker, the index of the point it was found at; all `None` when held.
    pub markers: Vec<Option<usize>>,
    /// Not seen in this frame: the last measured pose.
    pub held: bool,
}

#[derive(Debug, Clone)]
struct Track {
    pose: Isometry3<f64>,
    seen_ns: u64,
    residual_m: f64,
}

/// Identifies bodies frame after frame and follows them.
#[derive(Debug, Clone)]
pub struct BodyTracker {
    defs: Vec<BodyDef>,
    tracks: Vec<Option<Track>>,
    hold_ns: u64,
}

impl BodyTracker {
    /// `defs` are assumed checked ([`crate::check_bodies`]).
    pub fn new(defs: Vec<BodyDef>, hold_ns: u64) -> Self {
        let tracks = vec![None; defs.len()];
        BodyTracker {
            defs,
            tracks,
            hold_ns,
        }
    }

    pub fn defs(&self) -> &[BodyDef] {
        &self.defs
    }

    /// The bodies of one frame at `t_ns` among `points` (world, metres): those found, then
    /// those held.
    pub fn update(&mut self, points: &[Point3<f64>], t_ns: u64) -> Vec<TrackedBody> {
        self.update_refined(points, t_ns, &mut |_, _, _| None)
    }

    /// [`BodyTracker::update`] with each body's pose refined by `refine(body, markers, pose)`
    /// (`markers`: the point index of each marker; `None` keeps the Kabsch pose), before it
    /// is followed: fusion refines on the cameras' pixels ([`crate::refine_reprojection`]).
    pub fn update_refined(
        &mut self,
        points: &[Point3<f64>],
        t_ns: u64,
        refine: &mut Refine<'_>,
    ) -> Vec<TrackedBody> {
        let mut out = Vec::new();
        let mut found = vec![false; self.defs.len()];
        // Each body's last pose, while it is held: it settles how a body seen in part fits.
        let near: Vec<Option<Isometry3<f64>>> = self
            .tracks
            .iter()
            .map(|t| {
                t.as_ref()
                    .filter(|t| t_ns > t.seen_ns && t_ns - t.seen_ns <= self.hold_ns)
                    .map(|t| t.pose)
            })
            .collect();
        for mut m in identify_near(&self.defs, points, &near) {
            if let Some(better) = refine(m.body, &m.markers, &m.world_from_body) {
                let def = &self.defs[m.body];
                let (sq, n) = m
                    .markers
                    .iter()
                    .enumerate()
                    .filter_map(|(k, p)| {
                        p.map(|p| (better * def.markers_m[k] - points[p]).norm_squared())
                    })
                    .fold((0.0, 0usize), |(s, n), d| (s + d, n + 1));
                m.world_from_body = better;
                m.residual_m = (sq / n.max(1) as f64).sqrt();
            }
            let prev = self.tracks[m.body]
                .as_ref()
                .filter(|t| t_ns > t.seen_ns && t_ns - t.seen_ns <= self.hold_ns);
            let (velocity, angular) = match prev {
                Some(p) => {
                    let dt = (t_ns - p.seen_ns) as f64 * 1e-9;
                    let v = (m.world_from_body.translation.vector - p.pose.translation.vector) / dt;
                    let dr = m.world_from_body.rotation * p.pose.rotation.inverse();
                    (v, dr.scaled_axis() / dt)
                }
                None => (Vector3::zeros(), Vector3::zeros()),
            };
            found[m.body] = true;
            self.tracks[m.body] = Some(Track {
                pose: m.world_from_body,
                seen_ns: t_ns,
                residual_m: m.residual_m,
            });
            out.push(TrackedBody {
                body: m.body,
                world_from_body: m.world_from_body,
                velocity_m_per_s: velocity,
                angular_velocity_rad_per_s: angular,
                residual_m: m.residual_m,
                markers: m.markers,
                held: false,
            });
        }
        for (b, track) in self.tracks.iter_mut().enumerate() {
            if found[b] {
                continue;
            }
            let keep = track
                .as_ref()
                .is_some_and(|t| t_ns >= t.seen_ns && t_ns - t.seen_ns <= self.hold_ns);
            if !keep {
                *track = None;
                continue;
            }
            if let Some(t) = track {
                out.push(TrackedBody {
                    body: b,
                    world_from_body: t.pose,
                    velocity_m_per_s: Vector3::zeros(),
                    angular_velocity_rad_per_s: Vector3::zeros(),
                    residual_m: t.residual_m,
                    markers: vec![None; self.defs[b].markers_m.len()],
                    held: true,
                });
            }
        }
        out.sort_by_key(|t| t.body);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn head() -> BodyDef {
        BodyDef {
            name: "head".into(),
            markers_m: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(0.09, 0.0, 0.0),
                Point3::new(0.0, 0.06, 0.0),
                Point3::new(0.02, 0.03, 0.045),
            ],
            tolerance_m: 0.003,
        }
    }

    fn wand() -> BodyDef {
        BodyDef {
            name: "wand".into(),
            markers_m: vec![Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 0.0, 0.08)],
            tolerance_m: 0.003,
        }
    }

    fn placed(def: &BodyDef, pose: &Isometry3<f64>) -> Vec<Point3<f64>> {
        def.markers_m.iter().map(|m| pose * m).collect()
    }

    #[test]
    fn velocity_hold_through_occlusion_then_drop() {
        let mut t = BodyTracker::new(vec![head()], 100_000_000);
        let pose = |x: f64, yaw: f64| {
            Isometry3::from_parts(
                Translation3::new(x, 0.2, 1.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            )
        };
        let r = t.update(&placed(&head(), &pose(0.0, 0.0)), 0);
        assert_eq!((r.len(), r[0].held), (1, false));
        assert_eq!(r[0].velocity_m_per_s, Vector3::zeros());
        // 10 ms later, 1 cm along x and 0.01 rad about z: 1 m/s and 1 rad/s.
        let r = t.update(&placed(&head(), &pose(0.01, 0.01)), 10_000_000);
        assert!((r[0].velocity_m_per_s.x - 1.0).abs() < 1e-6, "{r:?}");
        assert!(
            (r[0].angular_velocity_rad_per_s.z - 1.0).abs() < 1e-6,
            "{r:?}"
        );
        // Hidden: held with the last pose, for up to 100 ms.
        let r = t.update(&[], 60_000_000);
        assert_eq!((r.len(), r[0].held), (1, true));
        assert!((r[0].world_from_body.translation.x - 0.01).abs() < 1e-9);
        assert!(r[0].markers.iter().all(|m| m.is_none()));
        assert!(t.update(&[], 200_000_000).is_empty());
        // Seen again after the hold: found, with velocities restarted.
        let r = t.update(&placed(&head(), &pose(0.5, 0.0)), 210_000_000);
        assert_eq!((r.len(), r[0].held), (1, false));
        assert_eq!(r[0].velocity_m_per_s, Vector3::zeros());
    }

    /// The demo's helmet: markers 0, 2 and 3 form a nearly equilateral triangle, so seen alone
    /// they fit the definition turned over. Alone they give no pose; after a whole sighting the
    /// right one.
    #[test]
    fn a_body_seen_in_part_never_turns_over() {
        let def = BodyDef {
            name: "head".into(),
            markers_m: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(0.18, 0.0, 0.0),
                Point3::new(0.0, 0.11, 0.0),
                Point3::new(0.06, 0.06, 0.08),
            ],
            tolerance_m: 0.01,
        };
        let pose = Isometry3::from_parts(
            Translation3::new(-0.1, 0.3, 0.6),
            UnitQuaternion::from_euler_angles(0.2, -0.1, 2.0),
        );
        let all = placed(&def, &pose);
        let part = [all[0], all[2], all[3]];
        assert!(crate::identify(std::slice::from_ref(&def), &part).is_empty());
        let mut t = BodyTracker::new(vec![def], DEFAULT_HOLD_NS);
        assert!(t.update(&part, 0).is_empty());
        assert_eq!(t.update(&all, 10_000_000).len(), 1);
        for k in 2..6u64 {
            let r = t.update(&part, k * 10_000_000);
            assert_eq!((r.len(), r[0].held), (1, false));
            assert!(r[0].world_from_body.rotation.angle_to(&pose.rotation) < 1e-6);
            assert_eq!(r[0].markers, vec![Some(0), None, Some(1), Some(2)]);
        }
    }

    #[test]
    fn a_pointer_keeps_its_direction_and_reports_no_roll() {
        let mut t = BodyTracker::new(vec![wand()], DEFAULT_HOLD_NS);
        let tilt = UnitQuaternion::from_euler_angles(0.3, 0.0, 0.0);
        let pose = Isometry3::from_parts(Translation3::new(0.1, 0.0, 1.0), tilt);
        let pts = placed(&wand(), &pose);
        let first = t.update(&pts, 0);
        // The same points listed the other way round: still the same direction.
        for k in 1..5u64 {
            let swapped = [pts[1], pts[0]];
            let r = t.update(&swapped, k * 10_000_000);
            let axis = r[0].world_from_body.rotation * Vector3::z();
            let want = first[0].world_from_body.rotation * Vector3::z();
            assert!((axis - want).norm() < 1e-9, "{axis} vs {want}");
            assert_eq!(r[0].markers, vec![Some(1), Some(0)]);
        }
        // The rotation is the shortest arc: no twist about the axis.
        let q = first[0].world_from_body.rotation;
        let arc = UnitQuaternion::rotation_between(&Vector3::z(), &(q * Vector3::z())).unwrap();
        assert!(q.angle_to(&arc) < 1e-9);
    }
}
