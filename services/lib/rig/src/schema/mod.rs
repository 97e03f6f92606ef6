//! The rig file's schema: one TOML file describing a rig's cameras, PCs and services, read once
//! by [`crate::Rig::load`]. Unknown keys are rejected and every closed set of words is an enum,
//! so a misspelt value is named by serde with the words it accepts. The checks of values that
//! the types cannot express are in `check.rs`. Every key is documented in `docs/rig.md`, with
//! the thesis's lab as a worked example.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

mod bodies;
pub use bodies::*;
mod models;
pub use models::*;
mod synthetic;
pub use stereoscope_proto::serial::SerialMode;
pub use synthetic::*;

/// The length unit of every position, translation and depth in a rig file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Units {
    #[serde(rename = "m")]
    Metres,
    #[serde(rename = "cm")]
    Centimetres,
    #[serde(rename = "mm")]
    Millimetres,
}

impl Units {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Units::Metres => 1.0,
            Units::Centimetres => 0.01,
            Units::Millimetres => 0.001,
        }
    }

    /// The unit's symbol, as the file spells it.
    pub fn symbol(self) -> &'static str {
        match self {
            Units::Metres => "m",
            Units::Centimetres => "cm",
            Units::Millimetres => "mm",
        }
    }
}

impl std::fmt::Display for Units {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.symbol())
    }
}

/// A word that is not one of [`Units`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not a unit: use m, cm or mm")]
pub struct UnknownUnit(pub String);

impl std::str::FromStr for Units {
    type Err = UnknownUnit;
    fn from_str(s: &str) -> Result<Self, UnknownUnit> {
        match s {
            "m" => Ok(Units::Metres),
            "cm" => Ok(Units::Centimetres),
            "mm" => Ok(Units::Millimetres),
            o => Err(UnknownUnit(o.to_string())),
        }
    }
}

/// A V4L2 pixel format the capture service reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum V4lFormat {
    /// 8-bit grey.
    Grey,
    /// 16-bit grey.
    Y16,
    /// 4:2:2 colour, the luma read.
    Yuyv,
    /// Motion JPEG, decoded to grey.
    Mjpg,
}

/// A GenICam pixel format the capture service reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GenicamFormat {
    Mono8,
    /// 10 and 12 bits in 16-bit containers (unpacked), read as 16-bit grey.
    Mono10,
    Mono12,
    Mono16,
}

/// How a GenICam camera's timestamps become the rig's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GenicamClock {
    Mapped,
    Ptp,
}

/// A V4L2 control's value in a rig file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ControlValue {
    Bool(bool),
    Integer(i64),
    /// A menu item, by its name.
    Item(String),
}

impl std::fmt::Display for ControlValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ControlValue::Bool(b) => write!(f, "{b}"),
            ControlValue::Integer(i) => write!(f, "{i}"),
            ControlValue::Item(s) => write!(f, "{s:?}"),
        }
    }
}

impl V4lFormat {
    /// The four-character code.
    pub fn fourcc(self) -> &'static str {
        match self {
            V4lFormat::Grey => "GREY",
            V4lFormat::Y16 => "Y16",
            V4lFormat::Yuyv => "YUYV",
            V4lFormat::Mjpg => "MJPG",
        }
    }

    pub fn bits(self) -> u32 {
        if self == V4lFormat::Y16 { 16 } else { 8 }
    }
}

/// An automatic threshold method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThresholdMethodSpec {
    /// Halfway from the histogram's background knee to the targets.
    Auto,
    Otsu,
    Triangle,
}

/// How a blob's centroid is weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WeightingSpec {
    /// Every foreground pixel counts 1 (the thesis's binary moments).
    Binary,
    /// Each pixel by its grey level above the background.
    Intensity,
    /// Each pixel by its estimated coverage of the target (the default).
    #[default]
    Coverage,
}

/// How fusion receives a camera's observations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObservationRoute {
    /// iceoryx2 for cameras on fusion's host, Zenoh for the others.
    #[default]
    Auto,
    /// Every camera over the network.
    Zenoh,
}

/// Which targets a moment worker looks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Polarity {
    /// Brighter than the background: foreground is `pixel >= threshold`.
    #[default]
    Bright,
    /// Darker than the background: foreground is `pixel <= threshold`.
    Dark,
}

