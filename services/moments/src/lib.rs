//! The moment worker service: one per camera, on the camera's PC. It borrows each frame in
//! shared memory (no copy), runs the worker's per-frame step on it (`stereoscope_pipeline::worker`:
//! thresholds, the thesis's moments and tracking windows, headings), and publishes one
//! `Observation` per frame: over iceoryx2 for a fusion on the same PC, and on Zenoh for one
//! elsewhere; a reduced preview goes to the viewer while someone watches.
//!
//! Always works on the newest frame: when it falls behind, older frames are released unread
//! and counted as dropped, as are gaps in the capture's sequence numbers. A frame whose header
//! disagrees with its payload is rejected, named in the log and in health, and skipped.

pub mod cli;

use std::time::Duration;
use stereoscope_pipeline::worker::{PREVIEW_EVERY_MS, Worker};
use stereoscope_proto::messages::{Detail, Message, Observation, now_ns};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_service::Context;
use stereoscope_transport::iox::FrameSubscriber;
use stereoscope_transport::{Flow, Outlet, Service, ServiceNode, Shutdown, drive};
use stereoscope_vision::VisionError;

#[derive(Debug, Clone)]
pub struct MomentsConfig {
    pub ctx: Context,
    pub camera: String,
    /// Stop after this many frames (tests, benchmarks).
    pub max_frames: Option<u64>,
}

/// Why a worker could not start.
#[derive(Debug, thiserror::Error)]
pub enum MomentsError {
    #[error("moments/{camera}: not a camera of the rig")]
    UnknownCamera { camera: String },
    #[error("moments/{camera}")]
    Rig {
        camera: String,
        #[source]
        source: stereoscope_rig::RigError,
    },
    #[error("moments/{camera}: the tracker")]
    Vision {
        camera: String,
        #[source]
        source: VisionError,
    },
    #[error("moments/{camera}")]
    Transport {
        camera: String,
        #[source]
        source: stereoscope_transport::TransportError,
    },
}

/// Runs until shutdown (or `max_frames`).
pub fn run(cfg: MomentsConfig, shutdown: Shutdown) -> Result<u64, MomentsError> {
    drive(MomentsService::setup(cfg)?, &shutdown)
}

/// A running moment worker: the frames it borrows, the [`Worker`] that tracks them, and the
/// outlet for its observations.
#[derive(Debug)]
pub struct MomentsService {
    cfg: MomentsConfig,
    node: ServiceNode,
    worker: Worker,
    frames: FrameSubscriber,
    observations: Outlet<Observation>,
    /// Previews for the viewer, on Zenoh only, and when the next is due.
    preview: stereoscope_transport::net::JsonPublisher,
    next_preview: std::time::Instant,
    last_sequence: Option<u64>,
    processed: u64,
}

impl MomentsService {
    /// Builds the worker from the rig's settings for this camera and joins the rig.
    pub fn setup(cfg: MomentsConfig) -> Result<Self, MomentsError> {
        let cam = cfg.camera.clone();
        let transport = |source| MomentsError::Transport {
            camera: cam.clone(),
            source,
        };
        let ctx = &cfg.ctx;
        let rig = &ctx.rig.name;
        let index = ctx
            .rig
            .camera_index(&cam)
            .ok_or_else(|| MomentsError::UnknownCamera {
                camera: cam.clone(),
            })?;
        let settings = ctx
            .rig
            .worker_settings(index)
            .map_err(|source| MomentsError::Rig {
                camera: cam.clone(),
                source,
            })?;
        let worker = Worker::new(settings, rig, &cam).map_err(|source| MomentsError::Vision {
            camera: cam.clone(),
            source,
        })?;
        let node =
            ServiceNode::start(ctx.node_spec(&format!("moments/{cam}"))).map_err(transport)?;
        let frames =
            FrameSubscriber::new(&node.iox, &iox_names::frames(rig, &cam)).map_err(transport)?;
        let observations = node
            .outlet(
                &iox_names::observations(rig, &cam),
                &[&iox_names::observations_ready(rig)],
                &keys::observations(rig, &cam),
            )
            .map_err(transport)?;
        let preview = stereoscope_transport::net::JsonPublisher::binary_low_priority(
            &node.session,
            &keys::preview(rig, &cam),
        )
        .map_err(transport)?;
        tracing::info!(camera = %cam, "moment worker ready");
        Ok(MomentsService {
            cfg,
            node,
            worker,
            frames,
            observations,
            preview,
            next_preview: std::time::Instant::now(),
            last_sequence: None,
            processed: 0,
        })
    }

