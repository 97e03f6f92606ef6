//! The fusion service: one per rig, on any PC. It gathers every camera's observations — over
//! iceoryx2 from moment workers on its own PC, over Zenoh from the others — pairs them in time
//! ([`pairing`]), recovers each object's position and heading with a stable id ([`fuser`]),
//! and publishes pose frames on Zenoh (the system's network interface) and iceoryx2 (for
//! output services on the same PC), plus each object's pose on its own key.
//!
//! A camera that stops sending is waited for at most `max_wait`, then left out of sets until
//! it is heard again (`camera_timeout`): fusion carries on with the cameras it has (two or
//! more: triangulation; one: depth from area where that camera has a model). Observations that
//! do not decode, or come from a camera the rig does not have, are counted, named in the log
//! and in health, and ignored.

pub mod bodies;
pub mod cli;
pub mod fuser;
pub mod identity;
pub mod pairing;

use fuser::{DEFAULT_CONFIRM_SETS, Fuser, FuserConfig};
use pairing::{Pairer, PairingConfig};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::time::Duration;
use stereoscope_geometry::correspond::CorrespondConfig;
use stereoscope_proto::messages::{
    BodyUpdate, Message, Observation, PoseFrame, PoseUpdate, SCHEMA_VERSION, now_ns,
};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_rig::Context;
use stereoscope_rig::schema::{ObservationRoute, RigFile};
use stereoscope_transport::iox::{MessageSubscriber, Waker};
use stereoscope_transport::net::KeyedPublisher;
use stereoscope_transport::{Counters, Flow, Outlet, Service, ServiceNode, Shutdown, drive, net};

#[derive(Debug, Clone)]
pub struct FusionConfig {
    pub ctx: Context,
    /// Stop after this many frame sets (tests, benchmarks).
    pub max_sets: Option<u64>,
}

