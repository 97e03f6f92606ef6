//! A Qualisys Track Manager real-time server (the QTM RT protocol, `docs/lab-protocols.md`,
//! "Qualisys RT"), written from Qualisys's published protocol documentation and what its own
//! clients send and decode (the `qtm-rt` Python SDK, the C++ `qualisys_cpp_sdk` that
//! libmotioncapture links). No maintained Rust server exists.
//!
//! *Connecting.* TCP on the base port + 1 (22223 by default: little-endian, protocol 1.1 and
//! later — where both SDKs connect). The server greets with the command
//! `QTM RT Interface connected`; the client sets its version (`Version 1.25` → `Version set to
//! 1.25`; 1.1 to 1.25 are served). Packets are a u32 size (header included), a u32 type (0
//! error, 1 command, 2 XML, 3 data, 4 no more data, 6 event), the body; commands and strings
//! end with a NUL.
//!
//! *Commands served.* `Version`, `QTMVersion`, `ByteOrder`, `GetState` (an event: 1,
//! connected — the system is live), `GetParameters` (`All`, `General`, `3D`, `6D` as XML, in
//! the layout of the version asked for), `GetCurrentFrame` and `StreamFrames` (`AllFrames`,
//! `Frequency:n`, `FrequencyDivisor:n`; over the TCP connection, or `UDP[:address]:port` to the
//! client's own address), `StreamFrames Stop`, and `Close` (answered `Closing connection`,
//! then the connection ends). Components: `3D` (each body marker by label, NaN when hidden),
//! `3DRes`, `3DNoLabels` (markers of no body, with fusion's object id), `3DNoLabelsRes`, `6D`
//! (position, column-major rotation matrix), `6DRes`, `6DEuler`, `6DEulerRes`. Commands that
//! control a Qualisys system (`TakeControl`, `New`, `Start`, `Save`, …) are answered with an
//! error naming the command. Positions are millimetres in the world frame (z up, as QTM's)
//! unless the rig gives another frame.
//!
//! *Bad peers.* A packet over [`MAX_PACKET`] bytes or under a header, a client more than
//! [`MAX_BACKLOG_BYTES`] behind, or one that stays silent without streaming while the server
//! is full, is disconnected and counted; at most [`MAX_CLIENTS`] at once.

mod wire;
pub use wire::*;

use crate::output::{BodyDef, Counts, Output, OutputFrame};
use std::io::{ErrorKind, Read, Write};
use std::net::{IpAddr, SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::time::{Duration, Instant};
use stereoscope_rig::vr::ConsumerFrame;

/// Largest packet accepted from a client (commands are a line of text).
pub const MAX_PACKET: usize = 64 * 1024;
/// Unsent bytes a client may fall behind by before it is dropped.
pub const MAX_BACKLOG_BYTES: usize = 4 << 20;
/// Most clients at once.
pub const MAX_CLIENTS: usize = 32;
/// How long a silent, non-streaming client keeps its place when the server is full.
pub const IDLE_DISPLACE: Duration = Duration::from_secs(10);
/// The newest protocol version served (the `qtm-rt` SDK's default).
pub const NEWEST_MINOR: u32 = 25;

/// Settings of the server, resolved from the rig.
#[derive(Debug, Clone, PartialEq)]
pub struct QualisysConfig {
    /// The base port's address (22222); the server listens on the port after it.
    pub base: SocketAddr,
    pub frame: ConsumerFrame,
    /// The rig's nominal frame rate (General/Frequency).
    pub frequency_hz: f64,
}

/// How often a streaming client gets frames.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Rate {
    All,
    /// At most this many per second, by exposure time.
    Frequency(f64),
    /// Every n-th frame.
    Divisor(u64),
}

#[derive(Debug)]
struct Stream {
    rate: Rate,
    components: Vec<Component>,
    /// UDP destination; `None`: over the TCP connection.
    udp: Option<SocketAddr>,
    counter: u64,
    last_sent_ns: Option<u64>,
}

