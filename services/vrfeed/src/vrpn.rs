//! A VRPN tracker server (`docs/vr.md`, "VRPN"), written from the protocol as the reference
//! implementation (vrpn/vrpn, `vrpn_Connection.C`, `vrpn_Tracker.C`) speaks it; no maintained
//! Rust crate exists.
//!
//! *Connecting.* A client reaches the server in one of two ways, both served: it connects over
//! TCP to the server's port (`tcp://host:3883`), or (the default of `vrpn_get_connection_by_name`)
//! it sends a UDP datagram to that port, `"<its address> <its TCP port>\0"`, and the server
//! connects back to it. Either way each side then sends a 24-byte cookie,
//! `"vrpn: ver. 07.38  0"` padded with zeros; the major version (through the last '.') must
//! match.
//!
//! *Messages.* Each is a header of six big-endian u32 — total length without padding
//! (24 + payload), time seconds, time microseconds, sender id, type id, sequence number — then
//! the payload padded with zeros to a multiple of 8. Negative types are the connection's own:
//! −1 describes a sender and −2 a type (sender field = its id; payload = name length
//! including its NUL as a big-endian u32, then the name and NUL), −3 the client's UDP port, −4
//! logging, −5 disconnect. Each side announces its senders and types after the cookies; ids are
//! per side, mapped by name.
//!
//! *Trackers.* Each body is a sender named after it (as OptiTrack Motive and Vicon Tracker
//! name theirs), sensor 0. `vrpn_Tracker Pos_Quat`: sensor (i32), padding (i32), position
//! x, y, z, quaternion x, y, z, w (f64, big-endian): 64 bytes. `vrpn_Tracker Velocity`: sensor,
//! padding, velocity x, y, z, the rotation over `vel_quat_dt` as a quaternion x, y, z, w, then
//! `vel_quat_dt` (f64): 72 bytes. Every message goes over TCP (the reference sends reports
//! over UDP when the client offers a port; TCP is what it falls back to, and what a client
//! behind a firewall gets). A `vrpn_Base ping_message` is answered with a
//! `vrpn_Base pong_message` from the same sender, so clients do not warn of a silent server.
//!
//! *Bad peers.* A client that sends garbage, a wrong cookie, a message longer than
//! [`MAX_MESSAGE_BYTES`], or does not read what it is sent (its backlog over
//! [`MAX_BACKLOG_BYTES`]) is disconnected and counted; the server and every other client go on.

use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::time::Duration;

/// The cookie this server sends (version 07.38, remote logging off).
pub const COOKIE: &[u8] = b"vrpn: ver. 07.38  0";
/// Cookie length on the wire.
pub const COOKIE_BYTES: usize = 24;
/// What a peer's cookie must start with (the major version).
const COOKIE_MAJOR: &[u8] = b"vrpn: ver. 07.";
const HEADER_BYTES: usize = 24;
/// Longest message accepted from a client (the reference's buffers are 64 KiB).
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;
/// Unsent bytes a client may fall behind by before it is dropped.
pub const MAX_BACKLOG_BYTES: usize = 1 << 20;
/// Most clients at once.
pub const MAX_CLIENTS: usize = 32;
/// Longest sender or type name (the reference's `cName` holds 100 bytes).
const MAX_NAME_BYTES: usize = 100;

const SENDER_DESCRIPTION: i32 = -1;
const TYPE_DESCRIPTION: i32 = -2;
const DISCONNECT: i32 = -5;

/// This server's message types, by their ids.
pub const TYPES: [&str; 3] = [
    "vrpn_Tracker Pos_Quat",
    "vrpn_Tracker Velocity",
    "vrpn_Base pong_message",
];
const POS_QUAT: i32 = 0;
const VELOCITY: i32 = 1;
const PONG: i32 = 2;
const PING_NAME: &str = "vrpn_Base ping_message";

/// The time a message carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stamp {
    pub sec: u32,
    pub usec: u32,
}

impl Stamp {
    pub fn from_ns(ns: u64) -> Stamp {
        Stamp {
            sec: (ns / 1_000_000_000) as u32,
            usec: ((ns % 1_000_000_000) / 1000) as u32,
        }
    }
}

