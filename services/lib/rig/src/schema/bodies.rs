//! The rig file's rigid bodies (`[[body]]`) and VR feed (`[vr]`) tables (`docs/bodies.md`,
//! `docs/vr.md`), read with the rest of the schema.

use super::Units;
use serde::{Deserialize, Serialize};

/// A rigid body: its markers in its own frame (file unit) and the tolerance of a measured
/// inter-marker distance (file unit, default 3 mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub name: String,
    pub markers: Vec<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    /// One Euro smoothing of the pose the VR feed sends (off when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smoothing: Option<SmoothingSpec>,
    /// Send the pose predicted this many milliseconds ahead (constant velocity; default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predict_ms: Option<f64>,
}

/// One Euro filter settings (`docs/bodies.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmoothingSpec {
    /// Cut-off at rest, Hz (default 1): lower is smoother.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_cutoff_hz: Option<f64>,
    /// Rise of the cut-off with speed, per (m/s or rad/s) (default 0.5): higher lags less.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
    /// Cut-off of the speed estimate, Hz (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub d_cutoff_hz: Option<f64>,
}

/// The VR feed: one `vrfeed` service on `host` reading the pose stream, serving each protocol
/// named here (`docs/vr.md`). Addresses default to loopback.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct VrSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vrpn: Option<VrpnSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vmt: Option<VmtSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vmc: Option<OscFeedSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub opentrack: Option<OpentrackSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub natnet: Option<NatNetSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub qualisys: Option<QualisysSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Spec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lsl: Option<LslSpec>,
}

/// A Lab Streaming Layer outlet (`docs/lab-protocols.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct LslSpec {
    /// liblsl to load (default: `liblsl.so.2`, then `liblsl.so`, on the library path).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub library: Option<String>,
    /// The stream's source id, kept across restarts (default `stereoscope/<rig name>`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_id: Option<String>,
    /// Default: the world frame in metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// ROS 2 topics through Zenoh as rmw_zenoh publishes them (`docs/lab-protocols.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Ros2Spec {
    /// The ROS user's Zenoh router, as a Zenoh endpoint (default "tcp/127.0.0.1:7447", where
    /// `ros2 run rmw_zenoh_cpp rmw_zenohd` listens).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub router: Option<String>,
    /// ROS domain id, 0–232 (default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain_id: Option<u32>,
    /// Topics are `<namespace>/<body>/pose` and `…/twist` (default "/stereoscope").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub namespace: Option<String>,
    /// The node's name in the ROS graph (default "stereoscope").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub node: Option<String>,
    /// `header.frame_id`, the parent of every body on /tf (default "world").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_id: Option<String>,
    /// Default: the world frame (z up, ROS's REP 103) in metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// A NatNet server, as OptiTrack Motive streams (`docs/lab-protocols.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct NatNetSpec {
    /// Address of the command port (default "127.0.0.1:1510").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    /// The data port frames go to (default 1511).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_port: Option<u16>,
    /// The multicast group (default "239.255.42.99"), or "unicast" to send each client its
    /// frames.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multicast: Option<String>,
    /// Default: Motive's y-up frame in metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// A Qualisys Track Manager real-time (RT protocol) server (`docs/lab-protocols.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct QualisysSpec {
    /// The base port's address (default "127.0.0.1:22222"); clients connect to the port after
    /// it (22223, little-endian).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<String>,
    /// Default: the world frame (z up) in millimetres, as QTM's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// A VRPN tracker server: each body a tracker named after it, sensor 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct VrpnSpec {
    /// Address to listen on, TCP and UDP (default "127.0.0.1:3883").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub listen: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// VirtualMotionTracker: `/VMT/Room/Driver` for each body, its tracker index by order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct VmtSpec {
    /// Where VMT listens (default "127.0.0.1:39570").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub send_to: Option<String>,
    /// Bodies to send, in tracker-index order (default: every body, in rig order).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bodies: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// An OSC feed (VMC: `/VMC/Ext/Tra/Pos`, default "127.0.0.1:39539").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OscFeedSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub send_to: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// opentrack's "UDP over network" input: one body (default the first).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct OpentrackSpec {
    /// Where opentrack listens (default "127.0.0.1:4242").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub send_to: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameSpec>,
}

/// The consumer's frame: each of its axes as a signed world axis (`"x"`, `"-z"` …), its
/// origin in world coordinates (file unit), and its length unit. Defaults per consumer are in
/// `docs/vr.md`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    /// The world axes the consumer's x, y and z are, e.g. `["x", "z", "-y"]` for a y-up world.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axes: Option<[String; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<Units>,
}