#[derive(Debug, thiserror::Error)]
pub enum FusionError {
    #[error("fusion: the rig has no cameras")]
    NoCameras,
    /// `[fusion] replay_sets` names a file that is not a recording's pose frames.
    #[error("fusion")]
    ReplaySets(#[source] stereoscope_rig::RigError),
    #[error("fusion")]
    Transport(#[from] stereoscope_transport::TransportError),
    #[error(transparent)]
    Identity(#[from] identity::IdentityError),
}

/// Most new objects one set can make: the id reservation covers them before a set is fused.
const MAX_NEW_OBJECTS_PER_SET: u32 = 256;

/// Fusion's settings from the rig file's `[fusion]` table (defaults in `docs/services.md`;
/// values checked when the rig was loaded).
pub fn settings(file: &RigFile) -> (PairingConfig, FuserConfig, bool) {
    let f = file.fusion.clone().unwrap_or_default();
    let scale = file.units.metres();
    let ms = |v: Option<f64>, d: f64| (v.unwrap_or(d) * 1e6) as u64;
    let pairing = PairingConfig {
        max_skew_ns: ms(f.max_skew_ms, 5.0),
        max_wait_ns: ms(f.max_wait_ms, 20.0),
        camera_timeout_ns: ms(f.camera_timeout_ms, 500.0),
        max_ahead_ns: ms(f.clock_window_ms, 1000.0),
        // A replay's frames keep their recorded times.
        max_behind_ns: f
            .replay_sets
            .is_none()
            .then(|| ms(f.clock_window_ms, 1000.0)),
    };
    let d = CorrespondConfig::default();
    let fuser = FuserConfig {
        correspond: CorrespondConfig {
            max_epipolar_px: f.max_epipolar_px.unwrap_or(d.max_epipolar_px),
            max_residual_px: f.max_residual_px.unwrap_or(d.max_residual_px),
        },
        gate_m: f.association_gate.map(|g| g * scale).unwrap_or(0.1),
        drop_after_ns: (f.drop_after_s.unwrap_or(2.0) * 1e9) as u64,
        confirm_sets: f.confirm_sets.unwrap_or(DEFAULT_CONFIRM_SETS),
        volume_m: f.volume.map(|v| {
            let p = |a: [f64; 3]| nalgebra::Point3::new(a[0] * scale, a[1] * scale, a[2] * scale);
            (p(v.min), p(v.max))
        }),
        ..FuserConfig::default()
    };
    let all_zenoh = f.observations == Some(ObservationRoute::Zenoh);
    (pairing, fuser, all_zenoh)
}

enum Input {
    Obs(usize, Observation),
    /// Refused before it changed anything: the reason it is counted under, and the message.
    Bad(&'static str, String),
}

/// Runs until shutdown (or `max_sets`); returns the number of pose frames published.
pub fn run(cfg: FusionConfig, shutdown: Shutdown) -> Result<u64, FusionError> {
    drive(FusionService::setup(cfg)?, &shutdown)
}

/// A running fusion: its inputs (iceoryx2 subscribers for this PC's workers, a channel fed by
/// Zenoh subscribers for the others), the pairer and fuser, and its outlets.
pub struct FusionService {
    cfg: FusionConfig,
    node: ServiceNode,
    local: Vec<(usize, MessageSubscriber)>,
    remote: mpsc::Receiver<Input>,
    /// Kept alive: dropping a subscriber undeclares it.
    _remote_subs: Vec<net::NetSubscriber>,
    /// Network messages the loop had no room for (it fell behind by 256).
    overflow: Arc<AtomicU64>,
    waker: Waker,
    wait: Duration,
    poses: Outlet<PoseFrame>,
    per_object: KeyedPublisher,
    per_body: KeyedPublisher,
    bodies: bodies::Bodies,
    pairer: Pairer,
    fuser: Fuser,
    sequence: u64,
    ids: identity::Reservations,
    /// Blobs left out because they held two objects' merged images.
    merged_blobs: u64,
}

impl std::fmt::Debug for FusionService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "FusionService({}, {} sets)",
            self.cfg.ctx.rig.name, self.sequence
        )
    }
}

impl FusionService {
    /// Subscribes to every camera's observations (iceoryx2 for this PC's cameras unless the
    /// rig routes them all over Zenoh) and declares the pose outlets.
    pub fn setup(cfg: FusionConfig) -> Result<Self, FusionError> {
        let ctx = &cfg.ctx;
        let rig = ctx.rig.spec.name.clone();
        let (pair_cfg, fuser_cfg, all_zenoh) = settings(&ctx.rig.spec);
        let n = ctx.rig.cameras.len();
        if n == 0 {
            return Err(FusionError::NoCameras);
        }
        let node = ServiceNode::start(ctx.node_spec("fusion"))?;
        let here = ctx.cameras_here();
        let mut local = Vec::new();
        let (tx, rx) = mpsc::sync_channel::<Input>(256);
        let overflow = Arc::new(AtomicU64::new(0));
        let mut remote_subs = Vec::new();
        for (i, c) in ctx.rig.cameras.iter().enumerate() {
            if !all_zenoh && here.contains(&c.id) {
                let sub = MessageSubscriber::new(&node.iox, &iox_names::observations(&rig, &c.id))?;
                local.push((i, sub));
            } else {
                let tx = tx.clone();
                let key = keys::observations(&rig, &c.id);
                let expected_rig = rig.clone();
                let cam_id = c.id.clone();
                let overflow = overflow.clone();
                let sub = net::subscribe(&node.session, &key, move |k, bytes| {
                    let input = match Observation::from_json(bytes) {
                        Ok(o) if o.rig == expected_rig && o.camera == cam_id => Input::Obs(i, o),
                        // Names are bounded by the decoder's checks.
                        Ok(o) => Input::Bad(
                            "foreign",
                            format!(
                                "{k}: observation of rig {:?} camera {:?} on this camera's key",
                                o.rig, o.camera
                            ),
                        ),
                        Err(e) => Input::Bad(e.reason(), format!("{k}: {e}")),
                    };
                    if tx.try_send(input).is_err() {
                        overflow.fetch_add(1, Ordering::Relaxed);
                    }
                })?;
                remote_subs.push(sub);
            }
        }
        let waker = Waker::new(&node.iox, &iox_names::observations_ready(&rig))?;
        let poses = node.outlet(&iox_names::poses(&rig), &[], &keys::poses(&rig))?;
        let per_object = KeyedPublisher::new(&node.session, &keys::all_poses(&rig))?;
        let per_body = KeyedPublisher::new(&node.session, &keys::all_bodies(&rig))?;
        let bodies = bodies::Bodies::of_rig(&ctx.rig.spec);
        tracing::info!(
            local = local.len(),
            remote = remote_subs.len(),
            "fusion ready for {n} cameras"
        );
        // With remote cameras, poll the network channel often; with local ones only, sleep
        // on the iceoryx2 event until a worker notifies.
        let wait = if remote_subs.is_empty() {
            Duration::from_millis(50)
        } else {
            Duration::from_micros(500)
        };
        // Within a launcher's session, numbers continue across restarts.
        let (ids, sequence, first_id) = match std::env::var(identity::SESSION_ENV) {
            Ok(session) if !session.is_empty() => identity::Reservations::open(
                &identity::Reservations::path(&ctx.iox_prefix, &rig),
                &session,
            )?,
            _ => (identity::Reservations::none(), 0, 1),
        };
        if sequence > 0 {
            tracing::info!(
                "continuing the session from pose frame {sequence}, object id {first_id}"
            );
        }
        let fuser = Fuser::new(&ctx.rig, fuser_cfg).with_first_id(first_id);
        let mut pairer = Pairer::new(n, pair_cfg);
        if let Some(p) = ctx
            .rig
            .spec
            .fusion
            .as_ref()
            .and_then(|f| f.replay_sets.as_ref())
        {
            let ids: Vec<String> = ctx.rig.cameras.iter().map(|c| c.id.clone()).collect();
            let schedule = pairing::read_schedule(&ctx.rig.source_path(p), &ids).map_err(|e| {
                FusionError::ReplaySets(stereoscope_rig::RigError {
                    kind: stereoscope_rig::RigErrorKind::Value,
                    file: ctx.rig.path.clone(),
                    key: "fusion.replay_sets".into(),
                    message: stereoscope_transport::error_chain(&e),
                })
            })?;
            tracing::info!("forming the {} sets of the recording", schedule.len());
            pairer = pairer.with_schedule(schedule);
        }
        Ok(FusionService {
            node,
            local,
            remote: rx,
            _remote_subs: remote_subs,
            overflow,
            waker,
            wait,
            poses,
            per_object,
            per_body,
            bodies,
            pairer,
            fuser,
            sequence,
            ids,
            merged_blobs: 0,
            cfg,
        })
    }