/// One message, framed: header, payload, zero padding to 8 bytes.
pub fn frame(sender: i32, kind: i32, stamp: Stamp, sequence: u32, payload: &[u8]) -> Vec<u8> {
    let padded = payload.len().div_ceil(8) * 8;
    let mut out = Vec::with_capacity(HEADER_BYTES + padded);
    for v in [
        (HEADER_BYTES + payload.len()) as u32,
        stamp.sec,
        stamp.usec,
        sender as u32,
        kind as u32,
        sequence,
    ] {
        out.extend_from_slice(&v.to_be_bytes());
    }
    out.extend_from_slice(payload);
    out.resize(HEADER_BYTES + padded, 0);
    out
}

/// A name description's payload: length with NUL (big-endian u32), name, NUL.
pub fn name_payload(name: &str) -> Vec<u8> {
    let mut p = ((name.len() + 1) as u32).to_be_bytes().to_vec();
    p.extend_from_slice(name.as_bytes());
    p.push(0);
    p
}

/// The cookie as sent: [`COOKIE`] padded with zeros to [`COOKIE_BYTES`].
pub fn cookie() -> [u8; COOKIE_BYTES] {
    let mut c = [0u8; COOKIE_BYTES];
    c[..COOKIE.len()].copy_from_slice(COOKIE);
    c
}

/// `vrpn_Tracker Pos_Quat` payload for sensor 0.
pub fn pos_quat(position: [f64; 3], quat_xyzw: [f64; 4]) -> Vec<u8> {
    let mut p = Vec::with_capacity(64);
    p.extend_from_slice(&0i32.to_be_bytes());
    p.extend_from_slice(&0i32.to_be_bytes());
    for v in position.iter().chain(&quat_xyzw) {
        p.extend_from_slice(&v.to_be_bytes());
    }
    p
}

/// `vrpn_Tracker Velocity` payload for sensor 0.
pub fn velocity(velocity: [f64; 3], vel_quat_xyzw: [f64; 4], vel_quat_dt_s: f64) -> Vec<u8> {
    let mut p = Vec::with_capacity(72);
    p.extend_from_slice(&0i32.to_be_bytes());
    p.extend_from_slice(&0i32.to_be_bytes());
    for v in velocity
        .iter()
        .chain(&vel_quat_xyzw)
        .chain([&vel_quat_dt_s])
    {
        p.extend_from_slice(&v.to_be_bytes());
    }
    p
}

/// Why a client was disconnected (counted by reason).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drop {
    /// It closed the connection (or said it would).
    Closed,
    /// Its cookie was not a VRPN 07 cookie.
    Cookie,
    /// A message that cannot be VRPN: a length below the header or over the limit, a name too
    /// long.
    Garbage,
    /// It did not read what it was sent.
    Slow,
    /// The socket failed.
    Io,
    /// No cookie within [`COOKIE_WAIT`] of connecting.
    NoCookie,
}

/// How long a new client has to send its cookie.
pub const COOKIE_WAIT: Duration = Duration::from_secs(5);

impl Drop {
    pub fn reason(self) -> &'static str {
        match self {
            Drop::Closed => "closed",
            Drop::Cookie => "bad_cookie",
            Drop::Garbage => "garbage",
            Drop::Slow => "slow_client",
            Drop::Io => "io",
            Drop::NoCookie => "no_cookie",
        }
    }

    /// What happened, for the log and health.
    pub fn describe(self) -> &'static str {
        match self {
            Drop::Closed => "disconnected",
            Drop::Cookie => "sent something other than a VRPN 07 cookie; dropped",
            Drop::Garbage => {
                "sent a message that is not VRPN (length or name out of bounds); dropped"
            }
            Drop::Slow => "fell more than 1 MiB behind; dropped",
            Drop::Io => "socket error; dropped",
            Drop::NoCookie => "sent no cookie within 5 s; dropped",
        }
    }
}