/// The form of a single-camera depth-from-area model (thesis Eq. 4.15–4.27).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AreaModelKind {
    /// `AREA = a / (D + b)²`.
    TwoParameter,
    /// `AREA = a / (D² + b·D + c)`.
    ThreeParameter,
}

/// A whole rig file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// A name for the rig (used in network keys later).
    pub name: String,
    /// The length unit of every position, translation and depth in the file: "m", "cm" or "mm".
    pub units: Units,
    #[serde(rename = "camera", default)]
    pub cameras: Vec<CameraSpec>,
    /// The PCs of the rig and how their services reach each other (`docs/deploy.md`).
    #[serde(rename = "host", default, skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<HostSpec>,
    /// The fusion service's settings and host.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<FusionSpec>,
    /// The scene synthetic cameras render.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub synthetic: Option<SyntheticSpec>,
    /// Serial-link outputs.
    #[serde(rename = "serial", default, skip_serializing_if = "Vec::is_empty")]
    pub serial: Vec<SerialSpec>,
    /// A recorder the launcher runs and supervises (`docs/recording.md`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recorder: Option<RecorderSpec>,
    /// Rigid bodies of markers (`docs/bodies.md`): checked for ambiguity when the rig loads.
    #[serde(rename = "body", default, skip_serializing_if = "Vec::is_empty")]
    pub bodies: Vec<BodySpec>,
    /// Kinematic models: robots and limbs as chains of links (`docs/models.md`), built and
    /// checked when the rig loads.
    #[serde(rename = "model", default, skip_serializing_if = "Vec::is_empty")]
    pub models: Vec<ModelSpec>,
    /// The VR feed (`docs/vr.md`): VRPN, VirtualMotionTracker/VMC over OSC, opentrack.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vr: Option<VrSpec>,
    /// The live view in a browser (`docs/viewer.md`), which the launcher runs and supervises.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viewer: Option<ViewerSpec>,
    /// Accept plain-TCP Zenoh links between PCs (unauthenticated, unencrypted). Without it a
    /// rig whose hosts listen or connect beyond loopback must use `tls/` endpoints.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub insecure: bool,
    /// Real-time scheduling of the services a frame and its pose pass through.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub realtime: Option<RealtimeSpec>,
}

/// The services on a frame's way to a pose and out — captures, moment workers, fusion, the VR
/// feed and serial outputs — run under `SCHED_FIFO` at `priority` on every host, so a frame's
/// wake-ups are not queued behind ordinary processes (`docs/deploy.md`, "Latency"). The
/// recorder, the viewer and the router keep the ordinary policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeSpec {
    /// `SCHED_FIFO` priority, 1–98 (99 is left to the kernel's own threads).
    pub priority: u32,
}

/// The viewer service: a web page with the 3D scene, the cameras' monitors and the services'
/// health, served from the binary.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewerSpec {
    /// The PC it runs on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// Address and port the page is served on (default `127.0.0.1:8750`: this PC only; give
    /// `0.0.0.0:8750` to show it to the network).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub listen: Option<String>,
    /// Most browsers connected at once (default 16); more are answered 503.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_clients: Option<u32>,
}

pub use crate::settings::DEFAULT_VIEWER_LISTEN;

/// A supervised recorder: each start (the first, and every restart after a crash) records a
/// new session folder inside `folder`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecorderSpec {
    /// The PC it runs on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// Where session folders go (relative to the rig file); made if missing.
    pub folder: String,
    /// Cameras on the recorder's PC whose raw frames to record as well.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub frames: Vec<String>,
    /// How often to write and sync, milliseconds (default 200).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flush_ms: Option<u64>,
}

/// A serial-link output (`docs/services.md`, "serial").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialSpec {
    /// The PC the port is on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// The device, e.g. "/dev/ttyUSB0".
    pub port: String,
    /// Line speed, 8N1 (default 9600, the thesis's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baud: Option<u32>,
    /// "legacy" (the thesis's packet, one object) or "framed" (default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<SerialMode>,
    /// Object ids to send; every object if absent (legacy: the lowest id).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub objects: Vec<u32>,
}