    /// Takes every observation waiting, local and remote, into the pairer.
    fn take_inputs(&mut self) {
        let cameras = &self.cfg.ctx.rig.cameras;
        if !self.local.is_empty() {
            self.waker.wait(self.wait);
        } else if let Ok(input) = self.remote.recv_timeout(Duration::from_millis(50)) {
            handle(input, &mut self.pairer, &mut self.node.counters, cameras);
        }
        let counters = &mut self.node.counters;
        for (i, sub) in &self.local {
            loop {
                match sub.try_next::<Observation>() {
                    Ok(Some(Ok(o))) => {
                        handle(Input::Obs(*i, o), &mut self.pairer, counters, cameras)
                    }
                    Ok(Some(Err(e))) => handle(
                        Input::Bad(e.reason(), format!("{}: {e}", sub.name())),
                        &mut self.pairer,
                        counters,
                        cameras,
                    ),
                    Ok(None) => break,
                    Err(e) => {
                        counters.note::<(), _>(Err(e));
                        break;
                    }
                }
            }
        }
        while let Ok(input) = self.remote.try_recv() {
            handle(input, &mut self.pairer, counters, cameras);
        }
    }

    /// Fuses one complete (or timed-out) set of observations and publishes its pose frame,
    /// on both transports, and each object's pose on its own key.
    fn publish_set(&mut self, set: &[(usize, Observation)]) -> Result<(), FusionError> {
        // Reserved before they are used: a crash never lets them be handed out twice.
        self.ids.reserve(
            self.sequence,
            self.fuser.next_id().saturating_add(MAX_NEW_OBJECTS_PER_SET),
        )?;
        let rig = &self.cfg.ctx.rig;
        let timestamp_ns = set.iter().map(|(_, o)| o.timestamp_ns).min().unwrap_or(0);
        let frame_published_ns = set
            .iter()
            .map(|(_, o)| o.frame_published_ns)
            .max()
            .unwrap_or(0);
        let cameras: Vec<String> = set
            .iter()
            .map(|(c, _)| rig.cameras[*c].id.clone())
            .collect();
        self.merged_blobs += set
            .iter()
            .map(|(_, o)| o.blobs.iter().filter(|b| b.merged).count() as u64)
            .sum::<u64>();
        let mut fused = self.fuser.fuse(set, timestamp_ns);
        let bodies = self
            .bodies
            .update_refined(&mut fused, timestamp_ns, &mut self.fuser);
        let published_ns = now_ns();
        let frame = PoseFrame {
            schema: SCHEMA_VERSION,
            rig: rig.name.clone(),
            sequence: self.sequence,
            timestamp_ns,
            frame_published_ns,
            published_ns,
            cameras,
            poses: fused,
            bodies,
        };
        let counters = &mut self.node.counters;
        self.poses.publish(&frame, counters);
        // Per-object and per-body updates are made only while someone subscribes to them.
        let objects_wanted = !frame.poses.is_empty() && self.per_object.matching();
        let bodies_wanted = !frame.bodies.is_empty() && self.per_body.matching();
        for p in frame.poses.iter().filter(|_| objects_wanted) {
            let u = PoseUpdate {
                schema: SCHEMA_VERSION,
                rig: rig.name.clone(),
                sequence: self.sequence,
                timestamp_ns,
                frame_published_ns,
                published_ns,
                pose: p.clone(),
            };
            counters.note(
                self.per_object
                    .put_bytes(&keys::pose(&rig.name, p.object_id), u.to_json()),
            );
        }
        for b in frame.bodies.iter().filter(|_| bodies_wanted) {
            let u = BodyUpdate {
                schema: SCHEMA_VERSION,
                rig: rig.name.clone(),
                sequence: self.sequence,
                timestamp_ns,
                frame_published_ns,
                published_ns,
                body: b.clone(),
            };
            counters.note(
                self.per_body
                    .put_bytes(&keys::body(&rig.name, &b.name), u.to_json()),
            );
        }
        self.sequence += 1;
        counters.processed += 1;
        Ok(())
    }

