//! A NatNet server (OptiTrack Motive's streaming protocol, `docs/lab-protocols.md`, "NatNet"),
//! written from what clients decode: libmotioncapture's `src/optitrack.cpp` and OptiTrack's own
//! Python sample client (`NatNetClient.py`, PyPI `natnetsdk`). No specification is published;
//! no maintained Rust server exists.
//!
//! *Version.* The server speaks **NatNet 4.1** (Motive 3.x), the newest both reference clients
//! decode: every data section carries its byte count after its item count.
//!
//! *Sockets.* Commands arrive on UDP port 1510 (`command`): each packet is a little-endian u16
//! message id, a u16 payload length, the payload. `CONNECT` (0) is answered with
//! `SERVERINFO` (1): application name (256 bytes), application version (4 bytes), NatNet
//! version (4 bytes), the tick frequency of the timestamps (u64), the data port (u16), whether
//! data is multicast (u8) and the group (4 bytes). `REQUEST_MODELDEF` (4) is answered with
//! `MODELDEF` (5), `REQUEST_FRAMEOFDATA` (6) with the last frame, `REQUEST` (2) with a
//! `RESPONSE` (3) for the queries this server knows (`Bitstream` → `"Bitstream,4.1.0.0"`) and
//! `UNRECOGNIZED_REQUEST` (100) for the rest, `KEEPALIVE` (10) renews a unicast client,
//! `DISCONNECT` (9) ends it.
//!
//! *Frames* (`FRAMEOFDATA`, 7) go to the multicast group and data port (239.255.42.99:1511 by
//! default), or with `multicast` off to each client that sent `CONNECT`: to the address it
//! sent from (OptiTrack's client reads frames on its command socket in unicast) and to its
//! host's data port (libmotioncapture listens there).
//!
//! *Bad peers.* A datagram shorter than its header, with a length that disagrees with its
//! size, or with an unknown id is counted and answered with `UNRECOGNIZED_REQUEST` at most
//! once per datagram; nothing a peer sends allocates more than one datagram. Unicast clients
//! are at most [`MAX_UNICAST_CLIENTS`]; a new one displaces the one heard from longest ago.

use crate::output::{BodyDef, Counts, Output, OutputFrame};
use nalgebra::{Point3, UnitQuaternion};
use socket2::{Domain, Protocol, Socket, Type};
use std::io::ErrorKind;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use stereoscope_rig::vr::ConsumerFrame;

pub const NAT_CONNECT: u16 = 0;
pub const NAT_SERVERINFO: u16 = 1;
pub const NAT_REQUEST: u16 = 2;
pub const NAT_RESPONSE: u16 = 3;
pub const NAT_REQUEST_MODELDEF: u16 = 4;
pub const NAT_MODELDEF: u16 = 5;
pub const NAT_REQUEST_FRAMEOFDATA: u16 = 6;
pub const NAT_FRAMEOFDATA: u16 = 7;
pub const NAT_DISCONNECT: u16 = 9;
pub const NAT_KEEPALIVE: u16 = 10;
pub const NAT_UNRECOGNIZED_REQUEST: u16 = 100;

/// The NatNet version spoken.
pub const NATNET_VERSION: [u8; 4] = [4, 1, 0, 0];
/// Ticks per second of the three high-resolution stamps: they are nanoseconds of the system
/// clock (Unix time), the clock every Stereoscope stamp is on.
pub const CLOCK_HZ: u64 = 1_000_000_000;
/// The largest payload a NatNet packet's u16 length can state.
pub const MAX_PAYLOAD: usize = u16::MAX as usize;
/// Most unicast clients at once.
pub const MAX_UNICAST_CLIENTS: usize = 32;
/// Marker diameter reported for every labelled marker, metres (the rig does not measure it).
const MARKER_SIZE_M: f32 = 0.0;
/// `FRAMEOFDATA` params bit: the tracked models changed; clients ask for the definitions again.
pub const MODELS_CHANGED: u16 = 0x02;
/// How long after a change of the bodies every frame carries [`MODELS_CHANGED`].
pub const MODELS_CHANGED_FOR: std::time::Duration = std::time::Duration::from_secs(1);