/// One PC of a rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HostSpec {
    pub name: String,
    /// Zenoh endpoints the launcher's router on this PC listens on (`tcp/192.168.1.10:7447`).
    #[serde(default)]
    pub zenoh_listen: Vec<String>,
    /// Zenoh endpoints of other PCs' routers this PC connects to.
    #[serde(default)]
    pub zenoh_connect: Vec<String>,
    /// Prefix of this PC's iceoryx2 files (two rigs on one PC need different prefixes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iceoryx2_prefix: Option<String>,
    /// This PC's certificate for its `tls/` endpoints (`docs/deploy.md`, "Security").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tls: Option<TlsSpec>,
    /// The loopback endpoint this PC's own services reach its router on (default: the first
    /// listen endpoint as seen from this PC when it is plain TCP, else `tcp/127.0.0.1:7446`;
    /// with `local_auth`, `tls/127.0.0.1:7446`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_listen: Option<String>,
    /// Loopback is not trusted: this PC's own services (and its tools: `status`, the viewer)
    /// reach its router over mutual TLS with the host's certificate and are held to what the
    /// host may publish, as the other PCs are (`docs/deploy.md`, "Security"). Needs `tls`,
    /// whose certificate must name 127.0.0.1. Off by default.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub local_auth: bool,
}

/// PEM files (paths relative to the rig file) of one PC's mutual-TLS identity: the rig's
/// certificate authority, this PC's certificate (its common name is the `[[host]]` name) and
/// its private key. `deploy/make-certs.sh` makes a test set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsSpec {
    pub ca: String,
    pub cert: String,
    pub key: String,
}

/// Where a camera's frames come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceSpec {
    /// The rig's `[synthetic]` scene rendered through this camera.
    Synthetic {
        fps: f64,
        /// Render this many frames once and repeat them (for benchmarks at rates the renderer
        /// cannot reach live); absent renders every frame.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        loop_frames: Option<u32>,
        /// 8 (default) or 16.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        bit_depth: Option<u32>,
    },
    /// A V4L2 camera (Linux).
    V4l {
        device: String,
        /// "GREY", "Y16", "YUYV" or "MJPG"; the first the camera offers if absent.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        format: Option<V4lFormat>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        fps: Option<f64>,
        /// Exposure time, 100 µs units (V4L2's `exposure_time_absolute`).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        exposure: Option<i64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        gain: Option<i64>,
        /// Any other of the camera's controls, by the name `v4l2-ctl --list-ctrls` shows
        /// (`white_balance_automatic = false`, `power_line_frequency = "Disabled"`): a number,
        /// a boolean, or a menu item's name. Set in name order after exposure and gain.
        #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
        controls: BTreeMap<String, ControlValue>,
        /// From the end of exposure to the driver's end-of-frame stamp, µs: the sensor's
        /// readout (a global shutter's whole readout, a rolling shutter's middle row's: half
        /// of it), which V4L2 does not report. Subtracted from end-of-frame stamps.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        readout_us: Option<f64>,
    },
    /// A GenICam camera (GigE Vision, USB3 Vision) through Aravis, loaded at run time.
    Genicam {
        /// Aravis's device id (`Vendor-Model-Serial`) or the camera's address.
        camera: String,
        /// "Mono8" (default), "Mono10", "Mono12" or "Mono16".
        #[serde(default, skip_serializing_if = "Option::is_none")]
        format: Option<GenicamFormat>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        fps: Option<f64>,
        /// ExposureTime, microseconds.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        exposure_us: Option<f64>,
        /// Gain, in the camera's unit (usually dB).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        gain: Option<f64>,
        /// "mapped" (default): the camera's clock moved onto the host's; "ptp": the camera's
        /// clock is already Unix time (PTP).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        timestamps: Option<GenicamClock>,
        /// "free" (every trigger off: the camera runs at `fps`), or a trigger source the camera
        /// lists (`"Line1"`: hardware sync; `"Software"`: the capture fires it at `fps`).
        /// Absent: the camera's own setting.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        trigger: Option<String>,
        /// The Aravis library (default `libaravis-0.8.so.0` on the library path).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        library: Option<String>,
    },
    /// A YUV4MPEG2 file or pipe (a FIFO that `ffmpeg … -f yuv4mpegpipe` writes).
    Y4m {
        path: String,
        /// Pace frames at the file's frame rate (default) or read as fast as the worker takes
        /// them.
        #[serde(default = "yes")]
        realtime: bool,
        /// Start again at the end (files only).
        #[serde(default)]
        repeat: bool,
        /// Replay recorded frames (their `Xts` times) at their recorded pace, every camera on
        /// one clock (what `stereoscope replay --frames` writes; `realtime` is then ignored).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        replay_clock: Option<ReplayClock>,
    },
    /// A sequence of PGM or PNG files, in name order.
    Images {
        /// A folder (every `.pgm`/`.png` in it) or one file.
        path: String,
        fps: f64,
        #[serde(default = "yes")]
        realtime: bool,
        #[serde(default)]
        repeat: bool,
    },
}