struct Client {
    peer: SocketAddr,
    stream: TcpStream,
    inbuf: Vec<u8>,
    outbuf: Vec<u8>,
    minor: u32,
    streaming: Option<Stream>,
    last_heard: Instant,
    closing: bool,
}

/// Why a client was disconnected.
#[derive(Debug, Clone, Copy)]
enum Gone {
    Closed,
    Garbage,
    Slow,
    Io,
    AskedToClose,
}

impl Gone {
    fn reason(self) -> &'static str {
        match self {
            Gone::Closed => "closed",
            Gone::Garbage => "garbage",
            Gone::Slow => "slow_client",
            Gone::Io => "io",
            Gone::AskedToClose => "closed",
        }
    }
    fn describe(self) -> &'static str {
        match self {
            Gone::Closed => "disconnected",
            Gone::Garbage => {
                "sent a packet that is not a QTM RT packet (size out of bounds); dropped"
            }
            Gone::Slow => "fell more than 4 MiB behind; dropped",
            Gone::Io => "socket error; dropped",
            Gone::AskedToClose => "asked to close",
        }
    }
}

impl Client {
    fn queue_text(&mut self, kind: u32, text: &str) {
        self.outbuf.extend_from_slice(&text_packet(kind, text));
    }

    fn flush(&mut self) -> Result<(), Gone> {
        while !self.outbuf.is_empty() {
            match self.stream.write(&self.outbuf) {
                Ok(0) => return Err(Gone::Closed),
                Ok(n) => {
                    self.outbuf.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => return Err(Gone::Io),
            }
        }
        if self.outbuf.len() > MAX_BACKLOG_BYTES {
            return Err(Gone::Slow);
        }
        if self.closing && self.outbuf.is_empty() {
            return Err(Gone::AskedToClose);
        }
        Ok(())
    }

    /// Reads what arrived; returns the whole packets (type, body without its NUL).
    fn receive(&mut self) -> Result<Vec<(u32, Vec<u8>)>, Gone> {
        let mut buf = [0u8; 8192];
        let mut packets = Vec::new();
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Err(Gone::Closed),
                Ok(n) => {
                    self.last_heard = Instant::now();
                    self.inbuf.extend_from_slice(&buf[..n]);
                    self.take_packets(&mut packets)?;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => return Err(Gone::Io),
            }
        }
        Ok(packets)
    }

    fn take_packets(&mut self, packets: &mut Vec<(u32, Vec<u8>)>) -> Result<(), Gone> {
        let mut at = 0;
        while self.inbuf.len() - at >= 8 {
            let word = |i: usize| {
                let b = &self.inbuf[at + 4 * i..at + 4 * i + 4];
                u32::from_le_bytes([b[0], b[1], b[2], b[3]])
            };
            let size = word(0) as usize;
            if !(8..=MAX_PACKET).contains(&size) {
                return Err(Gone::Garbage);
            }
            if self.inbuf.len() - at < size {
                break;
            }
            let kind = word(1);
            let mut body = self.inbuf[at + 8..at + size].to_vec();
            if body.last() == Some(&0) {
                body.pop();
            }
            packets.push((kind, body));
            at += size;
        }
        self.inbuf.drain(..at);
        Ok(())
    }
}

/// The server: its listening socket, the UDP socket UDP streams leave from, its clients.
pub struct QualisysServer {
    cfg: QualisysConfig,
    tcp: TcpListener,
    udp: UdpSocket,
    bodies: Vec<BodyDef>,
    clients: Vec<Client>,
    /// The last frame's pieces, for `GetCurrentFrame`.
    last: Option<LastFrame>,
    counts: Counts,
}

/// A frame kept for `GetCurrentFrame`.
struct LastFrame {
    sequence: u64,
    exposure_ns: u64,
    received_ns: u64,
    bodies: Vec<crate::output::OutputBody>,
    markers: Vec<crate::output::OutputMarker>,
}

impl std::fmt::Debug for QualisysServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "QualisysServer({} clients)", self.clients.len())
    }
}

