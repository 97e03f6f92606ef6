//! The serial-link output service: the pose stream (Zenoh `stereoscope/<rig>/poses`) to a
//! serial device, as the thesis's 10-byte packet (`send_serial_3Dx`, legacy mode: one object,
//! centimetres, no id or checksum) or the framed packet (object id, sequence, millimetres,
//! CRC-16, COBS); both codecs and their decoders are `stereoscope_proto::serial`
//! (`docs/protocol.md`, "Serial link packets").
//!
//! *Rate.* The line carries `baud / 10` bytes a second (8N1). The service keeps only the newest
//! pose frame; before each packet it takes the newest pose of the next object to send, and it
//! paces packets to the line's rate. So a line slower than the pose stream carries fresh poses
//! (each object at most once per pose frame), never a queue of stale ones; superseded poses are
//! counted as dropped.
//!
//! *Values* that do not fit a packet are clamped and counted, never wrapped.
//!
//! *Faults.* A port that cannot be opened, or fails while writing (a USB adapter pulled), is
//! reported in the log and in health and opened again every second; the service never exits for
//! it, and nothing else is affected.

pub mod cli;

use std::io::Write as _;
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Detail, PoseFrame};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_proto::serial::{SerialMode, SerialPose, encode_framed, encode_legacy};
use stereoscope_service::Context;
use stereoscope_transport::{Flow, Inlet, Service, ServiceNode, Shutdown, drive};

#[derive(Debug, Clone)]
pub struct SerialConfig {
    pub ctx: Context,
    /// The device (`/dev/ttyUSB0`).
    pub port: String,
    pub baud: u32,
    pub mode: SerialMode,
    /// Object ids to send, in this order; every object when empty (legacy mode: the first
    /// given, or the lowest id seen).
    pub objects: Vec<u32>,
    /// Stop after this many packets (tests).
    pub max_packets: Option<u64>,
}

#[derive(Debug, thiserror::Error)]
pub enum SerialServiceError {
    #[error("serial {port}: the baud rate must be above zero")]
    ZeroBaud { port: String },
    #[error("serial {port}")]
    Transport {
        port: String,
        #[source]
        source: stereoscope_transport::TransportError,
    },
}

/// Seconds the line needs for `bytes` at `baud` with 8N1 framing (10 bits a byte).
pub fn line_time(bytes: usize, baud: u32) -> Duration {
    Duration::from_secs_f64(bytes as f64 * 10.0 / baud.max(1) as f64)
}

/// The poses of a frame to send, in order: the selected objects present in it.
pub fn selected<'a>(
    frame: &'a PoseFrame,
    objects: &[u32],
    mode: SerialMode,
) -> Vec<&'a stereoscope_proto::messages::Pose> {
    let mut poses: Vec<_> = if objects.is_empty() {
        frame.poses.iter().collect()
    } else {
        objects
            .iter()
            .filter_map(|id| frame.poses.iter().find(|p| p.object_id == *id))
            .collect()
    };
    if objects.is_empty() {
        poses.sort_by_key(|p| p.object_id);
    }
    if mode == SerialMode::Legacy {
        poses.truncate(1);
    }
    poses
}

/// The objects of a frame in sending order, starting after `last_sent`: when the line cannot
/// carry every object of every frame, each still gets its turn.
pub fn round_robin(order: &[u32], last_sent: Option<u32>) -> Vec<u32> {
    let start = last_sent
        .and_then(|l| order.iter().position(|&id| id == l))
        .map(|i| i + 1)
        .unwrap_or(0);
    order[start.min(order.len())..]
        .iter()
        .chain(&order[..start.min(order.len())])
        .copied()
        .collect()
}

/// One packet's bytes and how many fields were clamped.
pub fn packet(
    pose: &stereoscope_proto::messages::Pose,
    mode: SerialMode,
    sequence: u16,
) -> (Vec<u8>, u32) {
    let sp = SerialPose {
        object_id: pose.object_id.min(u16::MAX as u32) as u16,
        position_m: pose.position_m,
        heading_deg: pose.heading_deg.unwrap_or(0.0),
    };
    match mode {
        SerialMode::Legacy => {
            let (b, c) = encode_legacy(&sp);
            (b.to_vec(), c.count())
        }
        SerialMode::Framed => {
            let (b, c) = encode_framed(&sp, sequence);
            (b, c.count())
        }
    }
}

/// Runs until shutdown (or `max_packets`); returns the packets written.
pub fn run(cfg: SerialConfig, shutdown: Shutdown) -> Result<u64, SerialServiceError> {
    drive(SerialService::setup(cfg)?, &shutdown)
}

