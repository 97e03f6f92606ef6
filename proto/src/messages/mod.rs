//! The messages services exchange (`docs/protocol.md`, "Live messages"): one serde type each,
//! carried as JSON on Zenoh (so a client in any language can read them) and as postcard, a
//! compact binary form of the same type, in iceoryx2 samples on the same PC.
//!
//! Optional fields added later carry `#[serde(default)]` so older JSON still reads, and are
//! always written (never `skip_serializing_if`: postcard's fields are positional, and a
//! skipped one would shift every field after it).
//!
//! Units are in the field names: `_px` image pixels (`docs/conventions.md`), `_m` metres in the
//! rig's world frame, `_deg` degrees, `_ns` nanoseconds since the Unix epoch (CLOCK_REALTIME).

use serde::{Deserialize, Serialize};

mod check;
mod control;
mod detail;
mod models;
mod view;
use check::{Checked, Checker};
pub use check::{DecodeError, Invalid, limits};
pub use control::TokenRenewal;
pub use detail::Detail;
pub use models::{JointState, LinkPose, ModelLabel, ModelPose, ModelUpdate};
pub use view::{CameraCoverage, MAX_COVERAGE_CELLS, PREVIEW_HISTOGRAM_BINS, Preview, WandCoverage};

/// Version of every message schema below; a receiver rejects a message with another.
pub const SCHEMA_VERSION: u32 = 1;

/// What a moment worker reports about one tracked blob.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlobObservation {
    /// The worker's track id (stable while the camera keeps the object; per camera).
    pub track_id: u32,
    /// "new" (first seen this frame), "tracked", or "lost" (not found; position predicted).
    pub status: TrackState,
    /// Area in pixels (binary count).
    pub area_px: f64,
    /// Centroid, pixels (grey-level weighted when the worker computes weights).
    pub x_px: f64,
    pub y_px: f64,
    /// Central second moments, sums over pixels (OpenCV's `mu20` convention).
    pub mu20: f64,
    pub mu02: f64,
    pub mu11: f64,
    /// Major-axis angle, degrees CCW on screen from +x, (−90, 90], PAR-corrected.
    pub orientation_deg: f64,
    /// Minor/major axis ratio (1 = round: the axis means nothing).
    pub roundness: f64,
    /// The camera's continuous heading of the blob, [0, 360).
    pub heading_deg: f64,
    /// `heading_deg` points along the target (third-order moments), not just along its axis.
    pub directed: bool,
    /// The heading step was ambiguous (≥ 90° from the prediction) or the blob near-circular.
    pub heading_ambiguous: bool,
    /// The blob touches the frame border or its window's edge (moments are of a cut shape).
    pub clipped: bool,
    /// The blob holds another tracked object's image too (its area far above its track's
    /// usual one, another track lost inside it): its centroid is between the two, so fusion
    /// does not use it.
    #[serde(default)]
    pub merged: bool,
    /// Tracking window searched this frame, `[x0, y0, x1, y1]` inclusive.
    pub window_px: [u32; 4],
    /// Bounding box, `[x0, y0, x1, y1]` inclusive.
    pub bbox_px: [u32; 4],
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackState {
    New,
    Tracked,
    Lost,
}

/// One camera's result for one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Observation {
    pub schema: u32,
    pub rig: String,
    pub camera: String,
    /// The frame's sequence number (capture's count).
    pub sequence: u64,
    /// Exposure time of the frame.
    pub timestamp_ns: u64,
    /// When capture published the frame.
    pub frame_published_ns: u64,
    /// When the worker published this observation.
    pub published_ns: u64,
    pub width_px: u32,
    pub height_px: u32,
    /// Foreground threshold used for the frame (`pixel >= threshold`; with `dark`,
    /// `pixel <= threshold`).
    pub threshold: u32,
    /// The worker looks for dark targets on a bright background (the rig's `polarity`).
    #[serde(default)]
    pub dark: bool,
    /// The whole frame was searched (no object tracked, or looking for new ones).
    pub full_frame: bool,
    /// Blobs found but not reported (over capacity).
    pub dropped_blobs: u32,
    pub blobs: Vec<BlobObservation>,
}

/// How a position was recovered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseMethod {
    /// Triangulated from two or more cameras (Eq. 4.28–4.38 generalised).
    Triangulated,
    /// One camera, depth from the blob's area (Eq. 4.15–4.27).
    DepthFromArea,
}