/// A frame recorded at `recorded_ns + d` is published at wall-clock time `wall_ns + d / speed`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayClock {
    pub recorded_ns: u64,
    pub wall_ns: u64,
    /// 1 = the recorded pace (default); 2 = twice as fast.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub speed: f64,
    /// Stamp each frame with the time it is published at instead of its recorded time, so
    /// fusion pairs the frames as it pairs live ones (a session with no recorded sets to
    /// follow; every camera on the one clock keeps them in step).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub restamp: bool,
}

fn one() -> f64 {
    1.0
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

fn yes() -> bool {
    true
}

/// A camera's moment worker.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct MomentsSpec {
    /// "bright" (default: targets brighter than the background) or "dark" (dark targets on a
    /// bright background, the thesis's black helmet rectangle).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polarity: Option<Polarity>,
    /// "auto" (default), "otsu", "triangle", or a grey level.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold: Option<ThresholdSpec>,
    /// Threshold each tracking window from its own histogram with this method.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_threshold: Option<ThresholdMethodSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_objects: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_area_px: Option<u64>,
    /// 4 or 8 (default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub connectivity: Option<u8>,
    /// "binary", "intensity" or "coverage" (default): how centroids are weighted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weighting: Option<WeightingSpec>,
    /// Grey level of a fully covered target pixel for "coverage" (default: the threshold's
    /// distance above the background, doubled).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub full_level: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search_every_frames: Option<u32>,
    /// The periodic search's test reads every this many rows (default: one in
    /// `height / 540`, at least 1), from a row that moves at each search.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search_row_step: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_half_width_px: Option<u32>,
    /// Read each object found in the last frame in its core (its last box moved by its
    /// motion, widened) first, and its whole window only when that does not settle the frame
    /// (default true; `docs/vision.md`, "Cores").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub core_scan: Option<bool>,
    /// Frames between fresh automatic thresholds (default 30).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold_every_frames: Option<u32>,
    /// Rectangles `[x0, y0, x1, y1]` (pixels, inclusive) where what is bright is not a marker
    /// — a lamp, a reflection: a blob whose centroid falls in one is ignored
    /// (`stereoscope calibrate mask` makes them, `docs/calibration.md`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub mask: Vec<[u32; 4]>,
}

/// A threshold: a method name or a grey level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(untagged)]
pub enum ThresholdSpec {
    Level(u32),
    Method(ThresholdMethodSpec),
}

impl<'de> Deserialize<'de> for ThresholdSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = ThresholdSpec;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("\"auto\", \"otsu\", \"triangle\" or a grey level")
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<ThresholdSpec, E> {
                u32::try_from(v)
                    .map(ThresholdSpec::Level)
                    .map_err(|_| E::custom(format!("{v} is not a grey level (0 to 65535)")))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<ThresholdSpec, E> {
                u32::try_from(v)
                    .map(ThresholdSpec::Level)
                    .map_err(|_| E::custom(format!("{v} is not a grey level (0 to 65535)")))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ThresholdSpec, E> {
                match v {
                    "auto" => Ok(ThresholdSpec::Method(ThresholdMethodSpec::Auto)),
                    "otsu" => Ok(ThresholdSpec::Method(ThresholdMethodSpec::Otsu)),
                    "triangle" => Ok(ThresholdSpec::Method(ThresholdMethodSpec::Triangle)),
                    o => Err(E::custom(format!(
                        "{o:?} is not auto, otsu, triangle or a grey level"
                    ))),
                }
            }
        }
        d.deserialize_any(V)
    }
}