    /// Counts the frames between the last one seen and this one as dropped: those released
    /// unread (`skipped`) and the gaps in the capture's numbering.
    fn count_gap(&mut self, sequence: u64, skipped: u64) {
        let counters = &mut self.node.counters;
        match self.last_sequence {
            Some(prev) if sequence > prev + 1 => {
                counters.lost_frames(&self.cfg.camera, prev + 1, sequence - 1)
            }
            // The first frame, or a capture restarted (its count starts again): what was
            // released unread is all that is known.
            _ => counters.dropped += skipped,
        }
        if self.last_sequence.is_some_and(|p| sequence <= p) {
            tracing::info!(camera = %self.cfg.camera, "frame sequence restarted at {sequence}");
        }
        self.last_sequence = Some(sequence);
    }
}

impl Service for MomentsService {
    type Summary = u64;
    type Error = MomentsError;

    /// Frames tracked.
    fn limit(&self) -> Option<u64> {
        self.cfg.max_frames
    }

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Waits up to 100 ms for the newest frame, tracks it in place and publishes its
    /// observation; a frame that fails its checks is counted, named and skipped.
    fn step(&mut self, _shutdown: &Shutdown) -> Result<Flow, MomentsError> {
        let got = match self.frames.next_newest(Duration::from_millis(100)) {
            Ok(got) => got,
            Err(e) => {
                self.node.counters.note::<(), _>(Err(e));
                return Ok(Flow::Continue);
            }
        };
        if let Some((sample, skipped)) = got {
            let header = *sample.user_header();
            self.count_gap(header.sequence, skipped);
            let result = self.worker.process_frame(&header, sample.payload());
            let counters = &mut self.node.counters;
            match result {
                Ok(mut obs) => {
                    obs.published_ns = now_ns();
                    self.observations.publish(&obs, counters);
                    self.processed += 1;
                    counters.processed = self.processed;
                    // The preview, when due and wanted, once the observation is out.
                    let now = std::time::Instant::now();
                    if now >= self.next_preview {
                        self.next_preview = now + Duration::from_millis(PREVIEW_EVERY_MS);
                        if self.preview.matching() {
                            let p = self.worker.preview(&header, sample.payload(), &obs);
                            drop(sample);
                            match p.map(|p| self.preview.put_bytes(p.to_binary())) {
                                Ok(Ok(())) => {}
                                Ok(Err(e)) => counters.note::<(), _>(Err(e)),
                                Err(e) => counters.reject("bad_frame", &e.to_string()),
                            }
                        }
                    }
                }
                Err(e) => {
                    let m = format!(
                        "frame {} of {}: {}",
                        header.sequence,
                        header.camera_id(),
                        stereoscope_transport::error_chain(&e)
                    );
                    tracing::warn!(camera = %self.cfg.camera, "rejected {m}");
                    counters.reject("bad_frame", &m);
                }
            }
        }
        if self.node.report_due() {
            let counters = &mut self.node.counters;
            if let Some(t) = self.worker.threshold() {
                counters.set(Detail::Threshold, t);
            }
            counters.set(Detail::Tracked, self.worker.tracked());
            counters.set(Detail::Masked, self.worker.masked());
            let (settled, widened) = self.worker.core_scans();
            counters.set(Detail::CoresSettled, settled);
            counters.set(Detail::CoresWidened, widened);
        }
        Ok(Flow::Continue)
    }

    fn summary(&self) -> u64 {
        self.processed
    }
}