/// Commands that would control a Qualisys system; refused by name.
const CONTROL: [&str; 17] = [
    "takecontrol",
    "releasecontrol",
    "new",
    "start",
    "stop",
    "load",
    "save",
    "loadproject",
    "trig",
    "setqtmevent",
    "event",
    "calibrate",
    "reprocess",
    "led",
    "getcapturec3d",
    "getcaptureqtm",
    "quit",
];

impl QualisysServer {
    /// Listens on the base port + 1 of `cfg.base` (port 0: any free port, for tests).
    pub fn bind(cfg: QualisysConfig, bodies: Vec<BodyDef>) -> std::io::Result<QualisysServer> {
        let port = if cfg.base.port() == 0 {
            0
        } else {
            cfg.base.port().checked_add(1).ok_or_else(|| {
                std::io::Error::new(ErrorKind::InvalidInput, "the base port is 65535")
            })?
        };
        let tcp = TcpListener::bind(SocketAddr::new(cfg.base.ip(), port))?;
        tcp.set_nonblocking(true)?;
        let udp = UdpSocket::bind(SocketAddr::new(cfg.base.ip(), 0))?;
        udp.set_nonblocking(true)?;
        Ok(QualisysServer {
            cfg,
            tcp,
            udp,
            bodies,
            clients: Vec::new(),
            last: None,
            counts: Counts::default(),
        })
    }