/// Settings of the NatNet server, resolved from the rig.
#[derive(Debug, Clone, PartialEq)]
pub struct NatNetConfig {
    pub command: SocketAddr,
    pub data_port: u16,
    /// The multicast group frames go to; `None`: unicast to each connected client.
    pub multicast: Option<Ipv4Addr>,
    pub frame: ConsumerFrame,
}

fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_i32(out: &mut Vec<u8>, v: i32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&(v as f32).to_le_bytes());
}
fn put_str(out: &mut Vec<u8>, s: &str) {
    // A name never carries a NUL of its own (it would end the string early for a client).
    out.extend(s.bytes().filter(|b| *b != 0));
    out.push(0);
}

/// A packet: id, payload length, payload. `None` when the payload is over [`MAX_PAYLOAD`].
pub fn packet(id: u16, payload: &[u8]) -> Option<Vec<u8>> {
    let n = u16::try_from(payload.len()).ok()?;
    let mut out = Vec::with_capacity(4 + payload.len());
    put_u16(&mut out, id);
    put_u16(&mut out, n);
    out.extend_from_slice(payload);
    Some(out)
}

/// `SERVERINFO`'s payload.
pub fn server_info(data_port: u16, multicast: Option<Ipv4Addr>) -> Vec<u8> {
    let mut p = vec![0u8; 256];
    let name = b"Stereoscope";
    p[..name.len()].copy_from_slice(name);
    let v = crate_version();
    p.extend_from_slice(&v);
    p.extend_from_slice(&NATNET_VERSION);
    p.extend_from_slice(&CLOCK_HZ.to_le_bytes());
    put_u16(&mut p, data_port);
    p.push(u8::from(multicast.is_some()));
    p.extend_from_slice(&multicast.unwrap_or(Ipv4Addr::UNSPECIFIED).octets());
    p
}

/// This build's version as four bytes (major, minor, patch, 0).
fn crate_version() -> [u8; 4] {
    let mut v = [0u8; 4];
    for (i, part) in env!("CARGO_PKG_VERSION").split('.').take(3).enumerate() {
        v[i] = part.parse().unwrap_or(0);
    }
    v
}

/// Marker ids of a body's markers: the body's id in the high 16 bits, the marker's number
/// (from 1) in the low ones, as Motive labels asset markers.
pub fn marker_id(body_id: i32, marker: u32) -> i32 {
    (body_id << 16) | ((marker + 1) as i32 & 0xffff)
}

/// The NatNet id of the rig's body `index` (from 1, in rig order).
pub fn body_id(index: usize) -> i32 {
    index as i32 + 1
}

/// `MODELDEF`'s payload: per body a marker set (its markers' names) and a rigid body (name,
/// id, no parent, zero offset, its markers in its own frame, names).
pub fn model_definitions(bodies: &[BodyDef], frame: &ConsumerFrame) -> Vec<u8> {
    let mut p = Vec::new();
    put_i32(&mut p, (bodies.len() * 2) as i32);
    for b in bodies {
        let mut d = Vec::new();
        put_str(&mut d, &b.name);
        put_i32(&mut d, b.markers_m.len() as i32);
        for k in 0..b.markers_m.len() {
            put_str(&mut d, &marker_name(&b.name, k));
        }
        put_i32(&mut p, 0);
        put_i32(&mut p, d.len() as i32);
        p.extend_from_slice(&d);
    }
    for (i, b) in bodies.iter().enumerate() {
        let mut d = Vec::new();
        put_str(&mut d, &b.name);
        put_i32(&mut d, body_id(i));
        put_i32(&mut d, -1);
        for _ in 0..3 {
            put_f32(&mut d, 0.0);
        }
        put_i32(&mut d, b.markers_m.len() as i32);
        // Offsets in the body's frame, on the consumer's axes and unit.
        for m in &b.markers_m {
            let v = frame.consumer_from_world * m.coords * frame.units_per_m;
            for c in v.iter() {
                put_f32(&mut d, *c);
            }
        }
        for _ in &b.markers_m {
            put_i32(&mut d, 0);
        }
        for k in 0..b.markers_m.len() {
            put_str(&mut d, &marker_name(&b.name, k));
        }
        put_i32(&mut p, 1);
        put_i32(&mut p, d.len() as i32);
        p.extend_from_slice(&d);
    }
    p
}