struct Client {
    peer: SocketAddr,
    stream: TcpStream,
    /// Bytes read not yet handled.
    inbuf: Vec<u8>,
    /// Bytes to send that the socket has not taken yet.
    outbuf: Vec<u8>,
    cookie_ok: bool,
    connected: std::time::Instant,
    sequence: u32,
    /// The client's type names by its ids (non-negative ones only).
    types: Vec<(i32, String)>,
    /// The client's sender names by its ids.
    senders: Vec<(i32, String)>,
}

impl Client {
    fn new(stream: TcpStream, peer: SocketAddr, senders: &[String]) -> std::io::Result<Client> {
        stream.set_nodelay(true)?;
        stream.set_nonblocking(true)?;
        let mut c = Client {
            peer,
            stream,
            inbuf: Vec::new(),
            outbuf: cookie().to_vec(),
            cookie_ok: false,
            connected: std::time::Instant::now(),
            sequence: 0,
            types: Vec::new(),
            senders: Vec::new(),
        };
        // Our senders and types follow the cookie (the peer reads them once it has checked it).
        let now = Stamp::from_ns(stereoscope_proto::messages::now_ns());
        for (i, name) in senders.iter().enumerate() {
            c.queue(i as i32, SENDER_DESCRIPTION, now, &name_payload(name));
        }
        for (i, name) in TYPES.iter().enumerate() {
            c.queue(i as i32, TYPE_DESCRIPTION, now, &name_payload(name));
        }
        Ok(c)
    }

    fn queue(&mut self, sender: i32, kind: i32, stamp: Stamp, payload: &[u8]) {
        let m = frame(sender, kind, stamp, self.sequence, payload);
        self.sequence = self.sequence.wrapping_add(1);
        self.outbuf.extend_from_slice(&m);
    }