/// Fusion's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct FusionSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// Frames of different cameras within this of each other form one set (default 5 ms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_skew_ms: Option<f64>,
    /// How long to wait for a live camera's frame before fusing without it (default 20 ms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_wait_ms: Option<f64>,
    /// A camera silent this long counts as gone until it is heard again (default 500 ms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_timeout_ms: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_epipolar_px: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_residual_px: Option<f64>,
    /// Largest distance from an object's prediction for a point to continue it, file unit
    /// (default 0.1 m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub association_gate: Option<f64>,
    /// An object unseen this long is dropped (default 2 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drop_after_s: Option<f64>,
    /// A new point becomes an object (an id, published) once it was continued in this many
    /// consecutive sets (default 3; 1 publishes at once).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub confirm_sets: Option<u32>,
    /// A point that continues no object starts one only when this many cameras see it
    /// (default 3 in a rig of six cameras or more, else 2; 2 up to the rig's cameras).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_views_to_start: Option<u32>,
    /// The capture volume: points triangulated outside `min`–`max` (world, file unit) are
    /// dropped and counted (none by default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<VolumeSpec>,
    /// A body not seen keeps its identity and last pose (flagged held) this long (default 250).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body_hold_ms: Option<f64>,
    /// "auto" (default: iceoryx2 for cameras on fusion's host, Zenoh for the others),
    /// "zenoh" (every camera over the network).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observations: Option<ObservationRoute>,
    /// An observation stamped further than this from fusion's clock, ahead (or behind, except
    /// in a replay) is refused and counted (default 1000 ms): keep the PCs' clocks within it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_window_ms: Option<f64>,
    /// A recording's `poses.jsonl`: form the sets it recorded, each with the cameras it had
    /// (`stereoscope replay --frames` sets it; relative to the rig file).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay_sets: Option<String>,
}

/// A box in the world, file unit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VolumeSpec {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// One camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Unique name of the camera.
    pub id: String,
    /// `[width, height]` in pixels.
    pub image_size: [u32; 2],
    /// Focal length in pixels along x (give `fx` and `fy`, or `focal_length_mm` and
    /// `pixel_pitch_um`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fy: Option<f64>,
    /// Lens focal length, millimetres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub focal_length_mm: Option<f64>,
    /// Pixel pitch `[width, height]`, micrometres (their ratio is the pixel aspect ratio).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_pitch_um: Option<[f64; 2]>,
    /// Principal point `[cx, cy]` in pixels; the image centre if absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub principal_point: Option<[f64; 2]>,
    /// Lens distortion; none if absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<DistortionSpec>,
    pub pose: PoseSpec,
    /// Single-camera depth from blob area, if calibrated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_from_area: Option<DepthFromAreaSpec>,
    /// The PC the camera is attached to (a `[[host]]` name); the only host if absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// Where its frames come from; needed to run the rig.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceSpec>,
    /// Its moment worker's settings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moments: Option<MomentsSpec>,
}

/// Brown–Conrady coefficients (OpenCV's k1 k2 p1 p2 k3); absent ones are zero.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistortionSpec {
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub k3: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
}

/// Where the camera is: either `position`, `look_at` and `up` (the thesis's construction,
/// §2.3.1), or `cam_from_world_rotation` and `cam_from_world_translation`. World coordinates
/// in the file's unit.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look_at: Option<[f64; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub up: Option<[f64; 3]>,
    /// Rows of the rotation taking world coordinates into camera coordinates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cam_from_world_rotation: Option<[[f64; 3]; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cam_from_world_translation: Option<[f64; 3]>,
}

/// `AREA = a / (D² + b·D + c)` ("three_parameter") or `AREA = a / (D + b)²`
/// ("two_parameter"), D the distance along the optical axis in the file's unit, AREA in pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthFromAreaSpec {
    pub model: AreaModelKind,
    pub a: f64,
    pub b: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub c: Option<f64>,
    /// The calibrated distance range `[near, far]`, file unit.
    pub range: [f64; 2],
}