/// One object's pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose {
    /// Fusion's object id, stable over time; never reused while fusion runs.
    pub object_id: u32,
    pub position_m: [f64; 3],
    /// Velocity, metres per second.
    pub velocity_m_per_s: [f64; 3],
    /// Heading about world +z, counter-clockwise from +x seen from above, unwrapped over
    /// frames, [0, 360). `None` while no camera sees an axis.
    pub heading_deg: Option<f64>,
    /// The heading points along the target; when false it is an axis and may be 180° off.
    pub heading_directed: bool,
    pub method: PoseMethod,
    /// Cameras whose blobs gave the position.
    pub cameras: Vec<String>,
    /// RMS reprojection residual of the position over those cameras, pixels (0 for one camera).
    pub residual_px: f64,
    /// Depth from area was outside its calibrated range (the value is not to be trusted).
    pub out_of_range: bool,
    /// The rigid body this marker was identified as part of, and its index in the body's
    /// definition (`docs/bodies.md`); `None` for a loose marker.
    #[serde(default)]
    pub body: Option<BodyLabel>,
    /// The kinematic model, link and marker this point was fitted as (`docs/models.md`);
    /// `None` for a point no valid model fit took.
    #[serde(default)]
    pub model: Option<ModelLabel>,
}

/// Which body, and which of its markers, a point is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyLabel {
    pub name: String,
    pub marker: u32,
}

/// One rigid body's pose (`docs/bodies.md`): `world_from_body` as a position and a unit
/// quaternion, with how it was measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyPose {
    /// The body's name from the rig's `[[body]]` table.
    pub name: String,
    /// The body origin in the world frame, metres.
    pub position_m: [f64; 3],
    /// `world_from_body` rotation, unit quaternion in the order x, y, z, w.
    pub orientation_xyzw: [f64; 4],
    /// Velocity of the origin, metres per second (0 until two frames were seen).
    pub velocity_m_per_s: [f64; 3],
    /// Angular velocity in the world frame, radians per second.
    pub angular_velocity_rad_per_s: [f64; 3],
    /// RMS distance between the measured markers and the posed definition, millimetres.
    pub residual_mm: f64,
    /// Markers identified in this frame, and how many the body has.
    pub markers_seen: u32,
    pub markers: u32,
    /// Not seen in this frame: the pose is the last measured one, held (for at most the rig's
    /// `[fusion] body_hold_ms`), so the body keeps its identity through a short occlusion.
    pub held: bool,
    /// A two-marker body (a pointer, the thesis's two-ball target): the rotation about its
    /// axis is unobservable and reported as zero twist from the shortest rotation of the
    /// definition's axis onto the measured one — never a measured roll.
    pub roll_unobservable: bool,
}

/// All poses fusion recovered from one set of frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseFrame {
    pub schema: u32,
    pub rig: String,
    /// Fusion's count of frame sets.
    pub sequence: u64,
    /// Exposure time of the frame set (the earliest of its frames).
    pub timestamp_ns: u64,
    /// Latest publication time of the frames used.
    pub frame_published_ns: u64,
    /// When fusion published the poses.
    pub published_ns: u64,
    /// Cameras whose observations are in the set.
    pub cameras: Vec<String>,
    pub poses: Vec<Pose>,
    /// Rigid bodies found among the poses (absent in recordings made before bodies existed).
    #[serde(default)]
    pub bodies: Vec<BodyPose>,
    /// Kinematic models fitted to the poses (`docs/models.md`; absent in recordings made
    /// before models existed).
    #[serde(default)]
    pub models: Vec<ModelPose>,
}

/// One body's pose on its own key (`stereoscope/<rig>/bodies/<name>`), with the times of the
/// frame set it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyUpdate {
    pub schema: u32,
    pub rig: String,
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub frame_published_ns: u64,
    pub published_ns: u64,
    pub body: BodyPose,
}

/// One object's pose on its own key (`stereoscope/<rig>/pose/<object_id>`), with the times
/// of the frame set it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseUpdate {
    pub schema: u32,
    pub rig: String,
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub frame_published_ns: u64,
    pub published_ns: u64,
    pub pose: Pose,
}