    /// Sends what the socket takes now.
    fn flush(&mut self) -> Result<(), Drop> {
        while !self.outbuf.is_empty() {
            match self.stream.write(&self.outbuf) {
                Ok(0) => return Err(Drop::Closed),
                Ok(n) => {
                    self.outbuf.drain(..n);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => return Err(Drop::Io),
            }
        }
        if self.outbuf.len() > MAX_BACKLOG_BYTES {
            return Err(Drop::Slow);
        }
        Ok(())
    }

    /// Reads what has arrived and handles every whole message in it.
    fn receive(&mut self, our_senders: &[String]) -> Result<(), Drop> {
        let mut buf = [0u8; 16 * 1024];
        loop {
            match self.stream.read(&mut buf) {
                Ok(0) => return Err(Drop::Closed),
                Ok(n) => {
                    self.inbuf.extend_from_slice(&buf[..n]);
                    // Never hold more than one largest message and a read.
                    if self.inbuf.len() > MAX_MESSAGE_BYTES + buf.len() + COOKIE_BYTES {
                        self.handle(our_senders)?;
                        if self.inbuf.len() > MAX_MESSAGE_BYTES + buf.len() + COOKIE_BYTES {
                            return Err(Drop::Garbage);
                        }
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(_) => return Err(Drop::Io),
            }
        }
        self.handle(our_senders)
    }

    fn handle(&mut self, our_senders: &[String]) -> Result<(), Drop> {
        if !self.cookie_ok {
            // Refused as soon as what came cannot begin a cookie.
            let n = self.inbuf.len().min(COOKIE_MAJOR.len());
            if self.inbuf[..n] != COOKIE_MAJOR[..n] {
                return Err(Drop::Cookie);
            }
            if self.inbuf.len() < COOKIE_BYTES {
                if self.connected.elapsed() > COOKIE_WAIT {
                    return Err(Drop::NoCookie);
                }
                return Ok(());
            }
            self.inbuf.drain(..COOKIE_BYTES);
            self.cookie_ok = true;
        }
        let mut at = 0;
        while self.inbuf.len() - at >= HEADER_BYTES {
            let word = |i: usize| {
                let b = &self.inbuf[at + 4 * i..at + 4 * i + 4];
                u32::from_be_bytes([b[0], b[1], b[2], b[3]])
            };
            let len = word(0) as usize;
            if !(HEADER_BYTES..=MAX_MESSAGE_BYTES).contains(&len) {
                return Err(Drop::Garbage);
            }
            let whole = HEADER_BYTES + (len - HEADER_BYTES).div_ceil(8) * 8;
            if self.inbuf.len() - at < whole {
                break;
            }
            let (sender, kind) = (word(3) as i32, word(4) as i32);
            let payload = self.inbuf[at + HEADER_BYTES..at + len].to_vec();
            at += whole;
            match kind {
                SENDER_DESCRIPTION | TYPE_DESCRIPTION => {
                    let name = described_name(&payload).ok_or(Drop::Garbage)?;
                    let table = if kind == SENDER_DESCRIPTION {
                        &mut self.senders
                    } else {
                        &mut self.types
                    };
                    table.retain(|(id, _)| *id != sender);
                    // Bounded: a client may describe at most as many as the reference allows.
                    if table.len() >= 2000 {
                        return Err(Drop::Garbage);
                    }
                    table.push((sender, name));
                }
                DISCONNECT => return Err(Drop::Closed),
                k if k < 0 => {}
                k => {
                    let is_ping = self.types.iter().any(|(id, n)| *id == k && n == PING_NAME);
                    let ours = self
                        .senders
                        .iter()
                        .find(|(id, _)| *id == sender)
                        .and_then(|(_, n)| our_senders.iter().position(|s| s == n));
                    if let (true, Some(s)) = (is_ping, ours) {
                        let now = Stamp::from_ns(stereoscope_proto::messages::now_ns());
                        self.queue(s as i32, PONG, now, &[]);
                    }
                }
            }
        }
        self.inbuf.drain(..at);
        Ok(())
    }
}

/// A description's name: a big-endian length including the NUL, then the name.
fn described_name(payload: &[u8]) -> Option<String> {
    let n = u32::from_be_bytes(payload.get(..4)?.try_into().ok()?) as usize;
    if n == 0 || n > MAX_NAME_BYTES {
        return None;
    }
    let bytes = payload.get(4..4 + n)?;
    let name = bytes.strip_suffix(&[0]).unwrap_or(bytes);
    Some(String::from_utf8_lossy(name).into_owned())
}

/// The server: its listening sockets, its senders (one per body) and its clients.
pub struct Server {
    tcp: TcpListener,
    udp: UdpSocket,
    senders: Vec<String>,
    clients: Vec<Client>,
    /// Disconnections by reason, and refusals (too many clients, a connect-back that failed, a
    /// bad UDP request), for health.
    pub dropped: Vec<(&'static str, String)>,
}

impl std::fmt::Debug for Server {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "vrpn::Server({} clients)", self.clients.len())
    }
}

impl Server {
    /// Listens on `addr` (TCP and UDP); `senders` are the tracker names.
    pub fn bind(addr: SocketAddr, senders: Vec<String>) -> std::io::Result<Server> {
        let tcp = TcpListener::bind(addr)?;
        tcp.set_nonblocking(true)?;
        let udp = UdpSocket::bind(tcp.local_addr()?)?;
        udp.set_nonblocking(true)?;
        Ok(Server {
            tcp,
            udp,
            senders,
            clients: Vec::new(),
            dropped: Vec::new(),
        })
    }

    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.tcp.local_addr()
    }

    /// The trackers after a change of the rig's bodies: `senders` begins with the ones the
    /// server has (a sender's id never changes while it runs); the new ones are described to
    /// every connected client, as a VRPN server does when it registers a sender.
    pub fn set_senders(&mut self, senders: &[String]) {
        let known = self.senders.len();
        if senders.len() <= known || senders[..known] != self.senders[..] {
            return;
        }
        let now = Stamp::from_ns(stereoscope_proto::messages::now_ns());
        for (i, name) in senders.iter().enumerate().skip(known) {
            for c in &mut self.clients {
                c.queue(i as i32, SENDER_DESCRIPTION, now, &name_payload(name));
            }
        }
        self.senders = senders.to_vec();
    }

    pub fn clients(&self) -> usize {
        self.clients.iter().filter(|c| c.cookie_ok).count()
    }

    fn admit(&mut self, stream: TcpStream, peer: SocketAddr) {
        if self.clients.len() >= MAX_CLIENTS {
            self.dropped.push((
                "too_many_clients",
                format!("VRPN client {peer} refused: {MAX_CLIENTS} already"),
            ));
            return;
        }
        match Client::new(stream, peer, &self.senders) {
            Ok(c) => {
                tracing::info!("VRPN client {peer} connected");
                self.clients.push(c);
            }
            Err(e) => self
                .dropped
                .push(("io", format!("VRPN client {peer}: {e}"))),
        }
    }

    /// Accepts new clients (direct, and by a UDP request to connect back), reads from every
    /// client, sends what is pending, and drops the ones that misbehaved.
    pub fn poll(&mut self) {
        loop {
            match self.tcp.accept() {
                Ok((s, peer)) => self.admit(s, peer),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) => {
                    self.dropped.push(("io", format!("VRPN accept: {e}")));
                    break;
                }
            }
        }
        let mut buf = [0u8; 1500];
        loop {
            match self.udp.recv_from(&mut buf) {
                Ok((n, from)) => match connect_back_address(&buf[..n], from) {
                    Some(to) => match TcpStream::connect_timeout(&to, Duration::from_millis(500)) {
                        Ok(s) => self.admit(s, to),
                        Err(e) => self
                            .dropped
                            .push(("connect_back", format!("VRPN client {to} (asked by {from}): {e}"))),
                    },
                    None => self.dropped.push((
                        "garbage",
                        format!("VRPN: a {n}-byte UDP datagram from {from} that is not a connection request"),
                    )),
                },
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(_) => break,
            }
        }
        let senders = &self.senders;
        let dropped = &mut self.dropped;
        self.clients
            .retain_mut(|c| match c.receive(senders).and_then(|_| c.flush()) {
                Ok(()) => true,
                Err(d) => {
                    tracing::info!("VRPN client {} {}", c.peer, d.describe());
                    dropped.push((
                        d.reason(),
                        format!("VRPN client {} {}", c.peer, d.describe()),
                    ));
                    false
                }
            });
    }