/// A running serial output: the newest pose frame (from its Zenoh inlet), the port (opened again after a failure), and the line's pacing.
pub struct SerialService {
    cfg: SerialConfig,
    node: ServiceNode,
    /// Pose frames from fusion's key; only the newest counts.
    poses: Inlet<PoseFrame>,
    latest: Option<PoseFrame>,
    /// Pose frames taken so far (the newest's number).
    generation: u64,
    port: Option<Box<dyn serialport::SerialPort>>,
    next_open: Instant,
    line_free: Instant,
    sent_generation: u64,
    /// Objects of the newest frame still to send, the next last.
    pending: Vec<u32>,
    sequence: u16,
    last_sent: Option<u32>,
    clamped: u64,
    packets: u64,
}

impl std::fmt::Debug for SerialService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SerialService({}, {} packets)",
            self.cfg.port, self.packets
        )
    }
}

impl SerialService {
    /// Joins the rig and subscribes to its pose frames; the port is opened by the first step
    /// (and again after it fails), so a missing device is reported, never fatal.
    pub fn setup(cfg: SerialConfig) -> Result<Self, SerialServiceError> {
        let ctx = &cfg.ctx;
        let transport = |source| SerialServiceError::Transport {
            port: cfg.port.clone(),
            source,
        };
        if cfg.baud == 0 {
            return Err(SerialServiceError::ZeroBaud {
                port: cfg.port.clone(),
            });
        }
        let rig = ctx.rig.name.clone();
        let short = std::path::Path::new(&cfg.port)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "port".into());
        let service = format!(
            "serial/{}",
            short.replace(|c: char| !c.is_ascii_alphanumeric() && c != '-', "_")
        );
        // One output per port and host; another PC may drive its own port of that name.
        let node = ServiceNode::start(stereoscope_transport::NodeSpec {
            exclusive: stereoscope_transport::Exclusive::Host,
            ..ctx.node_spec(&service)
        })
        .map_err(transport)?;
        let poses = Inlet::zenoh(&node.session, &[keys::poses(&rig)], &rig, "pose frame", 256)
            .map_err(transport)?;
        tracing::info!(port = %cfg.port, baud = cfg.baud, mode = ?cfg.mode, "serial output ready");
        Ok(SerialService {
            cfg,
            node,
            poses,
            latest: None,
            generation: 0,
            port: None,
            next_open: Instant::now(),
            line_free: Instant::now(),
            sent_generation: 0,
            pending: Vec::new(),
            sequence: 0,
            last_sent: None,
            clamped: 0,
            packets: 0,
        })
    }

    /// Opens the port when it is closed and its retry time has come; whether it is open.
    fn ensure_open(&mut self, shutdown: &Shutdown) -> bool {
        if self.port.is_some() {
            return true;
        }
        if Instant::now() < self.next_open {
            shutdown.sleep(Duration::from_millis(20));
            return false;
        }
        let counters = &mut self.node.counters;
        match serialport::new(&self.cfg.port, self.cfg.baud)
            .timeout(Duration::from_millis(200))
            .open()
        {
            Ok(p) => {
                tracing::info!(port = %self.cfg.port, "port open");
                counters.set(Detail::Port, "open");
                self.port = Some(p);
                true
            }
            Err(e) => {
                let m = format!("{}: {e}; trying again in 1 s", self.cfg.port);
                if counters.last_error() != Some(&m) {
                    tracing::warn!("{m}");
                }
                counters.set_error(&m);
                counters.set(Detail::Port, "closed");
                self.next_open = Instant::now() + Duration::from_secs(1);
                false
            }
        }
    }

    /// The newest pose frame, with the objects still to send from it refreshed when it is new
    /// (those pending from an older frame are superseded and counted as dropped).
    fn newest_frame(&mut self) -> Option<PoseFrame> {
        let counters = &mut self.node.counters;
        while let Some(f) = self.poses.try_next(counters) {
            self.latest = Some(f);
            self.generation += 1;
        }
        let (frame, generation) = (self.latest.clone()?, self.generation);
        if generation != self.sent_generation {
            counters.dropped += self.pending.len() as u64;
            let order: Vec<u32> = selected(&frame, &self.cfg.objects, self.cfg.mode)
                .iter()
                .map(|p| p.object_id)
                .collect();
            self.pending = round_robin(&order, self.last_sent);
            self.pending.reverse();
            self.sent_generation = generation;
        }
        Some(frame)
    }
}

impl Service for SerialService {
    type Summary = u64;
    type Error = SerialServiceError;

