//! The demo's summary (`stereoscope demo`'s last line and `--json`): each target's, body's
//! and model's errors against the synthetic scene's truth, the rates and latencies, the
//! ghosts, the VR feed's servers.

use crate::ModelStats;

/// Error statistics of one target.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TargetStats {
    pub target: u32,
    pub matched: u64,
    pub missed: u64,
    pub position_rms_m: f64,
    pub heading_rms_deg: Option<f64>,
    pub id_switches: u32,
}

/// Error statistics of one rigid body.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BodyStats {
    pub name: String,
    /// Frames with the body measured (not held) while its truth was visible.
    pub matched: u64,
    /// Frames with its truth visible and the body absent or held.
    pub missed: u64,
    pub position_rms_m: f64,
    pub rotation_rms_deg: f64,
}

/// What the demo measured.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DemoSummary {
    pub seconds: f64,
    pub pose_frames: u64,
    pub poses_per_s: f64,
    /// Frame published into shared memory → poses published, milliseconds.
    pub latency_p50_ms: f64,
    pub latency_p99_ms: f64,
    /// Exposure (scene instant) → poses published, milliseconds (includes rendering).
    pub exposure_latency_p50_ms: f64,
    pub position_rms_m: f64,
    pub heading_rms_deg: Option<f64>,
    /// Pose frames with every visible target matched within 5 cm.
    pub complete_frames: u64,
    /// Poses that were no target (more than 5 cm from every loose target and body marker, or
    /// a body's marker that far from its true place: `stereoscope_rig::truth`): ghosts that
    /// reached the outputs.
    pub ghost_poses: u64,
    /// The first ghosts (at most [`GHOST_EXAMPLES`]): where they were, how they were measured.
    pub ghosts: Vec<GhostExample>,
    pub targets: Vec<TargetStats>,
    pub bodies: Vec<BodyStats>,
    /// Kinematic models scored against the scene's joint truth (`docs/models.md`).
    pub models: Vec<ModelStats>,
    /// The VR feed's frame published → sent to its clients, from its last health report,
    /// microseconds (`None` without a VR feed).
    pub vr_latency_p50_us: Option<f64>,
    pub vr_latency_p99_us: Option<f64>,
    /// The feed's servers (VRPN, NatNet, Qualisys RT) by their state in its last health report
    /// (`listening`, `port in use`), with the reason when one is not listening.
    pub servers: Vec<ServerState>,
    pub restarts: u32,
    /// What the services' last health reports say they lost (frames dropped and which,
    /// inputs rejected, observations late): where a missed target can be traced to.
    pub losses: Vec<String>,
}

impl DemoSummary {
    pub fn to_json(&self) -> String {
        let targets: Vec<String> = self
            .targets
            .iter()
            .map(|t| {
                format!(
                    "{{\"target\":{},\"matched\":{},\"missed\":{},\"position_rms_m\":{},\"heading_rms_deg\":{},\"id_switches\":{}}}",
                    t.target,
                    t.matched,
                    t.missed,
                    json_number(t.position_rms_m, 6),
                    t.heading_rms_deg.map(|h| format!("{h:.4}")).unwrap_or("null".into()),
                    t.id_switches
                )
            })
            .collect();
        let bodies: Vec<String> = self
            .bodies
            .iter()
            .map(|b| {
                format!(
                    "{{\"name\":{},\"matched\":{},\"missed\":{},\"position_rms_m\":{},\"rotation_rms_deg\":{}}}",
                    serde_json::to_string(&b.name).unwrap_or_default(),
                    b.matched,
                    b.missed,
                    json_number(b.position_rms_m, 6),
                    json_number(b.rotation_rms_deg, 4)
                )
            })
            .collect();
        let models: Vec<String> = self
            .models
            .iter()
            .map(|m| {
                let joints: Vec<String> = m
                    .joints_rms
                    .iter()
                    .map(|(n, r)| {
                        format!(
                            "{{\"name\":{},\"rms\":{}}}",
                            serde_json::to_string(n).unwrap_or_default(),
                            r.map_or("null".to_string(), |r| json_number(r, 4))
                        )
                    })
                    .collect();
                format!(
                    "{{\"name\":{},\"frames\":{},\"valid\":{},\"whole\":{},\"joints\":[{}],\"tool_rms_m\":{},\"hidden\":{},\"ids_passed\":{},\"ids_per_marker\":{}}}",
                    serde_json::to_string(&m.name).unwrap_or_default(),
                    m.frames,
                    m.valid,
                    m.whole,
                    joints.join(","),
                    json_number(m.tool_rms_m, 6),
                    m.hidden.as_ref().map_or("null".to_string(), |h| h.json()),
                    m.ids_passed,
                    json_number(m.ids_per_marker, 2)
                )
            })
            .collect();
        let opt = |v: Option<f64>| v.map_or("null".to_string(), |v| json_number(v, 1));
        format!(
            "{{\"seconds\":{:.3},\"pose_frames\":{},\"poses_per_s\":{:.2},\"latency_p50_ms\":{},\"latency_p99_ms\":{},\"exposure_latency_p50_ms\":{},\"position_rms_m\":{},\"heading_rms_deg\":{},\"complete_frames\":{},\"ghost_poses\":{},\"ghosts\":{},\"restarts\":{},\"targets\":[{}],\"bodies\":[{}],\"models\":[{}],\"vr_latency_p50_us\":{},\"vr_latency_p99_us\":{},\"servers\":{},\"losses\":{}}}",
            self.seconds,
            self.pose_frames,
            self.poses_per_s,
            json_number(self.latency_p50_ms, 4),
            json_number(self.latency_p99_ms, 4),
            json_number(self.exposure_latency_p50_ms, 4),
            json_number(self.position_rms_m, 6),
            self.heading_rms_deg
                .map(|h| format!("{h:.4}"))
                .unwrap_or("null".into()),
            self.complete_frames,
            self.ghost_poses,
            serde_json::to_string(&self.ghosts).unwrap_or_else(|_| "[]".into()),
            self.restarts,
            targets.join(","),
            bodies.join(","),
            models.join(","),
            opt(self.vr_latency_p50_us),
            opt(self.vr_latency_p99_us),
            serde_json::to_string(&self.servers).unwrap_or_else(|_| "[]".into()),
            serde_json::to_string(&self.losses).unwrap_or_else(|_| "[]".into())
        )
    }
}

/// One of the feed's servers as its health last told.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ServerState {
    pub protocol: String,
    pub state: String,
}

/// How many ghosts the summary describes.
pub const GHOST_EXAMPLES: usize = 20;

/// One ghost pose, for the summary.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GhostExample {
    pub timestamp_ns: u64,
    pub object_id: u32,
    pub position_m: [f64; 3],
    pub method: stereoscope_proto::messages::PoseMethod,
    pub cameras: Vec<String>,
    pub body: Option<stereoscope_proto::messages::BodyLabel>,
}

/// A number for the JSON summary: `null` when not finite (no frame scored).
pub(crate) fn json_number(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "null".into()
    }
}