    /// The little-endian port's address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.tcp.local_addr()
    }

    fn admit(&mut self, stream: TcpStream, peer: SocketAddr) {
        if self.clients.len() >= MAX_CLIENTS {
            // A silent client that is not streaming gives up its place.
            let idle = (0..self.clients.len())
                .filter(|&i| {
                    self.clients[i].streaming.is_none()
                        && self.clients[i].last_heard.elapsed() > IDLE_DISPLACE
                })
                .min_by_key(|&i| self.clients[i].last_heard);
            match idle {
                Some(i) => {
                    let c = self.clients.remove(i);
                    self.counts.drop(
                        "idle",
                        format!("Qualisys RT client {} silent, displaced by {peer}", c.peer),
                    );
                }
                None => {
                    self.counts.drop(
                        "too_many_clients",
                        format!("Qualisys RT client {peer} refused: {MAX_CLIENTS} already"),
                    );
                    return;
                }
            }
        }
        if stream.set_nonblocking(true).is_err() || stream.set_nodelay(true).is_err() {
            self.counts.drop(
                "io",
                format!("Qualisys RT client {peer}: socket setup failed"),
            );
            return;
        }
        tracing::info!("Qualisys RT client {peer} connected");
        let mut c = Client {
            peer,
            stream,
            inbuf: Vec::new(),
            outbuf: Vec::new(),
            minor: 1,
            streaming: None,
            last_heard: Instant::now(),
            closing: false,
        };
        c.queue_text(PACKET_COMMAND, "QTM RT Interface connected");
        self.clients.push(c);
    }

    fn current_body(&self, components: &[Component]) -> Option<Vec<u8>> {
        let l = self.last.as_ref()?;
        let f = OutputFrame {
            sequence: l.sequence,
            exposure_ns: l.exposure_ns,
            received_ns: l.received_ns,
            bodies: &l.bodies,
            markers: &l.markers,
            models: &[],
        };
        Some(data_body(&f, &self.bodies, &self.cfg.frame, components))
    }

    /// Handles one command from client `i`.
    fn command(&mut self, i: usize, text: &str) {
        let words: Vec<&str> = text.split_whitespace().collect();
        let Some(first) = words.first() else {
            self.clients[i].queue_text(PACKET_ERROR, "Parse error: an empty command");
            return;
        };
        let verb = first.to_ascii_lowercase();
        let c = &mut self.clients[i];
        match verb.as_str() {
            "version" => match words.get(1) {
                None => {
                    let m = c.minor;
                    c.queue_text(PACKET_COMMAND, &format!("Version is 1.{m}"));
                }
                Some(v) => match parse_version(v) {
                    Some(minor) if (1..=NEWEST_MINOR).contains(&minor) => {
                        c.minor = minor;
                        c.queue_text(PACKET_COMMAND, &format!("Version set to 1.{minor}"));
                    }
                    _ => c.queue_text(
                        PACKET_ERROR,
                        &format!("Version NOT supported: {v} (this server speaks 1.1 to 1.{NEWEST_MINOR})"),
                    ),
                },
            },
            "qtmversion" => c.queue_text(
                PACKET_COMMAND,
                &format!(
                    "QTM Version is Stereoscope {} (QTM RT protocol server)",
                    env!("CARGO_PKG_VERSION")
                ),
            ),
            "byteorder" => c.queue_text(PACKET_COMMAND, "Byte order is little endian"),
            "getstate" | "getlastevent" => {
                c.outbuf
                    .extend_from_slice(&packet(PACKET_EVENT, &[EVENT_CONNECTED]));
            }
            "getparameters" => {
                let sections: Vec<&str> = words[1..].to_vec();
                let known = ["all", "general", "3d", "6d"];
                if let Some(bad) = sections
                    .iter()
                    .find(|s| !known.contains(&s.to_ascii_lowercase().as_str()))
                {
                    c.queue_text(
                        PACKET_ERROR,
                        &format!("GetParameters: {bad} is not served (All, General, 3D and 6D are)"),
                    );
                    return;
                }
                let xml = parameters_xml(
                    if sections.is_empty() { &["all"] } else { &sections },
                    c.minor,
                    &self.bodies,
                    &self.cfg,
                );
                self.clients[i].queue_text(PACKET_XML, &xml);
            }
            "getcurrentframe" => match components(&words[1..]) {
                Err(e) => c.queue_text(PACKET_ERROR, &e.to_string()),
                Ok(comps) => match self.current_body(&comps) {
                    Some(b) => self.clients[i]
                        .outbuf
                        .extend_from_slice(&packet(PACKET_DATA, &b)),
                    None => self.clients[i]
                        .outbuf
                        .extend_from_slice(&packet(PACKET_NO_MORE_DATA, &[])),
                },
            },
            "streamframes" => {
                if words.get(1).is_some_and(|w| w.eq_ignore_ascii_case("stop")) {
                    c.streaming = None;
                    return;
                }
                match stream_request(&words[1..], c.peer) {
                    Ok(s) => c.streaming = Some(s),
                    Err(e) => c.queue_text(PACKET_ERROR, &e.to_string()),
                }
            }
            "close" => {
                c.queue_text(PACKET_COMMAND, "Closing connection");
                c.closing = true;
            }
            v if CONTROL.contains(&v) => c.queue_text(
                PACKET_ERROR,
                &format!(
                    "{first}: refused; Stereoscope's RT server streams data and does not control capture"
                ),
            ),
            _ => c.queue_text(
                PACKET_ERROR,
                &format!(
                    "Parse error: {:?} is not a command",
                    first.chars().take(40).collect::<String>()
                ),
            ),
        }
    }
}

/// `1.25` → 25.
fn parse_version(v: &str) -> Option<u32> {
    let (major, minor) = v.split_once('.')?;
    if major != "1" {
        return None;
    }
    minor.parse().ok()
}

/// Why a client's `GetCurrentFrame` or `StreamFrames` is refused: its text is the error
/// packet's, as QTM words them ("Parse error: …").
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum RequestError {
    #[error("Parse error: no component named")]
    NoComponent,
    #[error(
        "Parse error: component {0} is not served (3D, 3DRes, 3DNoLabels, 3DNoLabelsRes, 6D, 6DRes, 6DEuler, 6DEulerRes are)"
    )]
    Component(String),
    #[error("Parse error: StreamFrames needs AllFrames, Frequency:n or FrequencyDivisor:n")]
    NoRate,
    #[error("Parse error: {0}: the divisor must be a whole number ≥ 1")]
    Divisor(String),
    #[error("Parse error: {0}: the frequency must be a number > 0")]
    Frequency(String),
    #[error("Parse error: {0} is not AllFrames, Frequency:n or FrequencyDivisor:n")]
    Rate(String),
    #[error("Parse error: {word}: {ip} is not an IP address")]
    Address { word: String, ip: String },
    #[error("Parse error: {0} is not UDP:port or UDP:address:port")]
    Udp(String),
    #[error("{word}: refused; frames go only to the client's own address ({peer})")]
    OtherAddress { word: String, peer: IpAddr },
    #[error("Parse error: {word}: {port} is not a port")]
    Port { word: String, port: String },
}

