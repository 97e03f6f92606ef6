//! The VR feed (`docs/vr.md`): one process that reads the pose stream — from shared memory
//! (iceoryx2, woken by fusion's notification) when fusion runs on its PC, else from Zenoh
//! `stereoscope/<rig>/poses` — and sends each rigid body to what the rig's `[vr]` section names:
//! a VRPN tracker server ([`vrpn`]), VirtualMotionTracker and VMC over OSC, and opentrack's UDP
//! packet ([`feeds`]), each in its consumer's frame (axes, origin, unit). A body's pose is
//! smoothed (One Euro) and predicted ahead when its `[[body]]` asks for it
//! (`stereoscope_bodies::filter`).
//!
//! *Latency.* For each pose frame the service notes the time from the newest camera frame's
//! publication (`frame_published_ns`) to the moment its VRPN bytes were handed to the sockets;
//! health reports the median and 99th percentile of the last 4096 (`latency_p50_us`,
//! `latency_p99_us`), and the log says them at exit.
//!
//! *Faults.* A frame that does not decode or is another rig's is counted and ignored; a UDP
//! receiver that is not there is a counted send error; a VRPN client that misbehaves is
//! dropped and counted ([`vrpn`]). None of it stops the feed.

pub mod bodies;
pub mod cli;
pub mod feeds;
mod labs;
pub mod lsl;
pub mod natnet;
pub mod output;
pub mod qualisys;
pub mod ros2;
pub mod vrpn;

use labs::{Defs, Lab, labs, nominal_fps};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::net::{SocketAddr, UdpSocket};
use std::time::Duration;
use stereoscope_bodies::filter::{PoseFilter, predict};
use stereoscope_proto::messages::{BodyPose, Detail, PoseFrame, now_ns};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_rig::vr::VrSettings;
use stereoscope_service::Context;
use stereoscope_transport::{Flow, Inlet, Service, ServiceNode, Shutdown, drive};

#[derive(Debug, Clone)]
pub struct VrFeedConfig {
    pub ctx: Context,
    /// Stop after this many pose frames (tests, benchmarks).
    pub max_frames: Option<u64>,
}

#[derive(Debug, thiserror::Error)]
pub enum VrFeedError {
    #[error("vrfeed: the rig has no [vr] section")]
    NoVr,
    #[error("vrfeed")]
    Rig(#[from] stereoscope_rig::RigError),
    #[error("vrfeed: VRPN cannot listen on {addr} (is another server using the port?)")]
    VrpnBind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("vrfeed: no UDP socket for the OSC and opentrack feeds")]
    Udp(#[source] std::io::Error),
    #[error("vrfeed")]
    Transport(#[from] stereoscope_transport::TransportError),
    #[error("vrfeed: {}: opening the trace file ({TRACE_ENV})", .path.display())]
    Trace {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// What the VR feed did: pose frames handled and the latency distribution, microseconds.
#[derive(Debug, Clone, Default)]
pub struct VrFeedSummary {
    pub frames: u64,
    pub latency_us: Vec<f64>,
}

/// Where pose frames come from: fusion's iceoryx2 outlet when fusion is on this PC (and the
/// event it notifies after each frame), its Zenoh key otherwise.
struct PoseInput {
    frames: Inlet<PoseFrame>,
    waker: Option<stereoscope_transport::iox::Waker>,
}

/// Latencies kept for the percentiles.
const LATENCY_WINDOW: usize = 4096;
/// The time `vrpn_Tracker Velocity`'s rotation is given over, seconds.
const VEL_QUAT_DT_S: f64 = 0.01;

/// Runs until shutdown (or `max_frames`).
pub fn run(cfg: VrFeedConfig, shutdown: Shutdown) -> Result<VrFeedSummary, VrFeedError> {
    drive(VrFeedService::setup(cfg)?, &shutdown)
}

pub struct VrFeedService {
    cfg: VrFeedConfig,
    node: ServiceNode,
    settings: VrSettings,
    /// The bodies by the index every protocol knows them by, and the models.
    defs: Defs,
    /// The running rig's bodies in its order: what `settings`' body indices count.
    rig_names: Vec<String>,
    /// The rig file, looked at for changed bodies and models.
    watch: Option<stereoscope_rig::watch::RigWatch>,
    reloads: u64,
    input: PoseInput,
    vrpn: Option<vrpn::Server>,
    next_bind: std::time::Instant,
    udp: UdpSocket,
    filters: Vec<Option<PoseFilter>>,
    /// The lab protocols the rig asks for (NatNet, Qualisys RT), each behind [`output::Output`].
    labs: Vec<Lab>,
    frames: u64,
    latency_us: std::collections::VecDeque<f64>,
    send_errors: u64,
    trace: Option<Trace>,
}

/// The environment variable naming a file the feed appends one JSON line to per pose frame
/// it sends (the latency bench joins it with what clients received: `benches/vr-latency.sh`).
pub const TRACE_ENV: &str = "STEREOSCOPE_VR_TRACE";

/// Per pose frame: its exposure (the oldest frame of its set), when its bytes began to go to
/// the sockets, each protocol's positions as sent (VRPN by body name, VMT by tracker index,
/// opentrack its one body) to match with what a client decodes, and each body's pose in the
/// world frame (name, measured in this frame, position, quaternion x y z w).
struct Trace {
    out: std::io::BufWriter<std::fs::File>,
    line: String,
}

impl Trace {
    fn open() -> Result<Option<Trace>, VrFeedError> {
        let Some(path) = std::env::var_os(TRACE_ENV) else {
            return Ok(None);
        };
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|source| VrFeedError::Trace {
                path: std::path::PathBuf::from(&path),
                source,
            })?;
        tracing::info!(
            "tracing what is sent to {}",
            std::path::Path::new(&path).display()
        );
        Ok(Some(Trace {
            out: std::io::BufWriter::new(file),
            line: String::new(),
        }))
    }
}

impl std::fmt::Debug for VrFeedService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "VrFeedService({} frames)", self.frames)
    }
}