/// A body marker's name: the body's, then its number from 1 (`head_1`), as Motive names them.
pub fn marker_name(body: &str, k: usize) -> String {
    format!("{body}_{}", k + 1)
}

/// A section: item count, byte count of what follows, the items.
fn section(out: &mut Vec<u8>, count: usize, items: &[u8]) {
    put_i32(out, count as i32);
    put_i32(out, items.len() as i32);
    out.extend_from_slice(items);
}

/// `FRAMEOFDATA`'s payload for one pose frame, positions and rotations in `frame`.
/// `transmit_ns` is the time the frame is handed to the socket.
pub fn frame_of_data(
    f: &OutputFrame,
    bodies: &[BodyDef],
    frame: &ConsumerFrame,
    transmit_ns: u64,
    models_changed: bool,
) -> Vec<u8> {
    let pos = |p: &Point3<f64>| frame.position(p);
    let mut p = Vec::with_capacity(256);
    put_i32(&mut p, f.sequence as i32);
    // Marker sets: one per body, its markers in definition order where seen this frame, the
    // posed definition where not.
    let mut sets = Vec::new();
    let mut n_sets = 0;
    for (i, b) in bodies.iter().enumerate() {
        let Some(pose) = f.bodies.iter().find(|o| o.index == i) else {
            continue;
        };
        n_sets += 1;
        put_str(&mut sets, &b.name);
        put_i32(&mut sets, b.markers_m.len() as i32);
        for (k, m) in b.markers_m.iter().enumerate() {
            let seen = f
                .markers
                .iter()
                .find(|x| x.label == Some((i, k as u32)))
                .map(|x| x.position_m);
            let at = seen.unwrap_or_else(|| pose.world_from_body * m);
            for c in pos(&at).iter() {
                put_f32(&mut sets, *c);
            }
        }
    }
    section(&mut p, n_sets, &sets);
    // The legacy "other markers" list: empty (NatNet 3+ clients read labelled markers).
    section(&mut p, 0, &[]);
    // Rigid bodies.
    let mut rb = Vec::new();
    for o in f.bodies {
        put_i32(&mut rb, body_id(o.index));
        for c in pos(&Point3::from(o.world_from_body.translation.vector)).iter() {
            put_f32(&mut rb, *c);
        }
        let q = frame.rotation(&o.world_from_body.rotation);
        for c in [q.i, q.j, q.k, q.w] {
            put_f32(&mut rb, c);
        }
        // Mean marker error in the consumer's unit.
        put_f32(&mut rb, o.residual_mm * 1e-3 * frame.units_per_m);
        put_u16(&mut rb, u16::from(o.tracked));
    }
    section(&mut p, f.bodies.len(), &rb);
    section(&mut p, 0, &[]); // skeletons
    section(&mut p, 0, &[]); // assets
    // Labelled markers: every marker of the frame. Body markers carry body id and number;
    // loose ones their object id, flagged unlabelled.
    let mut lm = Vec::new();
    for m in f.markers {
        let (id, params) = match m.label {
            Some((b, k)) => (marker_id(body_id(b), k), 0x08u16),
            None => ((m.object_id & 0xffff) as i32, 0x10u16),
        };
        put_i32(&mut lm, id);
        for c in pos(&m.position_m).iter() {
            put_f32(&mut lm, *c);
        }
        lm.extend_from_slice(&MARKER_SIZE_M.to_le_bytes());
        put_u16(&mut lm, params | 0x02);
        // Residual in the consumer's unit; pixels are not a length, so 0 when unknown.
        put_f32(&mut lm, 0.0);
    }
    section(&mut p, f.markers.len(), &lm);
    section(&mut p, 0, &[]); // force plates
    section(&mut p, 0, &[]); // devices
    p.extend_from_slice(&0u32.to_le_bytes()); // timecode
    p.extend_from_slice(&0u32.to_le_bytes()); // timecode subframe
    p.extend_from_slice(&(f.exposure_ns as f64 * 1e-9).to_le_bytes());
    p.extend_from_slice(&f.exposure_ns.to_le_bytes());
    p.extend_from_slice(&f.received_ns.to_le_bytes());
    p.extend_from_slice(&transmit_ns.to_le_bytes());
    // Precision timestamp: seconds and fraction (1/2³² s) of the exposure.
    let secs = (f.exposure_ns / 1_000_000_000) as u32;
    let frac = (((f.exposure_ns % 1_000_000_000) << 32) / 1_000_000_000) as u32;
    p.extend_from_slice(&secs.to_le_bytes());
    p.extend_from_slice(&frac.to_le_bytes());
    // Params (not recording; bit 1 while the bodies changed lately, so clients ask for the
    // model definitions again): the last field OptiTrack's client reads.
    put_u16(&mut p, if models_changed { MODELS_CHANGED } else { 0 });
    p
}