/// A synthetic camera's ground truth for one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Truth {
    pub schema: u32,
    pub camera: String,
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub targets: Vec<TargetTruth>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetTruth {
    /// Index of the target in the scene.
    pub target: u32,
    pub position_m: [f64; 3],
    pub heading_deg: f64,
    /// The target has a long axis (a heading can be measured): false for a sphere or a disc.
    pub has_axis: bool,
    /// The target is symmetric end to end: its heading is only defined modulo 180°.
    pub symmetric: bool,
    /// Some of the target's image is in the frame.
    pub visible: bool,
    pub area_px: f64,
    /// The image's centroid; `[0, 0]` when not visible (every number on the wire is finite).
    pub centroid_px: [f64; 2],
    /// A rigid body target: its name in the rig and its `world_from_body` rotation (x, y, z, w).
    #[serde(default)]
    pub body: Option<String>,
    #[serde(default)]
    pub orientation_xyzw: Option<[f64; 4]>,
}

/// A service's periodic report of itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Health {
    pub schema: u32,
    pub rig: String,
    pub host: String,
    /// "capture/cam0", "moments/cam0", "fusion".
    pub service: String,
    pub pid: u32,
    pub started_ns: u64,
    pub published_ns: u64,
    /// Items handled (frames, observations or frame sets) since start.
    pub processed: u64,
    /// Items handled per second over the last report interval.
    pub rate_hz: f64,
    /// Items lost (frames dropped for a slow consumer, skipped sequence numbers).
    pub dropped: u64,
    /// Bad inputs rejected (undecodable payloads, inconsistent frames).
    pub rejected: u64,
    /// The last problem met, if any, with what it concerned.
    pub last_error: Option<String>,
    /// Service-specific figures (threshold, tracked objects, cameras live …).
    #[serde(default)]
    pub detail: std::collections::BTreeMap<String, String>,
}

impl Health {
    /// One of the service's own figures, if it reported it.
    pub fn detail(&self, key: Detail) -> Option<&str> {
        self.detail.get(key.key()).map(String::as_str)
    }

    /// What this report says the service lost, in words, one line each: frames dropped (and
    /// which, when the service names them), inputs rejected (with the last reason),
    /// observations late for their set, recorded sets formed short. Empty when nothing was.
    pub fn losses(&self) -> Vec<String> {
        let service = &self.service;
        let mut out = Vec::new();
        if self.dropped > 0 {
            let which = self
                .detail(Detail::LastLost)
                .map(|l| format!(" (the last: {l})"))
                .unwrap_or_default();
            out.push(format!("{service}: {} dropped{which}", self.dropped));
        }
        if self.rejected > 0 {
            let why = self.last_error.as_deref().unwrap_or("");
            out.push(format!(
                "{service}: {} rejected (last: {why})",
                self.rejected
            ));
        }
        if let Some(late) = self.detail(Detail::Late).filter(|l| *l != "0") {
            out.push(format!("{service}: {late} observations late for their set"));
        }
        if let Some(short) = self.detail(Detail::ShortSets) {
            out.push(format!(
                "{service}: {short} recorded sets formed without one of their cameras"
            ));
        }
        out
    }
}

impl Pose {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.finite("position_m", &self.position_m)?;
        c.finite("velocity_m_per_s", &self.velocity_m_per_s)?;
        if let Some(h) = self.heading_deg {
            c.finite("heading_deg", &[h])?;
        }
        c.names("cameras", &self.cameras)?;
        if let Some(b) = &self.body {
            c.name("body.name", &b.name)?;
        }
        if let Some(m) = &self.model {
            c.within("model".into(), |c| m.validate(c))?;
        }
        c.range("residual_px", self.residual_px, 0.0, f64::MAX)
    }
}

impl BodyPose {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("name", &self.name)?;
        c.finite("position_m", &self.position_m)?;
        c.finite("velocity_m_per_s", &self.velocity_m_per_s)?;
        c.finite(
            "angular_velocity_rad_per_s",
            &self.angular_velocity_rad_per_s,
        )?;
        c.finite("orientation_xyzw", &self.orientation_xyzw)?;
        let norm = self
            .orientation_xyzw
            .iter()
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt();
        c.range("orientation_xyzw", norm, 0.999, 1.001)?;
        c.range("residual_mm", self.residual_mm, 0.0, f64::MAX)?;
        c.range("markers", self.markers as f64, 2.0, MAX_BODY_MARKERS as f64)?;
        c.range(
            "markers_seen",
            self.markers_seen as f64,
            0.0,
            self.markers as f64,
        )
    }
}

/// The most markers a body may have (`stereoscope-bodies`' `MAX_MARKERS`, repeated here so the
/// protocol crate stays free of algorithm crates; a test in that crate checks they agree).
pub const MAX_BODY_MARKERS: u32 = 8;