/// A body's pose as a rotation and translation.
fn isometry(b: &BodyPose) -> Isometry3<f64> {
    let [x, y, z, w] = b.orientation_xyzw;
    Isometry3::from_parts(
        Translation3::from(Vector3::from(b.position_m)),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

impl VrFeedService {
    pub fn setup(cfg: VrFeedConfig) -> Result<Self, VrFeedError> {
        let ctx = &cfg.ctx;
        let settings = stereoscope_rig::vr::settings(&ctx.rig.spec)?.ok_or(VrFeedError::NoVr)?;
        let rig_names: Vec<String> = ctx.rig.spec.bodies.iter().map(|b| b.name.clone()).collect();
        let defs = Defs {
            bodies: bodies::BodyTable::new(&bodies::body_defs(&ctx.rig.spec)),
            model_trees: ctx
                .rig
                .models
                .iter()
                .map(|m| ros2::ModelTree::of(&m.model))
                .collect(),
        };
        let names = defs.bodies.names();
        if names.is_empty() && defs.model_trees.is_empty() {
            tracing::warn!(
                "the rig defines no [[body]] or [[model]] yet: the feed listens, and sends from the first one defined in the rig file"
            );
        }
        // A port in use is reported and tried again every second (`bind_vrpn`); any other
        // failure to listen (an address not of this PC) stops the service with its reason.
        let vrpn = match settings.vrpn {
            Some((addr, _)) => match vrpn::Server::bind(addr, names.clone()) {
                Ok(s) => Some(s),
                Err(e) if e.kind() == std::io::ErrorKind::AddrInUse => None,
                Err(source) => return Err(VrFeedError::VrpnBind { addr, source }),
            },
            None => None,
        };
        let destinations: Vec<SocketAddr> = [
            settings.vmt.as_ref().map(|v| v.0),
            settings.vmc.as_ref().map(|v| v.0),
            settings.opentrack.as_ref().map(|v| v.0),
        ]
        .into_iter()
        .flatten()
        .collect();
        let udp = UdpSocket::bind(udp_source(&destinations)).map_err(VrFeedError::Udp)?;
        udp.set_nonblocking(true).map_err(VrFeedError::Udp)?;
        let mut node = ServiceNode::start(stereoscope_transport::NodeSpec {
            exclusive: stereoscope_transport::Exclusive::Host,
            ..ctx.node_spec("vrfeed")
        })?;
        if let Some((addr, _)) = settings.vrpn {
            let state = if vrpn.is_some() {
                "listening"
            } else {
                "port in use"
            };
            node.counters.set(Detail::Vrpn, state);
            if vrpn.is_none() {
                node.counters.set_error(&format!(
                    "VRPN cannot listen on {addr}: the port is in use; trying again every second"
                ));
            }
        }
        // The lab protocols bind (ROS 2's session takes about half a second to open) before the
        // pose input exists, so no frame waits behind them.
        let mut labs = labs(&settings, nominal_fps(&ctx.rig.spec), &ctx.rig.name);
        for l in &mut labs {
            l.bind(&mut node.counters, &defs);
        }
        node.counters.set(Detail::Bodies, rig_names.join(","));
        let rig = ctx.rig.name.clone();
        let input = if ctx.fusion_here() {
            let name = stereoscope_proto::names::iox::poses(&rig);
            PoseInput {
                frames: Inlet::iox(&node.iox, &name, &rig, "pose frame")?,
                waker: Some(stereoscope_transport::iox::Waker::new(&node.iox, &name)?),
            }
        } else {
            PoseInput {
                frames: Inlet::zenoh(&node.session, &[keys::poses(&rig)], &rig, "pose frame", 64)?,
                waker: None,
            }
        };
        match (&vrpn, settings.vrpn) {
            (Some(s), _) => {
                if let Ok(a) = s.local_addr() {
                    tracing::info!("VRPN trackers {names:?} on {a} (TCP and UDP)");
                }
            }
            (None, Some((a, _))) => {
                tracing::warn!("VRPN port {a} is in use; trying again every second")
            }
            (None, None) => {}
        }
        if let Some((a, _, b)) = &settings.vmt {
            tracing::info!("VMT /VMT/Room/Driver to {a} for {} bodies", b.len());
        }
        if let Some((a, _)) = &settings.vmc {
            tracing::info!("VMC /VMC/Ext/Tra/Pos to {a}");
        }
        if let Some((a, _, b)) = &settings.opentrack {
            tracing::info!("opentrack UDP to {a} with body {:?}", rig_names.get(*b));
        }
        let filters = settings
            .bodies
            .iter()
            .map(|b| b.smoothing.map(PoseFilter::new))
            .collect();

        let watch = ctx
            .rig
            .path
            .as_ref()
            .map(|p| stereoscope_rig::watch::RigWatch::new(p.clone()));
        Ok(VrFeedService {
            cfg,
            node,
            settings,
            defs,
            rig_names,
            watch,
            reloads: 0,
            input,
            vrpn,
            next_bind: std::time::Instant::now(),
            udp,
            filters,
            labs,
            frames: 0,
            latency_us: std::collections::VecDeque::with_capacity(LATENCY_WINDOW),
            send_errors: 0,
            trace: Trace::open()?,
        })
    }

    /// The VRPN server's address (tests ask for port 0).
    pub fn vrpn_addr(&self) -> Option<SocketAddr> {
        self.vrpn.as_ref().and_then(|s| s.local_addr().ok())
    }

    /// Listens for VRPN clients if the rig asks for it and the port was taken: once a second,
    /// with the reason in health meanwhile.
    fn bind_vrpn(&mut self) {
        let Some((addr, _)) = self.settings.vrpn else {
            return;
        };
        if self.vrpn.is_some() || std::time::Instant::now() < self.next_bind {
            return;
        }
        self.next_bind = std::time::Instant::now() + Duration::from_secs(1);
        let names = self.defs.bodies.names();
        match vrpn::Server::bind(addr, names.clone()) {
            Ok(s) => {
                tracing::info!("VRPN trackers {names:?} on {addr} (TCP and UDP)");
                self.node.counters.set(Detail::Vrpn, "listening");
                self.vrpn = Some(s);
            }
            Err(e) => {
                let m = format!("VRPN cannot listen on {addr}: {e}; trying again every second");
                if self.node.counters.last_error() != Some(&m) {
                    tracing::warn!("{m}");
                }
                self.node.counters.set_error(&m);
                self.node.counters.set(Detail::Vrpn, "port in use");
            }
        }
    }

    fn send_udp(&mut self, bytes: &[u8], to: SocketAddr) {
        if let Err(e) = self.udp.send_to(bytes, to) {
            self.send_errors += 1;
            // Nobody listening gives "connection refused" on the next send: counted, not fatal.
            if self.send_errors <= 3 || self.send_errors.is_power_of_two() {
                tracing::debug!("sending to {to}: {e} ({} so far)", self.send_errors);
            }
            self.node
                .counters
                .set_error(&format!("sending to {to}: {e}"));
        }
    }

    /// The pose to send for one body (`rig_index`: its place in the running rig's bodies):
    /// smoothed and predicted as its `[[body]]` asks.
    fn output_pose(&mut self, rig_index: Option<usize>, b: &BodyPose, t_ns: u64) -> Isometry3<f64> {
        let mut pose = isometry(b);
        let Some(index) = rig_index else {
            return pose;
        };
        if let Some(f) = self.filters.get_mut(index).and_then(|f| f.as_mut()) {
            pose = f.filter(&pose, t_ns);
        }
        let ahead = self.settings.bodies.get(index).map_or(0.0, |o| o.predict_s);
        if ahead > 0.0 && !b.held {
            pose = predict(
                &pose,
                &Vector3::from(b.velocity_m_per_s),
                &Vector3::from(b.angular_velocity_rad_per_s),
                ahead,
            );
        }
        pose
    }

    fn handle(&mut self, frame: &PoseFrame) {
        let stamp = vrpn::Stamp::from_ns(frame.timestamp_ns);
        // Bodies absent from this frame start their smoothing afresh when they return.
        for (i, f) in self.filters.iter_mut().enumerate() {
            if let Some(f) = f
                && !frame
                    .bodies
                    .iter()
                    .any(|b| self.rig_names.get(i) == Some(&b.name))
            {
                f.reset();
            }
        }
        let mut out_bodies: Vec<output::OutputBody> = Vec::new();
        // The UDP datagrams of this frame, sent once every body is encoded.
        let mut datagrams: Vec<(Vec<u8>, SocketAddr)> = Vec::new();
        let mut sent: Vec<(&'static str, String, [f64; 3])> = Vec::new();
        let tracing_sends = self.trace.is_some();
        for b in &frame.bodies {
            let Some(index) = self.defs.bodies.index(&b.name) else {
                continue;
            };
            let rig_index = self.rig_names.iter().position(|n| *n == b.name);
            let pose = self.output_pose(rig_index, b, frame.timestamp_ns);
            out_bodies.push(output::OutputBody {
                index,
                world_from_body: pose,
                residual_mm: b.residual_mm,
                tracked: !b.held,
                velocity_m_per_s: b.velocity_m_per_s,
                angular_velocity_rad_per_s: b.angular_velocity_rad_per_s,
            });
            let position = Point3::from(pose.translation.vector);
            if let Some((_, f)) = &self.settings.vrpn {
                let c = feeds::in_frame(f, &position, &pose.rotation);
                let w = f.rotation(&UnitQuaternion::from_scaled_axis(
                    Vector3::from(b.angular_velocity_rad_per_s) * VEL_QUAT_DT_S,
                ));
                let v = f.consumer_from_world * Vector3::from(b.velocity_m_per_s) * f.units_per_m;
                if tracing_sends {
                    sent.push(("vrpn", b.name.clone(), c.position));
                }
                if let Some(s) = self.vrpn.as_mut() {
                    s.send(
                        index,
                        stamp,
                        c.position,
                        c.quat_xyzw,
                        Some(([v.x, v.y, v.z], [w.i, w.j, w.k, w.w], VEL_QUAT_DT_S)),
                    );
                }
            }
            if let Some((to, f, bodies)) = &self.settings.vmt
                && let Some(k) = bodies.iter().position(|&x| Some(x) == rig_index)
            {
                let c = feeds::in_frame(f, &position, &pose.rotation);
                if tracing_sends {
                    sent.push(("vmt", k.to_string(), c.position));
                }
                datagrams.push((feeds::vmt_room_driver(k as i32, &c), *to));
            }
            if let Some((to, f)) = &self.settings.vmc {
                let c = feeds::in_frame(f, &position, &pose.rotation);
                datagrams.push((feeds::vmc_tracker(&b.name, &c), *to));
            }
            if let Some((to, f, body)) = &self.settings.opentrack
                && Some(*body) == rig_index
            {
                let c = feeds::in_frame(f, &position, &pose.rotation);
                if tracing_sends {
                    sent.push(("opentrack", String::new(), c.position));
                }
                datagrams.push((feeds::opentrack(&c).to_vec(), *to));
            }
        }
        // The trace's send time: just before the first byte goes to a socket.
        let sending_ns = if tracing_sends { now_ns() } else { 0 };
        for (bytes, to) in datagrams {
            self.send_udp(&bytes, to);
        }
        if let Some(s) = self.vrpn.as_mut() {
            s.flush();
        }
        if self.labs.iter().any(|l| l.server.is_some()) {
            let markers: Vec<output::OutputMarker> = frame
                .poses
                .iter()
                .map(|p| output::OutputMarker {
                    position_m: Point3::from(p.position_m),
                    label: p
                        .body
                        .as_ref()
                        .and_then(|l| self.defs.bodies.index(&l.name).map(|i| (i, l.marker))),
                    object_id: p.object_id,
                })
                .collect();
            let of = output::OutputFrame {
                sequence: frame.sequence,
                exposure_ns: frame.timestamp_ns,
                received_ns: frame.frame_published_ns,
                bodies: &out_bodies,
                markers: &markers,
                models: &frame.models,
            };
            for l in &mut self.labs {
                if let Some(s) = l.server.as_mut() {
                    s.send(&of);
                }
            }
        }
        let now = now_ns();
        if let Some(t) = self.trace.as_mut()
            && !(sent.is_empty() && out_bodies.is_empty())
        {
            use std::fmt::Write as _;
            t.line.clear();
            let _ = write!(
                t.line,
                "{{\"exposure_ns\":{},\"sent_ns\":{sending_ns},\"sent\":[",
                frame.timestamp_ns
            );
            for (i, (feed, key, p)) in sent.iter().enumerate() {
                let sep = if i == 0 { "" } else { "," };
                let _ = write!(
                    t.line,
                    "{sep}[\"{feed}\",{key:?},{:?},{:?},{:?}]",
                    p[0], p[1], p[2]
                );
            }
            // Each body's pose as every protocol sends it, in the world frame (metres; x, y, z, w):
            // what the lab protocols' tests compare their clients with.
            t.line.push_str("],\"bodies\":[");
            for (i, o) in out_bodies.iter().enumerate() {
                let sep = if i == 0 { "" } else { "," };
                let p = o.world_from_body.translation.vector;
                let q = o.world_from_body.rotation;
                let _ = write!(
                    t.line,
                    "{sep}[{:?},{},{:?},{:?},{:?},{:?},{:?},{:?},{:?}]",
                    self.defs.bodies.name(o.index),
                    o.tracked,
                    p.x,
                    p.y,
                    p.z,
                    q.i,
                    q.j,
                    q.k,
                    q.w
                );
            }
            t.line.push_str("]}\n");
            if let Err(e) = std::io::Write::write_all(&mut t.out, t.line.as_bytes()) {
                tracing::warn!("writing the trace: {e}; tracing stops");
                self.trace = None;
            }
        }
        if !frame.bodies.is_empty() && frame.frame_published_ns > 0 {
            if self.latency_us.len() >= LATENCY_WINDOW {
                self.latency_us.pop_front();
            }
            self.latency_us
                .push_back(now.saturating_sub(frame.frame_published_ns) as f64 * 1e-3);
        }
        self.frames += 1;
        self.node.counters.processed = self.frames;
    }

    fn report_detail(&mut self) {
        let counters = &mut self.node.counters;
        counters.dropped = self.input.frames.overflowed();
        if let Some(s) = self.vrpn.as_mut() {
            for (reason, message) in s.dropped.drain(..) {
                counters.reject(reason, &message);
            }
            counters.set(Detail::VrpnClients, s.clients());
        }
        let mut send_errors = self.send_errors;
        for l in &mut self.labs {
            if let Some(s) = l.server.as_mut() {
                if let (Some(key), Some(n)) = (l.clients_key, s.clients()) {
                    counters.set(key, n);
                }
                let c = s.counts();
                send_errors += c.send_errors;
                for (reason, message) in c.dropped.drain(..) {
                    counters.reject(reason, &message);
                }
                if let Some(e) = c.last_error.take() {
                    counters.set_error(&e);
                }
            }
        }
        counters.set(Detail::SendErrors, send_errors);
        if !self.latency_us.is_empty() {
            let mut v: Vec<f64> = self.latency_us.iter().copied().collect();
            v.sort_by(f64::total_cmp);
            let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
            counters.set(Detail::LatencyP50Us, format!("{:.0}", q(0.5)));
            counters.set(Detail::LatencyP99Us, format!("{:.0}", q(0.99)));
        }
    }
}

impl Service for VrFeedService {
    type Summary = VrFeedSummary;
    type Error = VrFeedError;

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Pose frames handled.
    fn limit(&self) -> Option<u64> {
        self.cfg.max_frames
    }

    fn step(&mut self, _shutdown: &Shutdown) -> Result<Flow, VrFeedError> {
        self.apply_rig_changes();
        self.bind_vrpn();
        for l in &mut self.labs {
            l.bind(&mut self.node.counters, &self.defs);
        }
        // Wake for a frame, or every 5 ms to serve VRPN clients.
        let wait = Duration::from_millis(5);
        let mut frames = Vec::new();
        let counters = &mut self.node.counters;
        let first = match &self.input.waker {
            Some(waker) => {
                waker.wait(wait);
                self.input.frames.try_next(counters)
            }
            None => self.input.frames.next_within(wait, counters),
        };
        frames.extend(first);
        while let Some(f) = self.input.frames.try_next(counters) {
            frames.push(f);
        }
        if let Some(s) = self.vrpn.as_mut() {
            s.poll();
        }
        for l in &mut self.labs {
            if let Some(s) = l.server.as_mut() {
                s.poll();
            }
        }
        for f in &frames {
            self.handle(f);
        }
        if self.node.report_due() {
            self.report_detail();
        }
        Ok(Flow::Continue)
    }

    fn summary(&self) -> VrFeedSummary {
        VrFeedSummary {
            frames: self.frames,
            latency_us: self.latency_us.iter().copied().collect(),
        }
    }
}

/// The address the UDP feeds (VMT, VMC, opentrack) send from: loopback when every
/// destination is on this PC, so nothing on another host can reach the socket; any address of
/// the destinations' family otherwise.
fn udp_source(destinations: &[SocketAddr]) -> SocketAddr {
    let all_v6 = !destinations.is_empty() && destinations.iter().all(SocketAddr::is_ipv6);
    let here = destinations.iter().all(|d| d.ip().is_loopback());
    let ip: std::net::IpAddr = match (here, all_v6) {
        (true, true) => std::net::Ipv6Addr::LOCALHOST.into(),
        (true, false) => std::net::Ipv4Addr::LOCALHOST.into(),
        (false, true) => std::net::Ipv6Addr::UNSPECIFIED.into(),
        (false, false) => std::net::Ipv4Addr::UNSPECIFIED.into(),
    };
    SocketAddr::new(ip, 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_udp_feeds_send_from_loopback_when_every_destination_is_here() {
        let at = |s: &str| s.parse::<SocketAddr>().unwrap();
        let here = [at("127.0.0.1:39570"), at("127.0.0.1:4242")];
        assert_eq!(udp_source(&here), at("127.0.0.1:0"));
        assert_eq!(udp_source(&[]), at("127.0.0.1:0"));
        assert_eq!(udp_source(&[at("[::1]:4242")]), at("[::1]:0"));
        let away = [at("127.0.0.1:39570"), at("192.168.1.20:4242")];
        assert_eq!(udp_source(&away), at("0.0.0.0:0"));
        assert_eq!(udp_source(&[at("[fe80::1]:4242")]), at("[::]:0"));
        // Sending from loopback to a loopback destination works.
        let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
        let tx = UdpSocket::bind(udp_source(&[rx.local_addr().unwrap()])).unwrap();
        tx.send_to(b"x", rx.local_addr().unwrap()).unwrap();
        let mut buf = [0u8; 4];
        rx.set_read_timeout(Some(std::time::Duration::from_secs(2)))
            .unwrap();
        assert_eq!(rx.recv_from(&mut buf).unwrap().0, 1);
    }
}
