//! Fusion's step over one set of observations: the fuser's points and poses (thesis Eq.
//! 4.28–4.38 generalised to N cameras, Eq. 4.15–4.27 for one camera, §4.1.1 headings; see
//! [`crate::fuser`]), then the rigid bodies among them ([`crate::bodies`]), refined on the
//! cameras' pixels of their markers; the bodies' unseen markers go back to the fuser for the
//! next set. The fusion service, replay and the ghost sweep all fuse through [`Fusion`], and
//! take their settings from [`FusionSettings::of_rig`].

use crate::bodies::Bodies;
use crate::fuser::{DEFAULT_CONFIRM_SETS, Fuser, FuserConfig};
use crate::models::Models;
use crate::pairing::PairingConfig;
use stereoscope_geometry::correspond::CorrespondConfig;
use stereoscope_proto::messages::{BodyPose, ModelPose, Observation, Pose};
use stereoscope_rig::schema::{ObservationRoute, RigFile};
use stereoscope_rig::{Rig, RigCamera};

/// Fusion's settings from the rig file's `[fusion]` table (defaults in `docs/services.md`;
/// values checked when the rig was loaded).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusionSettings {
    pub pairing: PairingConfig,
    pub fuser: FuserConfig,
    /// Every camera's observations come over Zenoh, even from workers on fusion's PC.
    pub all_zenoh: bool,
    /// How long a body unseen stays published as held.
    pub body_hold_ns: u64,
}

impl FusionSettings {
    pub fn of_rig(file: &RigFile) -> FusionSettings {
        let f = file.fusion.clone().unwrap_or_default();
        let scale = file.units.metres();
        let ms = |v: Option<f64>, d: f64| (v.unwrap_or(d) * 1e6) as u64;
        let pairing = PairingConfig {
            max_skew_ns: ms(f.max_skew_ms, 5.0),
            max_wait_ns: ms(f.max_wait_ms, 20.0),
            camera_timeout_ns: ms(f.camera_timeout_ms, 500.0),
            max_ahead_ns: ms(f.clock_window_ms, 1000.0),
            // A replay's frames keep their recorded times.
            max_behind_ns: f
                .replay_sets
                .is_none()
                .then(|| ms(f.clock_window_ms, 1000.0)),
        };
        let d = CorrespondConfig::default();
        let fuser = FuserConfig {
            correspond: CorrespondConfig {
                max_epipolar_px: f.max_epipolar_px.unwrap_or(d.max_epipolar_px),
                max_residual_px: f.max_residual_px.unwrap_or(d.max_residual_px),
                ..d
            },
            gate_m: f.association_gate.map(|g| g * scale).unwrap_or(0.1),
            drop_after_ns: (f.drop_after_s.unwrap_or(2.0) * 1e9) as u64,
            confirm_sets: f.confirm_sets.unwrap_or(DEFAULT_CONFIRM_SETS),
            min_views_to_start: f
                .min_views_to_start
                .map_or(if file.cameras.len() >= 6 { 3 } else { 2 }, |n| n as usize),
            volume_m: f.volume.map(|v| {
                let p =
                    |a: [f64; 3]| nalgebra::Point3::new(a[0] * scale, a[1] * scale, a[2] * scale);
                (p(v.min), p(v.max))
            }),
            ..FuserConfig::default()
        };
        let hold_ms = f
            .body_hold_ms
            .unwrap_or(stereoscope_bodies::tracker::DEFAULT_HOLD_NS as f64 * 1e-6);
        FusionSettings {
            pairing,
            fuser,
            all_zenoh: f.observations == Some(ObservationRoute::Zenoh),
            body_hold_ns: (hold_ms * 1e6) as u64,
        }
    }
}

/// One rig's fusion: its objects and bodies over sets.
#[derive(Debug)]
pub struct Fusion {
    pub fuser: Fuser,
    pub bodies: Bodies,
    /// The rig's kinematic models, fitted to each set's markers after the bodies'.
    pub models: Models,
    /// The models of the set fused last ([`Fusion::take_models`]).
    models_found: Vec<ModelPose>,
    /// Move each camera's blobs to the set's instant before triangulating (on by default;
    /// see [`Fusion::fuse`]).
    pub interpolate: bool,
    /// Each camera's last two observations, as they came, the newer first (for the
    /// interpolation).
    last: Vec<[Option<Observation>; 2]>,
    /// Poses left out of sets that made more than a pose frame carries
    /// ([`stereoscope_proto::messages::limits::MAX_POSES`]), counted.
    pub dropped_poses: u64,
}