    fn report_detail(&mut self) {
        let rig = &self.cfg.ctx.rig;
        let counters = &mut self.node.counters;
        let now = now_ns();
        counters.dropped = self.pairer.discarded + self.overflow.load(Ordering::Relaxed);
        let live: Vec<&str> = (0..rig.cameras.len())
            .filter(|&c| self.pairer.live(c, now))
            .map(|c| rig.cameras[c].id.as_str())
            .collect();
        let detail = &mut counters.detail;
        detail.insert("cameras_live".into(), live.join(","));
        detail.insert("late".into(), self.pairer.late.to_string());
        if self.pairer.before_start > 0 {
            detail.insert("before_start".into(), self.pairer.before_start.to_string());
        }
        if let Some((c, sequence)) = self.pairer.last_lost {
            let camera = rig.cameras.get(c).map(|c| c.id.as_str()).unwrap_or("?");
            detail.insert("last_lost".into(), format!("{camera} frame {sequence}"));
        }
        if self.pairer.short_sets > 0 {
            detail.insert("short_sets".into(), self.pairer.short_sets.to_string());
        }
        detail.insert("objects".into(), self.fuser.objects().to_string());
        if self.fuser.outside_volume > 0 {
            detail.insert(
                "outside_volume".into(),
                self.fuser.outside_volume.to_string(),
            );
        }
        if self.fuser.hiding_blobs > 0 {
            detail.insert("hiding".into(), self.fuser.hiding_blobs.to_string());
        }
        if self.fuser.clipped > 0 {
            detail.insert("clipped".into(), self.fuser.clipped.to_string());
        }
        if self.fuser.area_mismatch > 0 {
            detail.insert("area_mismatch".into(), self.fuser.area_mismatch.to_string());
        }
        if self.fuser.single_view_unmatched > 0 {
            detail.insert(
                "single_view_unmatched".into(),
                self.fuser.single_view_unmatched.to_string(),
            );
        }
        if self.merged_blobs > 0 {
            detail.insert("merged_blobs".into(), self.merged_blobs.to_string());
        }
    }
}

impl Service for FusionService {
    type Summary = u64;
    type Error = FusionError;

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Waits (bounded) for observations, then fuses every set the pairer has ready.
    fn step(&mut self, _shutdown: &Shutdown) -> Result<Flow, FusionError> {
        let done = |s: &Self| {
            s.cfg
                .max_sets
                .is_some_and(|m| s.node.counters.processed >= m)
        };
        if done(self) {
            return Ok(Flow::Stop);
        }
        self.take_inputs();
        while let Some(set) = self.pairer.pop(now_ns()) {
            if set.is_empty() {
                continue;
            }
            self.publish_set(&set)?;
            if done(self) {
                break;
            }
        }
        if self.pairer.schedule_done() {
            tracing::info!("formed every set of the recording");
            self.report_detail();
            return Ok(Flow::Stop);
        }
        if self.node.report_due() {
            self.report_detail();
        }
        Ok(Flow::Continue)
    }

    /// Pose frames published by this run.
    fn summary(&self) -> u64 {
        self.node.counters.processed
    }
}

/// Pairs an observation of camera index `c` (`cameras` names it in a refusal), or counts a
/// refused input.
fn handle(
    input: Input,
    pairer: &mut Pairer,
    counters: &mut Counters,
    cameras: &[stereoscope_rig::RigCamera],
) {
    let (reason, message) = match input {
        Input::Obs(c, o) => {
            let sequence = o.sequence;
            match pairer.push(c, o, now_ns()) {
                Ok(()) => return,
                Err(r) => {
                    let camera = cameras.get(c).map(|x| x.id.as_str()).unwrap_or("?");
                    (
                        r.reason(),
                        format!("observation of {camera} frame {sequence}: {r}"),
                    )
                }
            }
        }
        Input::Bad(reason, message) => (reason, message),
    };
    counters.reject(reason, &message);
    // A flood is counted in full but logged sparsely.
    if counters.rejected <= 10 || counters.rejected.is_power_of_two() {
        tracing::warn!("rejected {message} ({} so far)", counters.rejected);
    }
}