/// Quaternion of a rotation in the consumer's frame, x y z w (tests).
pub fn consumer_quat(frame: &ConsumerFrame, q: &UnitQuaternion<f64>) -> [f64; 4] {
    let c = frame.rotation(q);
    [c.i, c.j, c.k, c.w]
}

/// The server: its command socket, the socket frames leave from, its unicast clients.
pub struct NatNetServer {
    cfg: NatNetConfig,
    command: UdpSocket,
    data: UdpSocket,
    bodies: Vec<BodyDef>,
    /// Until when frames say the models changed (a second after the bodies last did).
    models_changed_until: Option<std::time::Instant>,
    /// Unicast clients: where they sent from, and when last heard (poll count).
    clients: Vec<(SocketAddr, u64)>,
    heard: u64,
    last_frame: Option<Vec<u8>>,
    counts: Counts,
}

impl std::fmt::Debug for NatNetServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "NatNetServer({})", self.cfg.command)
    }
}

impl NatNetServer {
    pub fn bind(cfg: NatNetConfig, bodies: Vec<BodyDef>) -> std::io::Result<NatNetServer> {
        let command = UdpSocket::bind(cfg.command)?;
        command.set_nonblocking(true)?;
        let ip = match cfg.command.ip() {
            IpAddr::V4(ip) => ip,
            IpAddr::V6(_) => {
                return Err(std::io::Error::new(
                    ErrorKind::InvalidInput,
                    "NatNet is IPv4 only",
                ));
            }
        };
        let data = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))?;
        data.bind(&SocketAddr::V4(SocketAddrV4::new(ip, 0)).into())?;
        if cfg.multicast.is_some() {
            if !ip.is_unspecified() {
                data.set_multicast_if_v4(&ip)?;
            }
            data.set_multicast_loop_v4(true)?;
            data.set_multicast_ttl_v4(1)?;
        }
        data.set_nonblocking(true)?;
        Ok(NatNetServer {
            cfg,
            command,
            data: data.into(),
            bodies,
            models_changed_until: None,
            clients: Vec::new(),
            heard: 0,
            last_frame: None,
            counts: Counts::default(),
        })
    }

    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.command.local_addr()
    }

    fn reply(&mut self, id: u16, payload: &[u8], to: SocketAddr) {
        if let Some(p) = packet(id, payload)
            && let Err(e) = self.command.send_to(&p, to)
        {
            self.counts.error(format!("NatNet reply to {to}: {e}"));
        }
    }

    fn remember(&mut self, from: SocketAddr) {
        self.heard += 1;
        if let Some(c) = self.clients.iter_mut().find(|c| c.0 == from) {
            c.1 = self.heard;
            return;
        }
        if self.clients.len() >= MAX_UNICAST_CLIENTS
            && let Some(oldest) = (0..self.clients.len()).min_by_key(|&i| self.clients[i].1)
        {
            let (gone, _) = self.clients.remove(oldest);
            self.counts.drop(
                "displaced",
                format!("NatNet unicast client {gone} displaced"),
            );
        }
        tracing::info!("NatNet client {from} connected");
        self.clients.push((from, self.heard));
    }

    fn handle(&mut self, d: &[u8], from: SocketAddr) {
        let (id, n) = match d {
            [a, b, c, e, ..] => (u16::from_le_bytes([*a, *b]), u16::from_le_bytes([*c, *e])),
            _ => {
                self.counts.drop(
                    "garbage",
                    format!(
                        "NatNet: a {}-byte datagram from {from}, shorter than a header",
                        d.len()
                    ),
                );
                return;
            }
        };
        let payload = &d[4..];
        // The stated length may be shorter (clients pad) but never longer than what came.
        if usize::from(n) > payload.len() {
            self.counts.drop(
                "garbage",
                format!(
                    "NatNet: message {id} from {from} states {n} bytes and carries {}",
                    payload.len()
                ),
            );
            self.reply(NAT_UNRECOGNIZED_REQUEST, &[], from);
            return;
        }
        let payload = &payload[..usize::from(n)];
        match id {
            NAT_CONNECT => {
                if self.cfg.multicast.is_none() {
                    self.remember(from);
                }
                let info = server_info(self.cfg.data_port, self.cfg.multicast);
                self.reply(NAT_SERVERINFO, &info, from);
            }
            NAT_KEEPALIVE => {
                if self.cfg.multicast.is_none() {
                    self.remember(from);
                }
            }
            NAT_DISCONNECT => {
                self.clients.retain(|c| c.0 != from);
            }
            NAT_REQUEST_MODELDEF => {
                let defs = model_definitions(&self.bodies, &self.cfg.frame);
                if defs.len() > MAX_PAYLOAD {
                    self.counts.error(format!(
                        "NatNet: the model definitions take {} bytes, over a packet's {MAX_PAYLOAD}",
                        defs.len()
                    ));
                } else {
                    self.reply(NAT_MODELDEF, &defs, from);
                }
            }
            NAT_REQUEST_FRAMEOFDATA => {
                if let Some(f) = self.last_frame.clone() {
                    if let Err(e) = self.command.send_to(&f, from) {
                        self.counts.error(format!("NatNet reply to {from}: {e}"));
                    }
                } else {
                    self.reply(NAT_UNRECOGNIZED_REQUEST, &[], from);
                }
            }
            NAT_REQUEST => {
                let text = payload.split(|b| *b == 0).next().unwrap_or(&[]);
                let text = String::from_utf8_lossy(text);
                if text.eq_ignore_ascii_case("Bitstream") {
                    let v = NATNET_VERSION;
                    let mut r =
                        format!("Bitstream,{}.{}.{}.{}", v[0], v[1], v[2], v[3]).into_bytes();
                    r.push(0);
                    self.reply(NAT_RESPONSE, &r, from);
                } else {
                    self.counts.drop(
                        "unknown_request",
                        format!(
                            "NatNet: {from} asked {:?}, which this server does not do",
                            text.chars().take(64).collect::<String>()
                        ),
                    );
                    self.reply(NAT_UNRECOGNIZED_REQUEST, &[], from);
                }
            }
            other => {
                self.counts.drop(
                    "garbage",
                    format!("NatNet: message id {other} from {from} is not a request"),
                );
                self.reply(NAT_UNRECOGNIZED_REQUEST, &[], from);
            }
        }
    }

    fn send_data(&mut self, bytes: &[u8]) {
        let mut targets: Vec<SocketAddr> = Vec::new();
        match self.cfg.multicast {
            Some(g) => targets.push(SocketAddr::from((g, self.cfg.data_port))),
            None => {
                for (a, _) in &self.clients {
                    targets.push(*a);
                    let d = SocketAddr::new(a.ip(), self.cfg.data_port);
                    if d != *a {
                        targets.push(d);
                    }
                }
            }
        }
        for to in targets {
            let r = if self.cfg.multicast.is_some() {
                self.data.send_to(bytes, to)
            } else {
                self.command.send_to(bytes, to)
            };
            if let Err(e) = r {
                self.counts.send_error(format!("NatNet frame to {to}: {e}"));
            }
        }
    }
}