fn components(words: &[&str]) -> Result<Vec<Component>, RequestError> {
    if words.is_empty() {
        return Err(RequestError::NoComponent);
    }
    words
        .iter()
        .map(|w| Component::parse(w).ok_or_else(|| RequestError::Component(w.to_string())))
        .collect()
}

/// `StreamFrames`' arguments: the rate, an optional `UDP[:address]:port`, the components.
fn stream_request(words: &[&str], peer: SocketAddr) -> Result<Stream, RequestError> {
    let Some(first) = words.first() else {
        return Err(RequestError::NoRate);
    };
    let lower = first.to_ascii_lowercase();
    let rate = if lower == "allframes" {
        Rate::All
    } else if let Some(n) = lower.strip_prefix("frequencydivisor:") {
        match n.parse::<u64>() {
            Ok(n) if n >= 1 => Rate::Divisor(n),
            _ => return Err(RequestError::Divisor(first.to_string())),
        }
    } else if let Some(n) = lower.strip_prefix("frequency:") {
        match n.parse::<f64>() {
            Ok(n) if n.is_finite() && n > 0.0 => Rate::Frequency(n),
            _ => return Err(RequestError::Frequency(first.to_string())),
        }
    } else {
        return Err(RequestError::Rate(first.to_string()));
    };
    let mut rest = &words[1..];
    let mut udp = None;
    if let Some(w) = rest.first()
        && w.to_ascii_lowercase().starts_with("udp")
    {
        let parts: Vec<&str> = w.split(':').collect();
        let (ip, port) = match parts.as_slice() {
            [_, port] => (peer.ip(), *port),
            [_, ip, port] => match ip.parse::<IpAddr>() {
                Ok(ip) => (ip, *port),
                Err(_) => {
                    return Err(RequestError::Address {
                        word: w.to_string(),
                        ip: ip.to_string(),
                    });
                }
            },
            _ => return Err(RequestError::Udp(w.to_string())),
        };
        if ip != peer.ip() {
            return Err(RequestError::OtherAddress {
                word: w.to_string(),
                peer: peer.ip(),
            });
        }
        let port: u16 = match port.parse() {
            Ok(p) if p > 0 => p,
            _ => {
                return Err(RequestError::Port {
                    word: w.to_string(),
                    port: port.to_string(),
                });
            }
        };
        udp = Some(SocketAddr::new(ip, port));
        rest = &rest[1..];
    }
    Ok(Stream {
        rate,
        components: components(rest)?,
        udp,
        counter: 0,
        last_sent_ns: None,
    })
}