/// Camera `o`'s blobs moved to `t_ns`: each blob tracked in `prev` too (same track id, neither
/// lost nor merged) goes along its track to where it was at `t_ns` — between the frames when
/// `prev` is older than `t_ns`, as a set's instant (its oldest exposure) always is for a camera
/// exposed after it. Through the blob's centroids in `older`, `prev` and `o` where it was
/// tracked in all three (a parabola: a marker swung round follows its curve), else along the
/// straight line from `prev`. Blobs new in `o`, and an `o` at `t_ns` already, are left as they
/// are; nothing is extrapolated beyond `prev`.
pub fn interpolated(
    o: &Observation,
    prev: Option<&Observation>,
    older: Option<&Observation>,
    t_ns: u64,
) -> Observation {
    let mut out = o.clone();
    let Some(prev) = prev else {
        return out;
    };
    if o.timestamp_ns <= t_ns || prev.timestamp_ns >= o.timestamp_ns || t_ns < prev.timestamp_ns {
        return out;
    }
    use stereoscope_proto::messages::{BlobObservation, TrackState};
    let same = |frame: &Observation, id: u32| -> Option<(f64, f64)> {
        frame
            .blobs
            .iter()
            .find(|p: &&BlobObservation| {
                p.track_id == id && p.status != TrackState::Lost && !p.merged
            })
            .map(|p| (p.x_px, p.y_px))
    };
    // Times relative to `o`'s, seconds.
    let dt = |frame: &Observation| (frame.timestamp_ns as f64 - o.timestamp_ns as f64) * 1e-9;
    let (t, t1) = ((t_ns as f64 - o.timestamp_ns as f64) * 1e-9, dt(prev));
    let t2 = older.filter(|f| f.timestamp_ns < prev.timestamp_ns).map(dt);
    for b in out
        .blobs
        .iter_mut()
        .filter(|b| b.status == TrackState::Tracked && !b.merged)
    {
        let Some((x1, y1)) = same(prev, b.track_id) else {
            continue;
        };
        let (x0, y0) = (b.x_px, b.y_px);
        match (older.and_then(|f| same(f, b.track_id)), t2) {
            (Some((x2, y2)), Some(t2)) => {
                // Lagrange through (0, p0), (t1, p1), (t2, p2).
                let l0 = (t - t1) * (t - t2) / ((0.0 - t1) * (0.0 - t2));
                let l1 = (t - 0.0) * (t - t2) / ((t1 - 0.0) * (t1 - t2));
                let l2 = (t - 0.0) * (t - t1) / ((t2 - 0.0) * (t2 - t1));
                b.x_px = l0 * x0 + l1 * x1 + l2 * x2;
                b.y_px = l0 * y0 + l1 * y1 + l2 * y2;
            }
            _ => {
                let back = t / t1;
                b.x_px = x0 + back * (x1 - x0);
                b.y_px = y0 + back * (y1 - y0);
            }
        }
    }
    out
}

impl Fusion {
    /// Fusion of `cameras` with `settings`, following `bodies`.
    pub fn new(cameras: &[RigCamera], settings: &FusionSettings, bodies: Bodies) -> Fusion {
        Fusion {
            fuser: Fuser::new(cameras, settings.fuser),
            bodies,
            models: Models::default(),
            models_found: Vec::new(),
            interpolate: true,
            last: vec![[None, None]; cameras.len()],
            dropped_poses: 0,
        }
    }

    /// The rig's fusion with its `[fusion]` settings and its `[[body]]`s.
    pub fn of_rig(rig: &Rig) -> Fusion {
        let settings = FusionSettings::of_rig(&rig.spec);
        let bodies = Bodies::new(stereoscope_rig::body_defs(&rig.spec), settings.body_hold_ns);
        let mut f = Fusion::new(&rig.cameras, &settings, bodies);
        f.models = Models::new(rig.models.clone());
        f
    }

    /// Follows `rig`'s `[[body]]`s and `[[model]]`s from the next set on (a rig file changed
    /// while fusion runs): bodies and models found again from their definitions; objects, ids
    /// and settings as they were.
    pub fn set_bodies_and_models(&mut self, rig: &Rig) {
        let settings = FusionSettings::of_rig(&rig.spec);
        self.bodies = Bodies::new(stereoscope_rig::body_defs(&rig.spec), settings.body_hold_ns);
        self.models = Models::new(rig.models.clone());
    }

    /// The names of the bodies followed.
    pub fn body_names(&self) -> Vec<&str> {
        self.bodies.names()
    }