impl BlobObservation {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.range("area_px", self.area_px, 0.0, f64::MAX)?;
        c.finite(
            "moments",
            &[
                self.x_px,
                self.y_px,
                self.mu20,
                self.mu02,
                self.mu11,
                self.orientation_deg,
                self.roundness,
                self.heading_deg,
            ],
        )
    }
}

impl Observation {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.name("camera", &self.camera)?;
        let side = limits::MAX_IMAGE_SIDE_PX as f64;
        c.range("width_px", self.width_px as f64, 1.0, side)?;
        c.range("height_px", self.height_px as f64, 1.0, side)?;
        c.count("blobs", self.blobs.len(), limits::MAX_BLOBS)?;
        for (i, b) in self.blobs.iter().enumerate() {
            c.within(format!("blobs[{i}]"), |c| b.validate(c))?;
        }
        // A worker numbers its tracks uniquely; fusion follows a blob from frame to frame
        // by its number, so two blobs with one number would be followed as one.
        c.unique(
            "blobs",
            "track_id",
            self.blobs.iter().map(|b| u64::from(b.track_id)),
        )?;
        Ok(())
    }
}

impl PoseFrame {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.names("cameras", &self.cameras)?;
        c.count("poses", self.poses.len(), limits::MAX_POSES)?;
        for (i, p) in self.poses.iter().enumerate() {
            c.within(format!("poses[{i}]"), |c| p.validate(c))?;
        }
        c.unique(
            "poses",
            "object_id",
            self.poses.iter().map(|p| u64::from(p.object_id)),
        )?;
        c.count("bodies", self.bodies.len(), limits::MAX_BODIES)?;
        for (i, b) in self.bodies.iter().enumerate() {
            c.within(format!("bodies[{i}]"), |c| b.validate(c))?;
        }
        c.count("models", self.models.len(), limits::MAX_MODELS)?;
        for (i, m) in self.models.iter().enumerate() {
            c.within(format!("models[{i}]"), |c| m.validate(c))?;
        }
        Ok(())
    }
}

impl BodyUpdate {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.within("body".into(), |c| self.body.validate(c))
    }
}

impl PoseUpdate {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.within("pose".into(), |c| self.pose.validate(c))
    }
}

impl Truth {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("camera", &self.camera)?;
        c.count("targets", self.targets.len(), limits::MAX_POSES)?;
        for (i, t) in self.targets.iter().enumerate() {
            c.within(format!("targets[{i}]"), |c| {
                c.finite("position_m", &t.position_m)?;
                c.finite("heading_deg", &[t.heading_deg, t.area_px])?;
                c.finite("centroid_px", &t.centroid_px)?;
                if let Some(b) = &t.body {
                    c.name("body", b)?;
                }
                c.finite("orientation_xyzw", &t.orientation_xyzw.unwrap_or_default())
            })?;
        }
        Ok(())
    }
}

impl Health {
    fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.name("host", &self.host)?;
        c.name("service", &self.service)?;
        c.range("rate_hz", self.rate_hz, 0.0, f64::MAX)?;
        if let Some(e) = &self.last_error {
            c.text("last_error", e, limits::MAX_TEXT_BYTES)?;
        }
        c.count("detail", self.detail.len(), limits::MAX_DETAIL_ENTRIES)?;
        for (k, v) in &self.detail {
            c.name("detail", k)?;
            c.text(&format!("detail.{k}"), v, limits::MAX_TEXT_BYTES)?;
        }
        Ok(())
    }
}

/// A message with a schema number, encodable both ways. Decoding checks the size first, then
/// the schema, then every field against [`limits`]: a message that decodes can be trusted to be
/// in bounds.
pub trait Message: Serialize + for<'de> Deserialize<'de> {
    fn schema(&self) -> u32;

    /// The rig the message is of (`None` for a message that names none: a camera's truth,
    /// which travels on its rig's keys only).
    fn rig(&self) -> Option<&str>;

    /// The field checks of this message type.
    fn fields_valid(&self) -> Result<(), DecodeError>;

    fn to_json(&self) -> Vec<u8> {
        // Serialising these plain structs cannot fail (no maps with non-string keys).
        serde_json::to_vec(self).unwrap_or_default()
    }