impl Output for QualisysServer {
    fn name(&self) -> &'static str {
        "qualisys"
    }

    fn poll(&mut self) {
        for _ in 0..256 {
            match self.tcp.accept() {
                Ok((s, peer)) => self.admit(s, peer),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => {
                    // Out of descriptors, say: counted; the listener stays.
                    self.counts.error(format!("Qualisys RT accept: {e}"));
                    break;
                }
            }
        }
        let mut i = 0;
        while i < self.clients.len() {
            let r = self.clients[i].receive();
            match r {
                Ok(packets) => {
                    for (kind, body) in packets {
                        if kind == PACKET_COMMAND {
                            let text = String::from_utf8_lossy(&body).into_owned();
                            self.command(i, &text);
                        } else {
                            self.clients[i].queue_text(
                                PACKET_ERROR,
                                &format!("packet type {kind} refused: only commands are served (settings cannot be changed)"),
                            );
                        }
                    }
                    match self.clients[i].flush() {
                        Ok(()) => i += 1,
                        Err(g) => self.remove(i, g),
                    }
                }
                Err(g) => self.remove(i, g),
            }
        }
    }

    fn send(&mut self, f: &OutputFrame) {
        self.last = Some(LastFrame {
            sequence: f.sequence,
            exposure_ns: f.exposure_ns,
            received_ns: f.received_ns,
            bodies: f.bodies.to_vec(),
            markers: f.markers.to_vec(),
        });
        let mut i = 0;
        while i < self.clients.len() {
            let c = &mut self.clients[i];
            let due = match &mut c.streaming {
                None => false,
                Some(s) => {
                    s.counter += 1;
                    let due = match s.rate {
                        Rate::All => true,
                        Rate::Divisor(n) => s.counter % n == 1 % n,
                        Rate::Frequency(hz) => s.last_sent_ns.is_none_or(|t| {
                            // Half a frame's slack so 60 Hz from 240 Hz takes every 4th.
                            f.exposure_ns.saturating_sub(t) as f64 >= 1e9 / hz * 0.99
                        }),
                    };
                    if due {
                        s.last_sent_ns = Some(f.exposure_ns);
                    }
                    due
                }
            };
            if due && let Some(s) = &c.streaming {
                let body = data_body(f, &self.bodies, &self.cfg.frame, &s.components);
                let p = packet(PACKET_DATA, &body);
                match s.udp {
                    Some(to) => {
                        if let Err(e) = self.udp.send_to(&p, to) {
                            self.counts
                                .send_error(format!("Qualisys RT frame to {to}: {e}"));
                        }
                    }
                    None => c.outbuf.extend_from_slice(&p),
                }
            }
            match self.clients[i].flush() {
                Ok(()) => i += 1,
                Err(g) => self.remove(i, g),
            }
        }
        self.counts.frames += 1;
    }

    fn counts(&mut self) -> &mut Counts {
        &mut self.counts
    }

    fn clients(&self) -> Option<usize> {
        Some(self.clients.len())
    }

    /// In place: `GetParameters 6D` and 3D's labels answer with the new bodies, and 6D data
    /// carries one entry per body of the table from the next frame (a body no longer in the rig
    /// keeps its place, untracked). QTM has no event for it; clients read the parameters again.
    fn set_bodies(&mut self, bodies: &[BodyDef]) -> bool {
        self.bodies = bodies.to_vec();
        true
    }
}