    /// Packets written.
    fn limit(&self) -> Option<u64> {
        self.cfg.max_packets
    }

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Writes at most one packet: the next object's newest pose, when the line is free.
    fn step(&mut self, shutdown: &Shutdown) -> Result<Flow, SerialServiceError> {
        if !self.ensure_open(shutdown) {
            return Ok(Flow::Continue);
        }
        let Some(frame) = self.newest_frame() else {
            shutdown.sleep(Duration::from_millis(2));
            return Ok(Flow::Continue);
        };
        let Some(id) = self.pending.pop() else {
            shutdown.sleep(Duration::from_millis(1));
            return Ok(Flow::Continue);
        };
        let Some(pose) = frame.poses.iter().find(|p| p.object_id == id) else {
            return Ok(Flow::Continue);
        };
        let (bytes, clamped) = packet(pose, self.cfg.mode, self.sequence);
        self.last_sent = Some(id);
        // Wait for the line, then write.
        let now = Instant::now();
        if self.line_free > now && shutdown.sleep(self.line_free - now) {
            return Ok(Flow::Stop);
        }
        // No flush: tcdrain has no timeout, and a stalled receiver must not stall the service
        // (the write itself times out after 200 ms and the port is reopened).
        let Some(port) = self.port.as_mut() else {
            return Ok(Flow::Continue);
        };
        let counters = &mut self.node.counters;
        match port.write_all(&bytes) {
            Ok(()) => {
                self.line_free =
                    Instant::now().max(self.line_free) + line_time(bytes.len(), self.cfg.baud);
                self.sequence = self.sequence.wrapping_add(1);
                self.packets += 1;
                counters.processed = self.packets;
                if clamped > 0 {
                    self.clamped += 1;
                    counters.set(Detail::Clamped, self.clamped);
                }
            }
            Err(e) => {
                let m = format!("{}: writing: {e}; reopening", self.cfg.port);
                tracing::warn!("{m}");
                counters.set_error(&m);
                counters.set(Detail::Port, "closed");
                self.port = None;
                self.next_open = Instant::now() + Duration::from_secs(1);
            }
        }
        Ok(Flow::Continue)
    }

    fn summary(&self) -> u64 {
        self.packets
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, PoseMethod, SCHEMA_VERSION};
    use stereoscope_proto::serial::{FramedDecoder, LegacyDecoder};

    fn pose(id: u32, x: f64) -> Pose {
        Pose {
            object_id: id,
            position_m: [x, 0.25, 1.5],
            velocity_m_per_s: [0.0; 3],
            heading_deg: Some(123.45),
            heading_directed: false,
            method: PoseMethod::Triangulated,
            cameras: vec![],
            residual_px: 0.0,
            out_of_range: false,
            body: None,
            model: None,
        }
    }

    fn frame(poses: Vec<Pose>) -> PoseFrame {
        PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            sequence: 0,
            timestamp_ns: 0,
            frame_published_ns: 0,
            published_ns: 0,
            cameras: vec![],
            poses,
            bodies: Vec::new(),
            models: Vec::new(),
        }
    }

    #[test]
    fn selection_and_packets() {
        let f = frame(vec![pose(5, 0.1), pose(2, 0.2), pose(9, 400.0)]);
        let ids = |v: Vec<&Pose>| v.iter().map(|p| p.object_id).collect::<Vec<_>>();
        assert_eq!(ids(selected(&f, &[], SerialMode::Framed)), [2, 5, 9]);
        assert_eq!(ids(selected(&f, &[9, 5, 7], SerialMode::Framed)), [9, 5]);
        assert_eq!(ids(selected(&f, &[], SerialMode::Legacy)), [2]);
        assert_eq!(ids(selected(&f, &[5], SerialMode::Legacy)), [5]);
        let (b, c) = packet(&f.poses[1], SerialMode::Legacy, 0);
        assert_eq!((b.len(), c), (10, 0));
        let p = LegacyDecoder::default().push(&b);
        assert_eq!(
            (p[0].x_cm, p[0].y_cm, p[0].z_cm, p[0].heading_centideg),
            (20, 25, 150, 12345)
        );
        // 400 m does not fit int16 centimetres: clamped and counted.
        assert_eq!(packet(&f.poses[2], SerialMode::Legacy, 0).1, 1);
        let (b, c) = packet(&f.poses[0], SerialMode::Framed, 77);
        assert_eq!(c, 0);
        let p = FramedDecoder::default().push(&b);
        let p = p[0].as_ref().unwrap();
        assert_eq!(
            (p.object_id, p.sequence, p.x_mm, p.z_mm),
            (5, 77, 100, 1500)
        );
    }

    #[test]
    fn every_object_gets_its_turn() {
        assert_eq!(round_robin(&[2, 5, 9], None), [2, 5, 9]);
        assert_eq!(round_robin(&[2, 5, 9], Some(5)), [9, 2, 5]);
        assert_eq!(round_robin(&[2, 5, 9], Some(9)), [2, 5, 9]);
        assert_eq!(round_robin(&[2, 5, 9], Some(7)), [2, 5, 9]);
        assert!(round_robin(&[], Some(1)).is_empty());
    }

    #[test]
    fn line_time_is_ten_bits_a_byte() {
        assert_eq!(line_time(10, 9600), Duration::from_secs_f64(100.0 / 9600.0));
        assert!(line_time(960, 9600) >= Duration::from_millis(999));
    }
}