impl Output for NatNetServer {
    fn name(&self) -> &'static str {
        "natnet"
    }

    fn poll(&mut self) {
        let mut buf = [0u8; 2048];
        // Bounded per poll so a flood cannot starve the frames.
        for _ in 0..256 {
            match self.command.recv_from(&mut buf) {
                Ok((n, from)) => {
                    let d = buf[..n].to_vec();
                    self.handle(&d, from);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                // A previous reply's ICMP error surfaces here: not this datagram's fault.
                Err(_) => continue,
            }
        }
    }

    fn send(&mut self, f: &OutputFrame) {
        let transmit_ns = stereoscope_proto::messages::now_ns();
        let changed = self
            .models_changed_until
            .is_some_and(|t| std::time::Instant::now() < t);
        let payload = frame_of_data(f, &self.bodies, &self.cfg.frame, transmit_ns, changed);
        let Some(bytes) = packet(NAT_FRAMEOFDATA, &payload) else {
            self.counts.error(format!(
                "NatNet: frame {} takes {} bytes, over a packet's {MAX_PAYLOAD}; not sent",
                f.sequence,
                payload.len()
            ));
            return;
        };
        self.send_data(&bytes);
        self.counts.frames += 1;
        self.last_frame = Some(bytes);
    }

    fn counts(&mut self) -> &mut Counts {
        &mut self.counts
    }

    /// In place: the definitions clients ask for are the new ones, and for a second every
    /// frame's params say the models changed (a client may miss a datagram).
    fn set_bodies(&mut self, bodies: &[BodyDef]) -> bool {
        self.bodies = bodies.to_vec();
        self.models_changed_until = Some(std::time::Instant::now() + MODELS_CHANGED_FOR);
        true
    }

    fn clients(&self) -> Option<usize> {
        Some(self.clients.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::{OutputBody, OutputMarker};
    use nalgebra::{Isometry3, Translation3, Vector3};

    fn body() -> Vec<BodyDef> {
        vec![BodyDef {
            name: "head".into(),
            markers_m: vec![
                Point3::new(0.05, 0.0, 0.0),
                Point3::new(0.0, 0.05, 0.0),
                Point3::new(0.0, 0.0, 0.05),
            ],
        }]
    }

    /// Reads a frame back as libmotioncapture's decoder walks it (section by section, byte
    /// counts honoured) and checks the body and the length.
    #[test]
    fn a_frame_walks_as_clients_walk_it() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5),
        );
        let bodies = [OutputBody {
            index: 0,
            world_from_body: pose,
            residual_mm: 0.4,
            tracked: true,
            velocity_m_per_s: [0.0; 3],
            angular_velocity_rad_per_s: [0.0; 3],
        }];
        let markers = [OutputMarker {
            position_m: Point3::new(0.15, 0.2, 0.3),
            label: Some((0, 0)),
            object_id: 4,
        }];
        let f = OutputFrame {
            sequence: 77,
            exposure_ns: 1_700_000_000_250_000_000,
            received_ns: 1_700_000_000_251_000_000,
            bodies: &bodies,
            markers: &markers,
            models: &[],
        };
        let frame = ConsumerFrame::y_up();
        let p = frame_of_data(&f, &body(), &frame, 1_700_000_000_252_000_000, false);
        let i32_at = |at: usize| i32::from_le_bytes(p[at..at + 4].try_into().unwrap());
        let f32_at = |at: usize| f32::from_le_bytes(p[at..at + 4].try_into().unwrap());
        assert_eq!(i32_at(0), 77);
        let mut at = 4;
        // Marker sets: count, size, then skip by size.
        assert_eq!(i32_at(at), 1);
        let size = i32_at(at + 4) as usize;
        assert_eq!(&p[at + 8..at + 13], b"head\0");
        at += 8 + size;
        assert_eq!((i32_at(at), i32_at(at + 4)), (0, 0));
        at += 8;
        assert_eq!((i32_at(at), i32_at(at + 4)), (1, 38));
        at += 8;
        assert_eq!(i32_at(at), 1);
        // Y-up: world (0.1, 0.2, 0.3) is (0.1, 0.3, −0.2).
        let got = [f32_at(at + 4), f32_at(at + 8), f32_at(at + 12)];
        assert!((got[0] - 0.1).abs() < 1e-6 && (got[1] - 0.3).abs() < 1e-6);
        assert!((got[2] + 0.2).abs() < 1e-6, "{got:?}");
        at += 38;
        for _ in 0..2 {
            assert_eq!((i32_at(at), i32_at(at + 4)), (0, 0));
            at += 8;
        }
        assert_eq!((i32_at(at), i32_at(at + 4)), (1, 26));
        assert_eq!(i32_at(at + 8), (1 << 16) | 1);
        at += 8 + 26;
        for _ in 0..2 {
            assert_eq!((i32_at(at), i32_at(at + 4)), (0, 0));
            at += 8;
        }
        at += 8; // timecode
        let t = f64::from_le_bytes(p[at..at + 8].try_into().unwrap());
        assert!((t - 1_700_000_000.25).abs() < 1e-6);
        let stamp =
            |k: usize| u64::from_le_bytes(p[at + 8 + 8 * k..at + 16 + 8 * k].try_into().unwrap());
        assert_eq!(stamp(0), f.exposure_ns);
        assert_eq!(stamp(1), f.received_ns);
        assert_eq!(stamp(2), 1_700_000_000_252_000_000);
        at += 32;
        assert_eq!(i32_at(at), 1_700_000_000);
        // A quarter second is 2³⁰ in 1/2³² s.
        assert_eq!(i32_at(at + 4), 1 << 30);
        assert_eq!(p.len(), at + 8 + 2);
        assert_eq!(&p[at + 8..], &[0, 0]);
        // After a change of the bodies, the params say so.
        let changed = frame_of_data(&f, &body(), &frame, 1_700_000_000_252_000_000, true);
        assert_eq!(&changed[at + 8..], &[MODELS_CHANGED as u8, 0]);
    }

    #[test]
    fn server_info_has_the_layout_clients_read() {
        let p = server_info(1511, Some(Ipv4Addr::new(239, 255, 42, 99)));
        assert_eq!(p.len(), 256 + 4 + 4 + 8 + 2 + 1 + 4);
        assert!(p.starts_with(b"Stereoscope\0"));
        assert_eq!(&p[260..264], &NATNET_VERSION);
        assert_eq!(
            u64::from_le_bytes(p[264..272].try_into().unwrap()),
            CLOCK_HZ
        );
        assert_eq!(u16::from_le_bytes([p[272], p[273]]), 1511);
        assert_eq!(p[274], 1);
        assert_eq!(&p[275..279], &[239, 255, 42, 99]);
    }

    #[test]
    fn model_definitions_carry_names_and_byte_counts() {
        let p = model_definitions(&body(), &ConsumerFrame::identity());
        let i32_at = |at: usize| i32::from_le_bytes(p[at..at + 4].try_into().unwrap());
        assert_eq!(i32_at(0), 2);
        assert_eq!(i32_at(4), 0);
        let size = i32_at(8) as usize;
        let rb = 12 + size;
        assert_eq!(i32_at(rb), 1);
        let d = &p[rb + 8..];
        assert_eq!(d.len(), i32_at(rb + 4) as usize);
        assert!(d.starts_with(b"head\0"));
        // id 1, parent −1.
        assert_eq!(i32::from_le_bytes(d[5..9].try_into().unwrap()), 1);
        assert_eq!(i32::from_le_bytes(d[9..13].try_into().unwrap()), -1);
        assert!(d.ends_with(b"head_1\0head_2\0head_3\0"));
    }

    #[test]
    fn bad_requests_are_counted_and_answered_once() {
        let cfg = NatNetConfig {
            command: "127.0.0.1:0".parse().unwrap(),
            data_port: 0,
            multicast: None,
            frame: ConsumerFrame::identity(),
        };
        let mut s = NatNetServer::bind(cfg, body()).unwrap();
        let at = s.local_addr().unwrap();
        let peer = UdpSocket::bind("127.0.0.1:0").unwrap();
        peer.set_read_timeout(Some(std::time::Duration::from_secs(2)))
            .unwrap();
        for d in [&[1u8][..], &[7, 0, 200, 0, 1, 2], &[55, 0, 0, 0]] {
            peer.send_to(d, at).unwrap();
        }
        peer.send_to(&packet(NAT_CONNECT, &[]).unwrap(), at)
            .unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(2);
        let mut replies = Vec::new();
        let mut buf = [0u8; 2048];
        while replies.len() < 3 && std::time::Instant::now() < deadline {
            s.poll();
            peer.set_nonblocking(true).unwrap();
            while let Ok((n, _)) = peer.recv_from(&mut buf) {
                replies.push(u16::from_le_bytes([buf[0], buf[1]]));
                assert!(n >= 4);
            }
        }
        assert_eq!(
            replies,
            vec![
                NAT_UNRECOGNIZED_REQUEST,
                NAT_UNRECOGNIZED_REQUEST,
                NAT_SERVERINFO
            ]
        );
        assert_eq!(s.counts.dropped.len(), 3, "{:?}", s.counts.dropped);
        assert_eq!(s.clients(), Some(1));
    }
}