impl QualisysServer {
    fn remove(&mut self, i: usize, g: Gone) {
        let c = self.clients.remove(i);
        let m = format!("Qualisys RT client {} {}", c.peer, g.describe());
        tracing::info!("{m}");
        self.counts.drop(g.reason(), m);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::{OutputBody, OutputMarker};
    use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

    fn bodies() -> Vec<BodyDef> {
        vec![BodyDef {
            name: "head".into(),
            markers_m: vec![Point3::new(0.05, 0.0, 0.0), Point3::new(0.0, 0.05, 0.0)],
        }]
    }

    #[test]
    fn euler_angles_rebuild_the_rotation() {
        for (a, b, c) in [(10.0, 20.0, 30.0), (-170.0, -45.0, 80.0), (0.0, 0.0, 0.0)] {
            let r = Rotation3::from_axis_angle(&Vector3::x_axis(), f64::to_radians(a))
                * Rotation3::from_axis_angle(&Vector3::y_axis(), f64::to_radians(b))
                * Rotation3::from_axis_angle(&Vector3::z_axis(), f64::to_radians(c));
            let got = euler_xyz_deg(&r);
            for (g, w) in got.iter().zip([a, b, c]) {
                assert!((g - w).abs() < 1e-9, "{got:?} vs {a} {b} {c}");
            }
        }
    }

    #[test]
    fn data_packets_hold_each_component_at_its_size() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5),
        );
        let b = [OutputBody {
            index: 0,
            world_from_body: pose,
            residual_mm: 0.5,
            tracked: true,
            velocity_m_per_s: [0.0; 3],
            angular_velocity_rad_per_s: [0.0; 3],
        }];
        let m = [
            OutputMarker {
                position_m: Point3::new(0.15, 0.2, 0.3),
                label: Some((0, 1)),
                object_id: 3,
            },
            OutputMarker {
                position_m: Point3::new(1.0, 1.0, 1.0),
                label: None,
                object_id: 9,
            },
        ];
        let f = OutputFrame {
            sequence: 5,
            exposure_ns: 2_000_123_000,
            received_ns: 0,
            bodies: &b,
            markers: &m,
            models: &[],
        };
        let mm = ConsumerFrame {
            units_per_m: 1000.0,
            ..ConsumerFrame::identity()
        };
        let comps = [
            Component::ThreeD,
            Component::ThreeDNoLabels,
            Component::SixD,
            Component::SixDEulerRes,
        ];
        let d = data_body(&f, &bodies(), &mm, &comps);
        let u32_at = |at: usize| u32::from_le_bytes(d[at..at + 4].try_into().unwrap());
        let f32_at = |at: usize| f32::from_le_bytes(d[at..at + 4].try_into().unwrap());
        assert_eq!(i64::from_le_bytes(d[0..8].try_into().unwrap()), 2_000_123);
        assert_eq!((u32_at(8), u32_at(12)), (5, 4));
        let mut at = 16;
        let mut sizes = Vec::new();
        for _ in 0..4 {
            sizes.push((u32_at(at + 4), u32_at(at)));
            at += u32_at(at) as usize;
        }
        assert_eq!(at, d.len());
        // 3D: 2 labels × 12; no labels: 1 × 16; 6D: 48; 6D Euler with residual: 28.
        assert_eq!(
            sizes,
            vec![(1, 16 + 24), (2, 16 + 16), (5, 16 + 48), (12, 16 + 28)]
        );
        // The hidden first label is NaN, the seen second at (150, 200, 300) mm.
        assert!(f32_at(16 + 16).is_nan());
        assert_eq!(f32_at(16 + 28), 150.0);
        // 6D's matrix is column-major: element 1 is R(1,0) = sin 0.5.
        let six = 16 + 40 + 32 + 16;
        assert!((f32_at(six + 12 + 4) - 0.5f32.sin()).abs() < 1e-6);
    }

    #[test]
    fn old_and_new_parameter_layouts() {
        let cfg = QualisysConfig {
            base: "127.0.0.1:0".parse().unwrap(),
            frame: ConsumerFrame::identity(),
            frequency_hz: 120.0,
        };
        let new = parameters_xml(&["6d"], 25, &bodies(), &cfg);
        assert!(new.starts_with("<QTM_Parameters_Ver_1.25><The_6D><Body><Name>head</Name>"));
        assert!(new.contains("Name=\"head_2\""));
        let old = parameters_xml(&["All"], 19, &bodies(), &cfg);
        assert!(old.contains("<Frequency>120</Frequency>"));
        assert!(old.contains("<The_6D><Bodies>1</Bodies><Body><Name>head</Name><RGBColor>"));
        assert!(old.contains("<Labels>2</Labels>"));
    }

    #[test]
    fn stream_requests_are_checked() {
        let peer: SocketAddr = "127.0.0.1:5000".parse().unwrap();
        let s = stream_request(
            &["FrequencyDivisor:4", "UDP:6734", "6deuler", "3DNoLabels"],
            peer,
        )
        .unwrap();
        assert_eq!(s.rate, Rate::Divisor(4));
        assert_eq!(s.udp, Some("127.0.0.1:6734".parse().unwrap()));
        assert_eq!(
            s.components,
            vec![Component::SixDEuler, Component::ThreeDNoLabels]
        );
        let e = stream_request(&["AllFrames", "UDP:10.0.0.9:6734", "6D"], peer)
            .unwrap_err()
            .to_string();
        assert!(e.contains("10.0.0.9") && e.contains("refused"), "{e}");
        let e = stream_request(&["AllFrames", "Analog"], peer)
            .unwrap_err()
            .to_string();
        assert!(e.contains("Analog"), "{e}");
        assert!(stream_request(&["Frequency:0", "6D"], peer).is_err());
    }

    fn command_packet(text: &str) -> Vec<u8> {
        text_packet(PACKET_COMMAND, text)
    }

    /// Polls until `pred` holds (bounded).
    fn poll_until(s: &mut QualisysServer, what: &str, pred: impl Fn(&QualisysServer) -> bool) {
        let end = Instant::now() + Duration::from_secs(5);
        while !pred(s) {
            assert!(Instant::now() < end, "never {what}: {:?}", s.counts);
            s.poll();
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// A streaming client that never reads is dropped once 4 MiB behind; one that claims a
    /// gigabyte packet is dropped at its header; a reading client gets every frame meanwhile.
    #[test]
    fn a_client_that_never_reads_is_dropped_and_others_go_on() {
        let cfg = QualisysConfig {
            base: "127.0.0.1:0".parse().unwrap(),
            frame: ConsumerFrame::identity(),
            frequency_hz: 240.0,
        };
        let mut s = QualisysServer::bind(cfg, bodies()).unwrap();
        let at = s.local_addr().unwrap();
        let mut deaf = TcpStream::connect(at).unwrap();
        let mut good = TcpStream::connect(at).unwrap();
        let mut liar = TcpStream::connect(at).unwrap();
        poll_until(&mut s, "three clients", |s| s.clients() == Some(3));
        for c in [&mut deaf, &mut good] {
            c.write_all(&command_packet("StreamFrames AllFrames 3D 6D 6DEuler"))
                .unwrap();
        }
        let mut header = (1u32 << 30).to_le_bytes().to_vec();
        header.extend_from_slice(&PACKET_COMMAND.to_le_bytes());
        liar.write_all(&header).unwrap();
        poll_until(&mut s, "both streaming, the liar dropped", |s| {
            s.clients.iter().filter(|c| c.streaming.is_some()).count() == 2
        });
        assert!(s.counts.dropped.iter().any(|d| d.0 == "garbage"));
        good.set_nonblocking(true).unwrap();
        let pose = Isometry3::identity();
        let b = [OutputBody {
            index: 0,
            world_from_body: pose,
            residual_mm: 0.1,
            tracked: true,
            velocity_m_per_s: [0.0; 3],
            angular_velocity_rad_per_s: [0.0; 3],
        }];
        let mut read = 0usize;
        let mut buf = vec![0u8; 1 << 16];
        let mut sent = 0u64;
        while s.clients() == Some(2) && sent < 2_000_000 {
            sent += 1;
            let f = OutputFrame {
                sequence: sent,
                exposure_ns: sent * 4_166_667,
                received_ns: 0,
                bodies: &b,
                markers: &[],
                models: &[],
            };
            s.send(&f);
            while let Ok(n) = good.read(&mut buf) {
                if n == 0 {
                    break;
                }
                read += n;
            }
        }
        assert_eq!(s.clients(), Some(1), "the deaf client was never dropped");
        assert!(s.counts.dropped.iter().any(|d| d.0 == "slow_client"));
        // The reading client was sent every frame up to then.
        let frame_bytes = packet(
            PACKET_DATA,
            &data_body(
                &OutputFrame {
                    sequence: 1,
                    exposure_ns: 0,
                    received_ns: 0,
                    bodies: &b,
                    markers: &[],
                    models: &[],
                },
                &bodies(),
                &ConsumerFrame::identity(),
                &[Component::ThreeD, Component::SixD, Component::SixDEuler],
            ),
        )
        .len();
        assert!(read + MAX_BACKLOG_BYTES + (8 << 20) >= sent as usize * frame_bytes);
        assert!(read >= frame_bytes, "the reading client got nothing");
    }
}