    fn from_json(bytes: &[u8]) -> Result<Self, DecodeError> {
        if bytes.len() > limits::MAX_MESSAGE_BYTES {
            return Err(DecodeError::TooLarge { bytes: bytes.len() });
        }
        let m: Self = serde_json::from_slice(bytes).map_err(DecodeError::Json)?;
        m.check()
    }

    fn to_binary(&self) -> Vec<u8> {
        postcard::to_allocvec(self).unwrap_or_default()
    }

    fn from_binary(bytes: &[u8]) -> Result<Self, DecodeError> {
        if bytes.len() > limits::MAX_MESSAGE_BYTES {
            return Err(DecodeError::TooLarge { bytes: bytes.len() });
        }
        let m: Self = postcard::from_bytes(bytes).map_err(DecodeError::Binary)?;
        m.check()
    }

    fn check(self) -> Result<Self, DecodeError> {
        if self.schema() != SCHEMA_VERSION {
            return Err(DecodeError::Schema {
                found: self.schema(),
            });
        }
        self.fields_valid()?;
        Ok(self)
    }
}

macro_rules! message {
    ($($t:ty),*; without rig: $($u:ty),*) => {
        $(message!(@impl $t, self => Some(self.rig.as_str()));)*
        $(message!(@impl $u, self => None);)*
    };
    (@impl $t:ty, $self:ident => $rig:expr) => {
        impl Message for $t {
            fn schema(&self) -> u32 {
                self.schema
            }

            fn rig(&$self) -> Option<&str> {
                $rig
            }

            fn fields_valid(&self) -> Result<(), DecodeError> {
                self.validate(&mut Checker::new())
            }
        }
    };
}
message!(
    Observation,
    PoseFrame,
    PoseUpdate,
    BodyUpdate,
    ModelUpdate,
    Health,
    Preview,
    WandCoverage,
    TokenRenewal;
    without rig: Truth
);

