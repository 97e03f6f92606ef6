//! The fusion service: one per rig, on any PC. It gathers every camera's observations — over
//! iceoryx2 from moment workers on its own PC, over Zenoh from the others — pairs them in time
//! (`stereoscope_pipeline::pairing`), recovers each object's position and heading with a
//! stable id and the rigid bodies among them (`stereoscope_pipeline::fusion`), and publishes pose frames on Zenoh (the system's network interface) and iceoryx2 (for
//! output services on the same PC), plus each object's pose on its own key.
//!
//! A camera that stops sending is waited for at most `max_wait`, then left out of sets until
//! it is heard again (`camera_timeout`): fusion carries on with the cameras it has (two or
//! more: triangulation; one: depth from area where that camera has a model). Observations that
//! do not decode, or come from a camera the rig does not have, are counted, named in the log
//! and in health, and ignored.
//!
//! The rig file's `[[body]]` and `[[model]]` tables are applied while fusion runs when the file
//! changes and loads (`reload`).

pub mod cli;
pub mod identity;

use std::time::Duration;
use stereoscope_pipeline::pairing::{self, Pairer};
use stereoscope_pipeline::{Fusion, FusionSettings};
use stereoscope_proto::messages::{
    BodyUpdate, Detail, Message, ModelUpdate, Observation, PoseFrame, PoseUpdate, SCHEMA_VERSION,
    now_ns,
};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_rig::watch::{Change, RigWatch};
use stereoscope_service::Context;
use stereoscope_transport::inlet::Unexpected;
use stereoscope_transport::iox::Waker;
use stereoscope_transport::net::KeyedPublisher;
use stereoscope_transport::{Counters, Flow, Inlet, Outlet, Service, ServiceNode, Shutdown, drive};

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

/// Most new objects one set can make (no more than a pose frame carries): the id reservation
/// covers them before a set is fused.
const MAX_NEW_OBJECTS_PER_SET: u32 = stereoscope_proto::messages::limits::MAX_POSES as u32;

/// Runs until shutdown (or `max_sets`); returns the number of pose frames published.
pub fn run(cfg: FusionConfig, shutdown: Shutdown) -> Result<u64, FusionError> {
    drive(FusionService::setup(cfg)?, &shutdown)
}