    /// Sends sender `index`'s pose (and velocity) to every client past its cookie.
    pub fn send(
        &mut self,
        index: usize,
        stamp: Stamp,
        position: [f64; 3],
        quat_xyzw: [f64; 4],
        vel: Option<([f64; 3], [f64; 4], f64)>,
    ) {
        let pq = pos_quat(position, quat_xyzw);
        let v = vel.map(|(v, q, dt)| velocity(v, q, dt));
        for c in self.clients.iter_mut().filter(|c| c.cookie_ok) {
            c.queue(index as i32, POS_QUAT, stamp, &pq);
            if let Some(v) = &v {
                c.queue(index as i32, VELOCITY, stamp, v);
            }
        }
    }

    /// Sends every client's pending bytes (after [`Server::send`]); drops failed ones.
    pub fn flush(&mut self) {
        let dropped = &mut self.dropped;
        self.clients.retain_mut(|c| match c.flush() {
            Ok(()) => true,
            Err(d) => {
                dropped.push((
                    d.reason(),
                    format!("VRPN client {} {}", c.peer, d.describe()),
                ));
                false
            }
        });
    }
}

/// The address a UDP connection request asks to be called back at: `"<host> <port>\0"` from
/// `from`. The host must be `from`'s own address (a request may not aim the server at a third
/// party); a name other than an address is taken as `from`'s.
pub fn connect_back_address(datagram: &[u8], from: SocketAddr) -> Option<SocketAddr> {
    let text = datagram.split(|b| *b == 0).next()?;
    let text = std::str::from_utf8(text).ok()?;
    let mut parts = text.split_whitespace();
    let host = parts.next()?;
    let port: u16 = parts.next()?.parse().ok()?;
    if parts.next().is_some() || port == 0 {
        return None;
    }
    match host.parse::<std::net::IpAddr>() {
        Ok(ip) if ip != from.ip() => None,
        _ => Some(SocketAddr::new(from.ip(), port)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_framed_as_the_reference_does() {
        let m = frame(3, -1, Stamp { sec: 7, usec: 9 }, 42, &name_payload("head"));
        // 24-byte header + 4 + 5 = 33 bytes of message, padded to 40.
        assert_eq!(m.len(), 24 + 16);
        assert_eq!(&m[0..4], &33u32.to_be_bytes());
        assert_eq!(&m[12..16], &3u32.to_be_bytes());
        assert_eq!(&m[16..20], &(-1i32 as u32).to_be_bytes());
        assert_eq!(&m[20..24], &42u32.to_be_bytes());
        assert_eq!(&m[24..28], &5u32.to_be_bytes());
        assert_eq!(&m[28..33], b"head\0");
        assert!(m[33..].iter().all(|b| *b == 0));
        assert_eq!(pos_quat([0.0; 3], [0.0, 0.0, 0.0, 1.0]).len(), 64);
        assert_eq!(velocity([0.0; 3], [0.0, 0.0, 0.0, 1.0], 0.01).len(), 72);
        assert_eq!(&cookie()[..19], b"vrpn: ver. 07.38  0");
        assert_eq!(
            described_name(&name_payload("head")).as_deref(),
            Some("head")
        );
        assert_eq!(described_name(&[0, 0, 0x10, 0, b'a']), None);
    }

    #[test]
    fn connect_back_requests_are_checked() {
        let from: SocketAddr = "127.0.0.1:5555".parse().unwrap();
        assert_eq!(
            connect_back_address(b"127.0.0.1 40001\0", from),
            Some("127.0.0.1:40001".parse().unwrap())
        );
        assert_eq!(
            connect_back_address(b"myhost 40001\0", from),
            Some("127.0.0.1:40001".parse().unwrap())
        );
        // Aimed at someone else, or not a request.
        assert_eq!(connect_back_address(b"10.0.0.9 40001\0", from), None);
        assert_eq!(connect_back_address(b"127.0.0.1 0\0", from), None);
        assert_eq!(connect_back_address(b"\xff\xfe", from), None);
        assert_eq!(connect_back_address(b"", from), None);
    }

    /// A raw TCP client: the cookie and descriptions arrive; garbage gets it dropped and
    /// counted while a second client carries on.
    #[test]
    fn a_garbage_client_is_dropped_and_others_go_on() {
        let mut s = Server::bind("127.0.0.1:0".parse().unwrap(), vec!["head".into()]).unwrap();
        let addr = s.local_addr().unwrap();
        let mut good = TcpStream::connect(addr).unwrap();
        let mut bad = TcpStream::connect(addr).unwrap();
        let poll_until = |s: &mut Server, n: usize| {
            for _ in 0..200 {
                s.poll();
                if s.clients.len() == n {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        };
        poll_until(&mut s, 2);
        good.write_all(&cookie()).unwrap();
        bad.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        poll_until(&mut s, 1);
        assert_eq!(s.clients.len(), 1);
        assert!(
            s.dropped.iter().any(|(r, _)| *r == "bad_cookie"),
            "{:?}",
            s.dropped
        );
        s.send(
            0,
            Stamp { sec: 1, usec: 2 },
            [1.0, 2.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
            None,
        );
        s.flush();
        good.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        // Cookie, the sender, three types (56 bytes each), then the pose.
        let mut got = vec![0u8; 24 + 40 + 3 * 56 + 88];
        good.read_exact(&mut got).unwrap();
        assert_eq!(&got[..19], COOKIE);
        let pose = &got[got.len() - 64..];
        assert_eq!(&pose[8..16], &1.0f64.to_be_bytes());
        assert_eq!(&pose[56..64], &1.0f64.to_be_bytes());
        // A message claiming 1 GB is garbage: dropped, not allocated.
        let mut huge = frame(0, 5, Stamp { sec: 0, usec: 0 }, 0, &[]);
        huge[0..4].copy_from_slice(&(1u32 << 30).to_be_bytes());
        good.write_all(&huge).unwrap();
        poll_until(&mut s, 0);
        assert!(
            s.dropped.iter().any(|(r, _)| *r == "garbage"),
            "{:?}",
            s.dropped
        );
    }
}
