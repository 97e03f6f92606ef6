//! Fusion's step over one set of observations: the fuser's points and poses (thesis Eq.
//! 4.28–4.38 generalised to N cameras, Eq. 4.15–4.27 for one camera, §4.1.1 headings; see
//! [`crate::fuser`]), then the rigid bodies among them ([`crate::bodies`]), refined on the
//! cameras' pixels of their markers; the bodies' unseen markers go back to the fuser for the
//! next set. The fusion service, replay and the ghost sweep all fuse through [`Fusion`], and
//! take their settings from [`FusionSettings::of_rig`].

use crate::bodies::Bodies;
use crate::fuser::{DEFAULT_CONFIRM_SETS, Fuser, FuserConfig};
use crate::pairing::PairingConfig;
use stereoscope_geometry::correspond::CorrespondConfig;
use stereoscope_proto::messages::{BodyPose, Observation, Pose};
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
            },
            gate_m: f.association_gate.map(|g| g * scale).unwrap_or(0.1),
            drop_after_ns: (f.drop_after_s.unwrap_or(2.0) * 1e9) as u64,
            confirm_sets: f.confirm_sets.unwrap_or(DEFAULT_CONFIRM_SETS),
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
}

impl Fusion {
    /// Fusion of `cameras` with `settings`, following `bodies`.
    pub fn new(cameras: &[RigCamera], settings: &FusionSettings, bodies: Bodies) -> Fusion {
        Fusion {
            fuser: Fuser::new(cameras, settings.fuser),
            bodies,
        }
    }

    /// The rig's fusion with its `[fusion]` settings and its `[[body]]`s.
    pub fn of_rig(rig: &Rig) -> Fusion {
        let settings = FusionSettings::of_rig(&rig.spec);
        let bodies = Bodies::new(stereoscope_rig::body_defs(&rig.spec), settings.body_hold_ns);
        Fusion::new(&rig.cameras, &settings, bodies)
    }

    /// Fuses one set (`(rig camera index, observation)`, at `timestamp_ns`, its oldest
    /// exposure): the objects' poses (bodies' markers labelled) and the bodies' poses.
    pub fn fuse(
        &mut self,
        set: &[(usize, Observation)],
        timestamp_ns: u64,
    ) -> (Vec<Pose>, Vec<BodyPose>) {
        let mut poses = self.fuser.fuse(set, timestamp_ns);
        let found = self
            .bodies
            .update_refined(&mut poses, timestamp_ns, self.fuser.sightings());
        self.fuser.expect_unseen(timestamp_ns, found.unseen);
        (poses, found.bodies)
    }
}
