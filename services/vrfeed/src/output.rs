//! What every protocol module of the feed shares (`docs/lab-protocols.md`): the pose frame as
//! outputs see it (bodies smoothed and predicted as the rig asks, markers with their labels, the
//! exposure and receipt times), the bodies' definitions, and one small interface — serve
//! clients, send a frame, count what happened.

use nalgebra::{Isometry3, Point3};

/// A rigid body as the rig defines it: its name and its markers in its own frame, metres.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyDef {
    pub name: String,
    pub markers_m: Vec<Point3<f64>>,
}

/// One body in one frame: its index in the rig's bodies, `world_from_body`, the RMS marker
/// residual, and whether it was measured in this frame (false: held through an occlusion).
#[derive(Debug, Clone, PartialEq)]
pub struct OutputBody {
    pub index: usize,
    pub world_from_body: Isometry3<f64>,
    pub residual_mm: f64,
    pub tracked: bool,
    /// World-frame velocity of the origin (m/s) and angular velocity (rad/s).
    pub velocity_m_per_s: [f64; 3],
    pub angular_velocity_rad_per_s: [f64; 3],
}

/// One 3D marker in one frame: where it is, which body marker it is (body index, marker
/// index) if any, and fusion's object id.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputMarker {
    pub position_m: Point3<f64>,
    pub label: Option<(usize, u32)>,
    pub object_id: u32,
}

/// One pose frame for the outputs.
#[derive(Debug, Clone, Copy)]
pub struct OutputFrame<'a> {
    /// Fusion's frame-set count.
    pub sequence: u64,
    /// Exposure of the set (its oldest frame), ns of the system clock.
    pub exposure_ns: u64,
    /// When the set's last frame was published by its capture, ns of the system clock.
    pub received_ns: u64,
    pub bodies: &'a [OutputBody],
    pub markers: &'a [OutputMarker],
    /// The kinematic models fitted in this frame (`docs/models.md`).
    pub models: &'a [stereoscope_proto::messages::ModelPose],
}

/// What a module did since it was last asked: frames sent, peers dropped or refused (by
/// reason), send errors, and the last error.
#[derive(Debug, Default)]
pub struct Counts {
    pub frames: u64,
    pub send_errors: u64,
    /// (reason, message) since the feed last reported.
    pub dropped: Vec<(&'static str, String)>,
    pub last_error: Option<String>,
}

impl Counts {
    pub fn drop(&mut self, reason: &'static str, message: String) {
        // Bounded between reports: a flood is counted by its first messages.
        if self.dropped.len() < 1024 {
            self.dropped.push((reason, message));
        }
    }

    pub fn send_error(&mut self, message: String) {
        self.send_errors += 1;
        if self.send_errors <= 3 || self.send_errors.is_power_of_two() {
            tracing::debug!("{message} ({} so far)", self.send_errors);
        }
        self.last_error = Some(message);
    }

    pub fn error(&mut self, message: String) {
        if self.last_error.as_ref() != Some(&message) {
            tracing::warn!("{message}");
        }
        self.last_error = Some(message);
    }
}

/// A protocol the feed serves. `poll` runs every step (at least every 5 ms) to serve
/// requests; `send` once per pose frame. Neither blocks.
pub trait Output {
    /// The protocol's name in health and the log (`natnet`, `qualisys`, …).
    fn name(&self) -> &'static str;
    fn poll(&mut self);
    fn send(&mut self, frame: &OutputFrame);
    fn counts(&mut self) -> &mut Counts;
    /// Clients connected now, where the protocol knows them.
    fn clients(&self) -> Option<usize>;
    /// The rig's bodies changed while running (`docs/bodies.md`): the feed's body table, in
    /// which a body keeps its index for as long as the feed runs and new ones are appended.
    /// True when the protocol took them in place; false when it must be opened again with them
    /// (the feed then drops it and opens it anew).
    fn set_bodies(&mut self, _bodies: &[BodyDef]) -> bool {
        false
    }
}