/// A running fusion: its inputs (iceoryx2 subscribers for this PC's workers, a channel fed by
/// Zenoh subscribers for the others), the pairer and fuser, and its outlets.
pub struct FusionService {
    cfg: FusionConfig,
    node: ServiceNode,
    /// This PC's cameras' observations (rig camera index, inlet).
    local: Vec<(usize, Inlet<Observation>)>,
    /// The other PCs' cameras' observations, on their keys.
    remote: Option<Inlet<Observation>>,
    waker: Waker,
    wait: Duration,
    poses: Outlet<PoseFrame>,
    per_object: KeyedPublisher,
    per_body: KeyedPublisher,
    per_model: KeyedPublisher,
    pairer: Pairer,
    fusion: Fusion,
    sequence: u64,
    ids: identity::Reservations,
    /// Blobs left out because they held two objects' merged images.
    merged_blobs: u64,
    /// The rig file, for bodies and models changed while fusion runs.
    watch: Option<RigWatch>,
    /// Changes of bodies and models applied.
    reloads: u64,
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
        let settings = FusionSettings::of_rig(&ctx.rig.spec);
        let n = ctx.rig.cameras.len();
        if n == 0 {
            return Err(FusionError::NoCameras);
        }
        let node = ServiceNode::start(ctx.node_spec("fusion"))?;
        let here = ctx.cameras_here();
        let mut local = Vec::new();
        let mut remote_keys = Vec::new();
        for (i, c) in ctx.rig.cameras.iter().enumerate() {
            if !settings.all_zenoh && here.contains(&c.id) {
                let name = iox_names::observations(&rig, &c.id);
                let id = c.id.clone();
                let inlet = Inlet::iox(&node.iox, &name, &rig, "observation")?
                    .expecting(move |_, o: &Observation| same_camera(&id, o));
                local.push((i, inlet));
            } else {
                remote_keys.push((keys::observations(&rig, &c.id), c.id.clone()));
            }
        }
        // Each camera's observations on its own key only; a network message the loop had no
        // room for (it fell behind by 256) is counted as dropped.
        let remote = if remote_keys.is_empty() {
            None
        } else {
            let names: Vec<String> = remote_keys.iter().map(|(k, _)| k.clone()).collect();
            let inlet = Inlet::zenoh(&node.session, &names, &rig, "observation", 256)?.expecting(
                move |key, o: &Observation| match remote_keys.iter().find(|(k, _)| k == key) {
                    Some((_, id)) => same_camera(id, o),
                    None => Err(format!("on {key}, which is no camera's").into()),
                },
            );
            Some(inlet)
        };
        let waker = Waker::new(&node.iox, &iox_names::observations_ready(&rig))?;
        let poses = node.outlet(&iox_names::poses(&rig), &[], &keys::poses(&rig))?;
        let per_object = KeyedPublisher::new(&node.session, &keys::all_poses(&rig))?;
        let per_body = KeyedPublisher::new(&node.session, &keys::all_bodies(&rig))?;
        let per_model = KeyedPublisher::new(&node.session, &keys::all_models(&rig))?;
        tracing::info!(
            local = local.len(),
            remote = n - local.len(),
            "fusion ready for {n} cameras"
        );
        // With remote cameras, poll the network channel often; with local ones only, sleep
        // on the iceoryx2 event until a worker notifies.
        let wait = if remote.is_none() {
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
        let mut fusion = Fusion::of_rig(&ctx.rig);
        fusion.fuser = fusion.fuser.with_first_id(first_id);
        let mut pairer = Pairer::new(n, settings.pairing);
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
            remote,
            waker,
            wait,
            poses,
            per_object,
            per_body,
            per_model,
            pairer,
            fusion,
            sequence,
            ids,
            merged_blobs: 0,
            watch: ctx.rig.path.as_ref().map(|p| RigWatch::new(p.clone())),
            reloads: 0,
            cfg,
        })
    }

    /// Applies the rig file's bodies and models when it changed and loads; reports why not
    /// otherwise. The running rig (cameras, keys, settings) stays as it started.
    fn apply_rig_changes(&mut self) {
        let Some(change) = self.watch.as_mut().and_then(|w| w.poll(&self.cfg.ctx.rig)) else {
            return;
        };
        match change {
            Change::Refused(e) => {
                tracing::warn!("the rig file changed but does not load; nothing applied: {e}");
                self.node
                    .counters
                    .set_error(&format!("rig file changed, not applied: {e}"));
            }
            Change::Apply {
                rig,
                others_changed,
            } => {
                self.fusion.set_bodies_and_models(&rig);
                self.reloads += 1;
                let names = |v: Vec<&str>| v.join(", ");
                tracing::info!(
                    "bodies and models from the changed rig file applied: bodies [{}], models [{}]",
                    names(rig.spec.bodies.iter().map(|b| b.name.as_str()).collect()),
                    names(rig.models.iter().map(|m| m.model.name.as_str()).collect())
                );
                if others_changed {
                    tracing::warn!(
                        "the rig file changed beyond [[body]] and [[model]]: restart the rig to apply the rest"
                    );
                    self.node.counters.set_error(
                        "rig file changed beyond [[body]] and [[model]]: restart to apply the rest",
                    );
                }
            }
        }
    }

    /// Takes every observation waiting, local and remote, into the pairer.
    fn take_inputs(&mut self) {
        let cameras = &self.cfg.ctx.rig.cameras;
        let counters = &mut self.node.counters;
        if !self.local.is_empty() {
            self.waker.wait(self.wait);
        } else if let Some(remote) = &self.remote
            && let Some(o) = remote.next_within(Duration::from_millis(50), counters)
        {
            pair(o, &mut self.pairer, counters, cameras);
        }
        for (_, inlet) in &self.local {
            while let Some(o) = inlet.try_next(counters) {
                pair(o, &mut self.pairer, counters, cameras);
            }
        }
        if let Some(remote) = &self.remote {
            while let Some(o) = remote.try_next(counters) {
                pair(o, &mut self.pairer, counters, cameras);
            }
        }
    }

    /// Fuses one complete (or timed-out) set of observations and publishes its pose frame,
    /// on both transports, and each object's pose on its own key.
    fn publish_set(&mut self, set: &[(usize, Observation)]) -> Result<(), FusionError> {
        // Reserved before they are used: a crash never lets them be handed out twice.
        self.ids.reserve(
            self.sequence,
            self.fusion
                .fuser
                .next_id()
                .saturating_add(MAX_NEW_OBJECTS_PER_SET),
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
        let (fused, bodies) = self.fusion.fuse(set, timestamp_ns);
        let models = self.fusion.take_models();
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
            models,
        };
        let counters = &mut self.node.counters;
        self.poses.publish(&frame, counters);
        // Per-object and per-body updates are made only while someone subscribes to them.
        let objects_wanted = !frame.poses.is_empty() && self.per_object.matching();
        let bodies_wanted = !frame.bodies.is_empty() && self.per_body.matching();
        let models_wanted = !frame.models.is_empty() && self.per_model.matching();
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
        for m in frame.models.iter().filter(|_| models_wanted) {
            let u = ModelUpdate {
                schema: SCHEMA_VERSION,
                rig: rig.name.clone(),
                sequence: self.sequence,
                timestamp_ns,
                frame_published_ns,
                published_ns,
                model: m.clone(),
            };
            counters.note(
                self.per_model
                    .put_bytes(&keys::model(&rig.name, &m.name), u.to_json()),
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
        let overflowed = self.remote.as_ref().map_or(0, Inlet::overflowed);
        counters.dropped = self.pairer.discarded + overflowed + self.fusion.dropped_poses;
        let live: Vec<&str> = (0..rig.cameras.len())
            .filter(|&c| self.pairer.live(c, now))
            .map(|c| rig.cameras[c].id.as_str())
            .collect();
        counters.set(Detail::CamerasLive, live.join(","));
        counters.set(Detail::Late, self.pairer.late);
        counters.set_nonzero(Detail::BeforeStart, self.pairer.before_start);
        if let Some((c, sequence)) = self.pairer.last_lost {
            let camera = rig.cameras.get(c).map(|c| c.id.as_str()).unwrap_or("?");
            counters.set(Detail::LastLost, format!("{camera} frame {sequence}"));
        }
        counters.set_nonzero(Detail::ShortSets, self.pairer.short_sets);
        let fuser = &self.fusion.fuser;
        counters.set(Detail::Objects, fuser.objects());
        counters.set_nonzero(Detail::OutsideVolume, fuser.outside_volume);
        counters.set_nonzero(Detail::Hiding, fuser.hiding_blobs);
        counters.set_nonzero(Detail::Clipped, fuser.clipped);
        counters.set_nonzero(Detail::AreaMismatch, fuser.area_mismatch);
        counters.set_nonzero(Detail::SingleViewUnmatched, fuser.single_view_unmatched);
        counters.set_nonzero(Detail::TooFewViews, fuser.too_few_views);
        counters.set_nonzero(Detail::MergedBlobs, self.merged_blobs);
        counters.set(Detail::Bodies, self.fusion.body_names().join(","));
        counters.set_nonzero(Detail::RigReloads, self.reloads);
    }
}

impl Service for FusionService {
    type Summary = u64;
    type Error = FusionError;

    /// Pose frames published.
    fn limit(&self) -> Option<u64> {
        self.cfg.max_sets
    }

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Waits (bounded) for observations, then fuses every set the pairer has ready.
    fn step(&mut self, _shutdown: &Shutdown) -> Result<Flow, FusionError> {
        // One step can fuse several sets: none past the limit.
        let done = |s: &Self| s.limit().is_some_and(|m| s.node.counters.processed >= m);
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
        self.apply_rig_changes();
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

/// Refuses an observation that names a camera other than `camera`, whose key or service it
/// came on.
fn same_camera(camera: &str, o: &Observation) -> Result<(), Unexpected> {
    if o.camera == camera {
        Ok(())
    } else {
        Err(format!("of camera {:?} on camera {camera:?}'s channel", o.camera).into())
    }
}

/// Pairs an observation (of a camera of the rig: its inlet checked that), or counts it as
/// refused by the pairer.
fn pair(
    o: Observation,
    pairer: &mut Pairer,
    counters: &mut Counters,
    cameras: &[stereoscope_rig::RigCamera],
) {
    let Some(c) = cameras.iter().position(|x| x.id == o.camera) else {
        return;
    };
    let sequence = o.sequence;
    if let Err(r) = pairer.push(c, o, now_ns()) {
        let message = format!("observation of {} frame {sequence}: {r}", cameras[c].id);
        stereoscope_transport::inlet::refuse(
            counters,
            &stereoscope_transport::Refusal {
                reason: r.reason(),
                message,
            },
        );
    }
}
