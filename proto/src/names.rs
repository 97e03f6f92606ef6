//! Every name a service is reached by, in one place (`docs/protocol.md`, "Names"): iceoryx2
//! service names with their sizes (the QoS every side must agree on), and Zenoh key
//! expressions.

/// iceoryx2 services on one PC. Each pub/sub service has an event service of the same name
/// that the publisher notifies after each sample, so readers sleep until data arrives.
/// The environment variable the launcher names its session with (its start time in
/// nanoseconds since the Unix epoch), for the services it starts: fusion keeps its pose
/// sequence and object ids unique within a session across restarts.
pub const SESSION_ENV: &str = "STEREOSCOPE_SESSION";

pub mod iox {
    /// Frames of one camera: `[u8]` payload with a `FrameHeader` user header.
    pub fn frames(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/frames/{camera}")
    }

    /// Observations of one camera (postcard `Observation`).
    pub fn observations(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/observations/{camera}")
    }

    /// One event service every moment worker of a rig notifies, so fusion waits on one thing.
    pub fn observations_ready(rig: &str) -> String {
        format!("stereoscope/{rig}/observations-ready")
    }

    /// Pose frames of a rig (postcard `PoseFrame`).
    pub fn poses(rig: &str) -> String {
        format!("stereoscope/{rig}/poses")
    }

    /// Ground truth of a synthetic camera (postcard `Truth`).
    pub fn truth(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/truth/{camera}")
    }

    /// Frames a subscriber may queue before the oldest is overwritten: a slow reader loses old
    /// frames, the camera never waits.
    pub const FRAME_BUFFER: usize = 2;
    /// Frames the publisher keeps for a subscriber that connects late.
    pub const FRAME_HISTORY: usize = 0;
    /// Frames a reader may hold at once.
    pub const FRAME_BORROWED: usize = 2;
    /// Observation and pose samples a subscriber may queue.
    pub const MESSAGE_BUFFER: usize = 16;
    /// Largest message sample, bytes: an observation of 512 blobs is about 50 KB, a pose frame
    /// of 1024 poses seen by 16 cameras about 200 KB (both measured by a unit test).
    pub const MESSAGE_MAX_BYTES: usize = 512 * 1024;
    /// What a message publisher's samples hold at first, bytes; they grow by powers of two
    /// up to [`MESSAGE_MAX_BYTES`] when a message needs it (most never do).
    pub const MESSAGE_INITIAL_BYTES: usize = 16 * 1024;
    /// Subscribers, publishers and nodes a service admits.
    pub const MAX_SUBSCRIBERS: usize = 8;
    pub const MAX_PUBLISHERS: usize = 4;
    pub const MAX_NODES: usize = 16;
    /// Notifiers and listeners of an event service.
    pub const MAX_NOTIFIERS: usize = 32;
    pub const MAX_LISTENERS: usize = 8;
}

/// Zenoh key expressions (the network interface of the system).
pub mod zenoh {
    /// Every camera's observations: `stereoscope/<rig>/observations/<camera>`.
    pub fn observations(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/observations/{camera}")
    }

    pub fn all_observations(rig: &str) -> String {
        format!("stereoscope/{rig}/observations/*")
    }

    /// All poses of one frame set.
    pub fn poses(rig: &str) -> String {
        format!("stereoscope/{rig}/poses")
    }

    /// One object's pose (a `Pose` with the frame's times; see docs/protocol.md).
    pub fn pose(rig: &str, object_id: u32) -> String {
        format!("stereoscope/{rig}/pose/{object_id}")
    }

    pub fn all_poses(rig: &str) -> String {
        format!("stereoscope/{rig}/pose/*")
    }

    /// One rigid body's pose (a `BodyUpdate`): `stereoscope/<rig>/bodies/<name>`.
    pub fn body(rig: &str, name: &str) -> String {
        format!("stereoscope/{rig}/bodies/{name}")
    }

    pub fn all_bodies(rig: &str) -> String {
        format!("stereoscope/{rig}/bodies/*")
    }

    /// One kinematic model's joints and links (a `ModelUpdate`): `stereoscope/<rig>/models/<name>`.
    pub fn model(rig: &str, name: &str) -> String {
        format!("stereoscope/{rig}/models/{name}")
    }

    pub fn all_models(rig: &str) -> String {
        format!("stereoscope/{rig}/models/*")
    }

    pub fn truth(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/truth/{camera}")
    }

    /// A camera's preview for people (binary `Preview`, a few a second, only while someone
    /// subscribes): `stereoscope/<rig>/preview/<camera>`.
    pub fn preview(rig: &str, camera: &str) -> String {
        format!("stereoscope/{rig}/preview/{camera}")
    }

    pub fn all_previews(rig: &str) -> String {
        format!("stereoscope/{rig}/preview/*")
    }

    /// A live wand calibration's coverage of each camera's image (`WandCoverage`, twice a
    /// second while it collects).
    pub fn wand_coverage(rig: &str) -> String {
        format!("stereoscope/{rig}/calibration/coverage")
    }

    /// A service's health reports.
    pub fn health(rig: &str, host: &str, service: &str) -> String {
        format!("stereoscope/{rig}/health/{host}/{service}")
    }

    pub fn all_health(rig: &str) -> String {
        format!("stereoscope/{rig}/health/**")
    }

    /// Liveliness token of a running service.
    pub fn alive(rig: &str, host: &str, service: &str) -> String {
        format!("stereoscope/{rig}/alive/{host}/{service}")
    }

    pub fn all_alive(rig: &str) -> String {
        format!("stereoscope/{rig}/alive/**")
    }

    /// Requests that a service declare its liveliness token again (`TokenRenewal`).
    pub fn renew(rig: &str, host: &str, service: &str) -> String {
        format!("stereoscope/{rig}/renew/{host}/{service}")
    }

    pub fn all_renew(rig: &str) -> String {
        format!("stereoscope/{rig}/renew/**")
    }
}

/// Whether `name` may be used as a rig, host or camera name: it becomes a path segment of
/// iceoryx2 services and Zenoh keys, so only `[A-Za-z0-9_-]`, 1–32 characters.
pub fn valid_segment(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 32
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments() {
        assert!(valid_segment("cam0"));
        assert!(valid_segment("thesis-lab"));
        assert!(!valid_segment(""));
        assert!(!valid_segment("a/b"));
        assert!(!valid_segment("a*"));
        assert!(!valid_segment(&"a".repeat(33)));
        assert_eq!(zenoh::pose("lab", 3), "stereoscope/lab/pose/3");
    }
}