    /// Fuses one set (`(rig camera index, observation)`, at `timestamp_ns`, its oldest
    /// exposure): the objects' poses (bodies' markers labelled) and the bodies' poses.
    /// Cameras that are not synchronised expose at different instants: with `interpolate`,
    /// each later camera's blobs are first moved back to the set's instant along their track
    /// from that camera's previous frame ([`interpolated`]), so a moving marker is
    /// triangulated from where every camera saw it at one instant.
    pub fn fuse(
        &mut self,
        set: &[(usize, Observation)],
        timestamp_ns: u64,
    ) -> (Vec<Pose>, Vec<BodyPose>) {
        let moved: Vec<(usize, Observation)>;
        let originals = set;
        let set = if self.interpolate && set.iter().any(|(_, o)| o.timestamp_ns > timestamp_ns) {
            moved = set
                .iter()
                .map(|(c, o)| {
                    let last = self.last.get(*c);
                    let prev = last.and_then(|l| l[0].as_ref());
                    let older = last.and_then(|l| l[1].as_ref());
                    (*c, interpolated(o, prev, older, timestamp_ns))
                })
                .collect();
            &moved[..]
        } else {
            set
        };
        for (c, o) in originals {
            if let Some(slots) = self.last.get_mut(*c) {
                slots[1] = slots[0].take();
                slots[0] = Some(o.clone());
            }
        }
        let mut poses = self.fuser.fuse(set, timestamp_ns);
        let found = self
            .bodies
            .update_refined(&mut poses, timestamp_ns, self.fuser.sightings());
        self.fuser.expect_unseen(timestamp_ns, found.unseen);
        self.models_found = self.models.update(&mut poses);
        // A pose frame carries at most MAX_POSES poses (receivers refuse more): the rest of an
        // overfull set is left out and counted.
        let max = stereoscope_proto::messages::limits::MAX_POSES;
        if poses.len() > max {
            self.dropped_poses += (poses.len() - max) as u64;
            poses.truncate(max);
        }
        (poses, found.bodies)
    }

    /// The kinematic models fitted to the set fused last (`docs/models.md`), taken.
    pub fn take_models(&mut self) -> Vec<ModelPose> {
        std::mem::take(&mut self.models_found)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{BlobObservation, SCHEMA_VERSION, TrackState};

    fn obs(t_ns: u64, blobs: &[(u32, f64, TrackState)]) -> Observation {
        Observation {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            camera: "c".into(),
            sequence: 0,
            timestamp_ns: t_ns,
            frame_published_ns: t_ns,
            published_ns: t_ns,
            width_px: 640,
            height_px: 480,
            threshold: 100,
            dark: false,
            full_frame: false,
            dropped_blobs: 0,
            blobs: blobs
                .iter()
                .map(|&(id, x, status)| BlobObservation {
                    track_id: id,
                    status,
                    area_px: 20.0,
                    x_px: x,
                    y_px: 2.0 * x,
                    mu20: 1.0,
                    mu02: 1.0,
                    mu11: 0.0,
                    orientation_deg: 0.0,
                    roundness: 1.0,
                    heading_deg: 0.0,
                    directed: false,
                    heading_ambiguous: false,
                    clipped: false,
                    merged: false,
                    window_px: [0, 0, 639, 479],
                    bbox_px: [0, 0, 10, 10],
                })
                .collect(),
        }
    }

    #[test]
    fn blobs_move_back_along_their_track_to_the_sets_instant() {
        let prev = obs(
            1_000,
            &[
                (1, 100.0, TrackState::Tracked),
                (2, 50.0, TrackState::Tracked),
            ],
        );
        let now = obs(
            2_000,
            &[
                (1, 110.0, TrackState::Tracked),
                (2, 60.0, TrackState::New),
                (3, 70.0, TrackState::Tracked),
            ],
        );
        let at = interpolated(&now, Some(&prev), None, 1_250);
        // Tracked in both: a quarter of the way from the previous centroid.
        assert_eq!((at.blobs[0].x_px, at.blobs[0].y_px), (102.5, 205.0));
        // With the frame before: along the parabola through the three (x = t² here, in
        // microseconds: 0 at 0, 1 at 1 000, 4 at 2 000; at 1 500, 2.25).
        let older = obs(0, &[(1, 0.0, TrackState::Tracked)]);
        let prev2 = obs(1_000, &[(1, 1.0, TrackState::Tracked)]);
        let now2 = obs(2_000, &[(1, 4.0, TrackState::Tracked)]);
        let curved = interpolated(&now2, Some(&prev2), Some(&older), 1_500);
        assert!(
            (curved.blobs[0].x_px - 2.25).abs() < 1e-9,
            "{}",
            curved.blobs[0].x_px
        );
        // New, or not in the previous frame: as seen.
        assert_eq!(at.blobs[1].x_px, 60.0);
        assert_eq!(at.blobs[2].x_px, 70.0);
        // At the set's instant already, without a previous frame, or further back than it:
        // unchanged.
        assert_eq!(interpolated(&now, Some(&prev), None, 2_000), now);
        assert_eq!(interpolated(&now, None, None, 1_250), now);
        assert_eq!(interpolated(&now, Some(&prev), None, 500), now);
    }
}