/// Nanoseconds since the Unix epoch now (CLOCK_REALTIME).
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {

    #[test]
    fn health_says_what_was_lost_and_which_frame() {
        let mut h = Health {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            host: "pc".into(),
            service: "moments/cam0".into(),
            pid: 1,
            started_ns: 0,
            published_ns: 0,
            processed: 10,
            rate_hz: 1.0,
            dropped: 0,
            rejected: 0,
            last_error: None,
            detail: Default::default(),
        };
        assert!(h.losses().is_empty());
        h.dropped = 2;
        h.detail
            .insert("last_lost".into(), "cam0 frames 7–8".into());
        h.detail.insert("late".into(), "0".into());
        assert_eq!(
            h.losses(),
            vec!["moments/cam0: 2 dropped (the last: cam0 frames 7–8)".to_string()]
        );
        h.rejected = 1;
        h.last_error = Some("frame 9: header".into());
        h.detail.insert("late".into(), "3".into());
        h.detail.insert("short_sets".into(), "1".into());
        let l = h.losses();
        assert_eq!(l.len(), 4, "{l:?}");
        assert!(l[1].contains("1 rejected (last: frame 9: header)"), "{l:?}");
        assert!(l[2].contains("3 observations late"), "{l:?}");
        assert!(l[3].contains("1 recorded sets formed without"), "{l:?}");
    }
    use super::*;

    fn sample() -> PoseFrame {
        PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "lab".into(),
            sequence: 3,
            timestamp_ns: 10,
            frame_published_ns: 11,
            published_ns: 12,
            cameras: vec!["cam0".into(), "cam1".into()],
            poses: vec![Pose {
                object_id: 1,
                // Values whose shortest decimal form needs all 17 digits round-trip exactly.
                position_m: [0.1, -0.2, 0.0009008192496449652],
                velocity_m_per_s: [0.0; 3],
                heading_deg: Some(45.0),
                heading_directed: false,
                method: PoseMethod::Triangulated,
                cameras: vec!["cam0".into(), "cam1".into()],
                residual_px: 0.2,
                out_of_range: false,
                body: Some(BodyLabel {
                    name: "head".into(),
                    marker: 2,
                }),
                model: Some(ModelLabel {
                    name: "arm".into(),
                    link: "forearm".into(),
                    marker: "forearm_1".into(),
                }),
            }],
            bodies: vec![BodyPose {
                name: "head".into(),
                position_m: [0.1, 0.2, 0.3],
                orientation_xyzw: [0.0, 0.0, 0.6, 0.8],
                velocity_m_per_s: [0.0; 3],
                angular_velocity_rad_per_s: [0.0, 0.0, 1.5],
                residual_mm: 0.4,
                markers_seen: 3,
                markers: 4,
                held: false,
                roll_unobservable: false,
            }],
            models: Vec::new(),
        }
    }

    #[test]
    fn both_encodings_round_trip() {
        let mut loose = sample();
        loose.poses[0].body = None;
        loose.bodies.clear();
        assert_eq!(PoseFrame::from_binary(&loose.to_binary()).unwrap(), loose);
        let p = sample();
        assert_eq!(PoseFrame::from_json(&p.to_json()).unwrap(), p);
        assert_eq!(PoseFrame::from_binary(&p.to_binary()).unwrap(), p);
        let text = String::from_utf8(p.to_json()).unwrap();
        assert!(text.contains("\"method\":\"triangulated\""), "{text}");
    }

    /// An observation of four blobs numbered 1–4 as a worker reports them.
    fn sample_observation() -> Observation {
        let blob = BlobObservation {
            track_id: 3,
            status: TrackState::Tracked,
            area_px: 41.0,
            x_px: 171.4231,
            y_px: 118.0712,
            mu20: 190.25,
            mu02: 71.93,
            mu11: -30.51,
            orientation_deg: 14.61,
            roundness: 0.61,
            heading_deg: 194.6,
            directed: false,
            heading_ambiguous: false,
            clipped: false,
            merged: false,
            window_px: [141, 88, 201, 148],
            bbox_px: [165, 114, 178, 122],
        };
        Observation {
            schema: SCHEMA_VERSION,
            rig: "demo".into(),
            camera: "cam0".into(),
            sequence: 1812,
            timestamp_ns: 1_764_601_234_533_333_333,
            frame_published_ns: 1_764_601_234_536_912_000,
            published_ns: 1_764_601_234_537_001_000,
            width_px: 320,
            height_px: 240,
            threshold: 98,
            dark: false,
            full_frame: false,
            dropped_blobs: 0,
            blobs: numbered(&blob, 4),
        }
    }

    #[test]
    fn binary_form_is_compact() {
        let o = sample_observation();
        let (bin, json) = (o.to_binary(), o.to_json());
        println!(
            "observation with 4 blobs: {} bytes binary, {} bytes JSON",
            bin.len(),
            json.len()
        );
        assert!(bin.len() * 2 < json.len());
        assert_eq!(Observation::from_binary(&bin).unwrap(), o);

        // The largest messages the limits allow in use: an observation of MAX_BLOBS blobs and
        // a pose frame of MAX_POSES poses each seen by 16 cameras fit a shared-memory sample
        // in binary and the decoder's bound in JSON, and both come back.
        let full = Observation {
            blobs: numbered(&o.blobs[0], limits::MAX_BLOBS),
            ..o.clone()
        };
        let (bin, json) = (full.to_binary(), full.to_json());
        println!(
            "observation with {} blobs: {} bytes binary, {} bytes JSON",
            limits::MAX_BLOBS,
            bin.len(),
            json.len()
        );
        assert!(bin.len() <= crate::names::iox::MESSAGE_MAX_BYTES);
        assert!(json.len() <= limits::MAX_MESSAGE_BYTES);
        assert_eq!(Observation::from_binary(&bin).unwrap(), full);
        assert_eq!(Observation::from_json(&json).unwrap(), full);
        let sixteen: Vec<String> = (0..16).map(|c| format!("cam{c}")).collect();
        let mut frame = sample();
        frame.cameras = sixteen.clone();
        frame.poses = (0..limits::MAX_POSES)
            .map(|i| Pose {
                object_id: i as u32 + 1,
                position_m: [0.123456789, -1.23456789, 2.3456789 + i as f64 * 1e-3],
                velocity_m_per_s: [0.31234, -0.0451, 1.2e-3],
                cameras: sixteen.clone(),
                ..frame.poses[0].clone()
            })
            .collect();
        let (bin, json) = (frame.to_binary(), frame.to_json());
        println!(
            "pose frame of {} poses by 16 cameras: {} bytes binary, {} bytes JSON",
            limits::MAX_POSES,
            bin.len(),
            json.len()
        );
        assert!(bin.len() <= crate::names::iox::MESSAGE_MAX_BYTES);
        assert!(json.len() <= limits::MAX_MESSAGE_BYTES);
        assert_eq!(PoseFrame::from_binary(&bin).unwrap(), frame);
        assert_eq!(PoseFrame::from_json(&json).unwrap(), frame);
        let over = Observation {
            blobs: numbered(&o.blobs[0], limits::MAX_BLOBS + 1),
            ..o.clone()
        };
        assert!(matches!(
            Observation::from_binary(&over.to_binary()),
            Err(DecodeError::Invalid { ref field, .. }) if field == "blobs"
        ));
    }

    /// `n` copies of `blob` numbered 1, 2, … as a worker numbers its tracks.
    fn numbered(blob: &BlobObservation, n: usize) -> Vec<BlobObservation> {
        (0..n)
            .map(|i| BlobObservation {
                track_id: i as u32 + 1,
                ..blob.clone()
            })
            .collect()
    }

    #[test]
    fn a_repeated_track_or_object_number_is_refused_by_entry() {
        let mut o = sample_observation();
        o.blobs = numbered(&o.blobs[0], 5);
        o.blobs[3].track_id = 2;
        let e = Observation::from_json(&o.to_json()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "blobs[3].track_id repeats 2, first at entry 1",
            "{e:?}"
        );
        let mut p = sample();
        p.poses.push(p.poses[0].clone());
        let e = PoseFrame::from_binary(&p.to_binary()).unwrap_err();
        assert!(
            matches!(e, DecodeError::Invalid { ref field, .. } if field == "poses[1].object_id"),
            "{e}"
        );
    }

    #[test]
    fn bad_payloads_are_errors_not_panics() {
        let p = sample();
        let json = p.to_json();
        assert!(PoseFrame::from_json(&json[..json.len() / 2]).is_err());
        assert!(PoseFrame::from_json(b"\xff\x00garbage").is_err());
        let bin = p.to_binary();
        assert!(PoseFrame::from_binary(&bin[..bin.len() / 2]).is_err());
        let mut other = p.clone();
        other.schema = 2;
        let e = PoseFrame::from_json(&other.to_json()).unwrap_err();
        assert!(e.to_string().contains("schema 2"), "{e}");
        let unknown = String::from_utf8(json)
            .unwrap()
            .replacen("\"rig\"", "\"rigg\"", 1);
        assert!(PoseFrame::from_json(unknown.as_bytes()).is_err());
    }

    /// What decodes but is out of bounds is refused with the field's path and the reason;
    /// what is too large is refused before it is parsed.
    #[test]
    fn fields_out_of_bounds_are_refused_by_path() {
        let invalid = |r: Result<PoseFrame, DecodeError>| match r {
            Err(DecodeError::Invalid { field, problem }) => (field, problem),
            other => panic!("{other:?}"),
        };
        // A NaN only travels in the binary form (JSON has none).
        let mut p = sample();
        p.poses[0].position_m[1] = f64::NAN;
        let (field, problem) = invalid(PoseFrame::from_binary(&p.to_binary()));
        assert_eq!(
            (field.as_str(), problem),
            ("poses[0].position_m", Invalid::NotFinite)
        );
        let mut p = sample();
        p.poses[0].residual_px = -1.0;
        let (field, _) = invalid(PoseFrame::from_binary(&p.to_binary()));
        assert_eq!(field, "poses[0].residual_px");
        let mut p = sample();
        p.rig = "r".repeat(65);
        let (field, problem) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(
            (field.as_str(), problem),
            ("rig", Invalid::TooLong { bytes: 65, max: 64 })
        );
        let mut p = sample();
        p.poses = vec![p.poses[0].clone(); limits::MAX_POSES + 1];
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "poses");
        let mut p = sample();
        p.poses[0].cameras[1] = String::new();
        let (field, problem) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(
            (field.as_str(), problem),
            ("poses[0].cameras[1]", Invalid::Empty)
        );
        // A body's rotation must be a unit quaternion, its markers seen at most its markers.
        let mut p = sample();
        p.bodies[0].orientation_xyzw = [0.0, 0.0, 0.0, 2.0];
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "bodies[0].orientation_xyzw");
        let mut p = sample();
        p.bodies[0].markers_seen = 5;
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "bodies[0].markers_seen");
        // A model: its links' rotations unit quaternions, a joint at most four values, its
        // markers seen at most its markers; a good one round-trips.
        let model = ModelPose {
            name: "arm".into(),
            valid: true,
            rms_mm: 0.3,
            markers_seen: 20,
            markers: 28,
            joints: vec![JointState {
                name: "elbow".into(),
                values: vec![1.25],
                determined: true,
                at_limit: false,
                residual_mm: Some(0.2),
            }],
            links: vec![LinkPose {
                name: "base".into(),
                position_m: [0.1, 0.2, 0.0],
                orientation_xyzw: [0.0, 0.0, 0.6, 0.8],
            }],
        };
        let mut p = sample();
        p.models = vec![model.clone()];
        assert_eq!(PoseFrame::from_json(&p.to_json()).unwrap(), p);
        p.models[0].links[0].orientation_xyzw = [0.0, 0.0, 0.0, 2.0];
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "models[0].links[0].orientation_xyzw");
        let mut p = sample();
        p.models = vec![model.clone()];
        p.models[0].joints[0].values = vec![0.0; 5];
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "models[0].joints[0].values");
        p.models[0].joints[0].values = vec![f64::NAN];
        assert!(PoseFrame::from_json(&p.to_json()).is_err());
        let mut p = sample();
        p.models = vec![model];
        p.models[0].markers_seen = 29;
        let (field, _) = invalid(PoseFrame::from_json(&p.to_json()));
        assert_eq!(field, "models[0].markers_seen");
        // A frame recorded before bodies existed still reads.
        let old = String::from_utf8(sample().to_json())
            .unwrap()
            .split(",\"bodies\"")
            .next()
            .unwrap()
            .to_string()
            + "}";
        assert!(
            PoseFrame::from_json(old.as_bytes())
                .unwrap()
                .bodies
                .is_empty()
        );
        let big = vec![b' '; limits::MAX_MESSAGE_BYTES + 1];
        assert!(matches!(
            PoseFrame::from_json(&big),
            Err(DecodeError::TooLarge { .. })
        ));
        let e = DecodeError::Invalid {
            field: "blobs[3].x_px".into(),
            problem: Invalid::NotFinite,
        };
        assert_eq!(e.to_string(), "blobs[3].x_px is not a finite number");
        assert_eq!(e.reason(), "invalid");
        // What a service sends is within bounds.
        assert_eq!(
            PoseFrame::from_binary(&sample().to_binary()).unwrap(),
            sample()
        );
    }

    /// Property test: 20 000 hostile variants of each message's JSON and binary form (cut,
    /// bit-flipped, with bytes inserted, removed or repeated, random) decode to an error or to
    /// a message within the limits — never a panic (docs/reliability.md).
    #[test]
    fn hostile_bytes_never_panic_a_decoder() {
        use stereoscope_numeric::random::mutations;
        fn each<M: Message + std::fmt::Debug>(valid: &M, seed: u64) -> usize {
            let mut ok = 0;
            for form in [valid.to_json(), valid.to_binary()] {
                for bytes in mutations(&form, 2_000, seed) {
                    let json = M::from_json(&bytes);
                    let binary = M::from_binary(&bytes);
                    for m in [json, binary].into_iter().flatten() {
                        // What decodes passed every check.
                        assert!(m.fields_valid().is_ok(), "{m:?}");
                        ok += 1;
                    }
                }
            }
            ok
        }
        let frame = sample();
        let update = PoseUpdate {
            schema: SCHEMA_VERSION,
            rig: "lab".into(),
            sequence: 1,
            timestamp_ns: 2,
            frame_published_ns: 3,
            published_ns: 4,
            pose: frame.poses[0].clone(),
        };
        let truth = Truth {
            schema: SCHEMA_VERSION,
            camera: "cam0".into(),
            sequence: 1,
            timestamp_ns: 2,
            targets: vec![TargetTruth {
                target: 0,
                position_m: [0.1, 0.2, 0.3],
                heading_deg: 10.0,
                has_axis: true,
                symmetric: false,
                visible: true,
                area_px: 40.0,
                centroid_px: [10.0, 20.0],
                body: None,
                orientation_xyzw: None,
            }],
        };
        let body = BodyUpdate {
            schema: SCHEMA_VERSION,
            rig: "lab".into(),
            sequence: 1,
            timestamp_ns: 2,
            frame_published_ns: 3,
            published_ns: 4,
            body: frame.bodies[0].clone(),
        };
        let mut decoded = 0;
        for seed in 0..5 {
            decoded += each(&frame, seed);
            decoded += each(&update, seed);
            decoded += each(&body, seed);
            decoded += each(&truth, seed);
        }
        // The variants reach past the first byte: some still decode.
        assert!(decoded > 0);
    }
}