impl RigFile {
    /// Parses a rig file's text, without the checks of [`crate::Rig`]. The error names the key
    /// and line of the problem.
    pub fn from_toml(text: &str) -> Result<Self, toml::de::Error> {
        toml::from_str(text)
    }

    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }
}

impl CameraSpec {
    /// One camera as TOML, a `[[camera]]` table whose nested values (`pose`, `distortion`, …)
    /// are inline tables: a user can append keys (`source = …`, `host = …`) below it and they
    /// stay in this camera's table. Lengths are in `units`, said in a comment above it.
    pub fn to_toml_table(&self, units: Units) -> Result<String, toml::ser::Error> {
        let table = toml::Table::try_from(self)?;
        let mut out = format!(
            "# lengths in {units}: paste into a rig file whose `units = \"{units}\"`\n[[camera]]\n"
        );
        // The id first, then the rest in the order the table keeps them.
        for (k, v) in table
            .iter()
            .filter(|(k, _)| *k == "id")
            .chain(table.iter().filter(|(k, _)| *k != "id"))
        {
            out.push_str(&format!("{k} = {v}\n"));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAB: &str = r#"
name = "lab"
units = "cm"

[[camera]]
id = "cam0"
image_size = [320, 240]
focal_length_mm = 12.5
pixel_pitch_um = [21.5, 25.0]
pose = { position = [0.0, 0.0, 277.5], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }

[[camera]]
id = "cam1"
image_size = [320, 240]
fx = 600.0
fy = 520.0
distortion = { k1 = -0.1 }
pose = { cam_from_world_rotation = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], cam_from_world_translation = [-20.0, 0.0, 280.0] }
depth_from_area = { model = "three_parameter", a = 1.0e6, b = 0.0, c = -4.0, range = [75.0, 275.0] }
"#;

    #[test]
    fn parses_and_round_trips() {
        let rig = RigFile::from_toml(LAB).unwrap();
        assert_eq!(rig.cameras.len(), 2);
        assert_eq!(rig.cameras[1].distortion.unwrap().k1, -0.1);
        let back = RigFile::from_toml(&rig.to_toml().unwrap()).unwrap();
        assert_eq!(back, rig);
        let one = rig.cameras[1].to_toml_table(Units::Centimetres).unwrap();
        assert!(one.contains("[[camera]]") && one.contains("in cm"), "{one}");
        // Nested values are inline: keys appended below stay in the camera's table.
        let appended = format!(
            "name = \"x\"\nunits = \"cm\"\n{one}host = \"pc1\"\n[[host]]\nname = \"pc1\"\n"
        );
        let back = RigFile::from_toml(&appended).unwrap();
        assert_eq!(back.cameras[0].host.as_deref(), Some("pc1"));
        assert_eq!(back.cameras[0].pose, rig.cameras[1].pose);
        assert_eq!(back.cameras[0].distortion, rig.cameras[1].distortion);
    }

    #[test]
    fn unknown_and_missing_keys_are_named() {
        let err = RigFile::from_toml(&LAB.replace("focal_length_mm", "focal_lenght_mm"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("focal_lenght_mm"), "{err}");
        let err = RigFile::from_toml(&LAB.replace("units = \"cm\"\n", ""))
            .unwrap_err()
            .to_string();
        assert!(err.contains("units"), "{err}");
        let err = RigFile::from_toml(&LAB.replace("image_size = [320, 240]\nfx", "fx"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("image_size"), "{err}");
    }

    /// Property test: 20 000 hostile variants of the demo rig (cut, bit-flipped, with bytes
    /// inserted, removed or repeated, random) load or are refused with a `RigError` — never a
    /// panic (docs/reliability.md).
    #[test]
    fn hostile_rig_files_never_panic_the_loader() {
        use stereoscope_numeric::random::mutations;
        let demo = include_str!("../../../../../deploy/rigs/demo.toml");
        let mut loaded = 0;
        for seed in 0..10 {
            for m in mutations(demo.as_bytes(), 2_000, seed) {
                if crate::Rig::from_toml(&String::from_utf8_lossy(&m)).is_ok() {
                    loaded += 1;
                }
            }
        }
        assert!(loaded > 0);
    }
}
