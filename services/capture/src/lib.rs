//! The capture service: one camera's frames into shared memory, once each, for the camera's
//! moment worker (and anything else on the PC) to read in place. The source is chosen by the
//! camera's `source` in the rig file (`docs/services.md`): a V4L2 camera, a
//! Y4M file or pipe, a PGM/PNG sequence, or the synthetic scene — whose ground truth goes out
//! on its own channel (iceoryx2 and Zenoh).
//!
//! Never blocks on a slow reader: subscribers keep the newest frames only (safe overflow), and
//! the worker counts what it missed from sequence gaps. Real-time sources are paced on a
//! fixed grid (slot n at n / fps since the Unix epoch; a frame that is late is published at
//! once, and a source more than a period behind skips to the current slot, counting the
//! skipped ones as dropped), the others as fast as the reader takes them.

pub mod cli;

use std::time::{Duration, Instant};
use stereoscope_proto::frame::FrameHeader;
use stereoscope_proto::messages::{Detail, Observation, SCHEMA_VERSION, Truth, now_ns};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_service::Context;
use stereoscope_sources::{FrameSource, OpenError, Read, SourceError};
use stereoscope_transport::iox::{FramePublisher, FrameStamp};
use stereoscope_transport::{Flow, Inlet, Outlet, Service, ServiceNode, Shutdown, drive};

/// What to run.
#[derive(Debug, Clone)]
pub struct CaptureConfig {
    pub ctx: Context,
    pub camera: String,
    /// Stop after this many frames (tests, benchmarks).
    pub max_frames: Option<u64>,
    /// Override the source's pacing: `Some(false)` reads files as fast as possible.
    pub realtime: Option<bool>,
}

#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The camera's source could not be opened (`stereoscope_sources::open`).
    #[error(transparent)]
    Open(#[from] OpenError),
    #[error("camera {camera}: the frame header")]
    Header {
        camera: String,
        #[source]
        source: stereoscope_proto::frame::FrameError,
    },
    #[error("camera {camera}")]
    Transport {
        camera: String,
        #[source]
        source: stereoscope_transport::TransportError,
    },
    #[error("camera {camera}: {source}")]
    Source {
        camera: String,
        #[source]
        source: SourceError,
    },
}

/// What a run did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CaptureSummary {
    pub frames: u64,
    pub bad_frames: u64,
}

/// Runs until the source ends, `max_frames`, or shutdown.
pub fn run(cfg: CaptureConfig, shutdown: Shutdown) -> Result<CaptureSummary, CaptureError> {
    drive(Capture::setup(cfg)?, &shutdown)
}

/// A running capture: its source, its frame publisher and truth outlet, and the pacing grid.
pub struct Capture {
    cfg: CaptureConfig,
    node: ServiceNode,
    source: Box<dyn FrameSource>,
    frames: FramePublisher,
    truth: Option<Outlet<Truth>>,
    header0: FrameHeader,
    realtime: bool,
    period_ns: Option<u64>,
    start: Instant,
    start_ns: u64,
    first_slot: u64,
    next_slot: u64,
    /// Frames read or skipped as bad so far (the source's frame index).
    index: u64,
    summary: CaptureSummary,
    /// With a lockstep source: the worker's observations, and the sequence number of the last
    /// frame sent, whose observation the next frame waits for.
    lockstep: Option<(Inlet<Observation>, Option<u64>)>,
}

/// The longest a lockstep frame waits for the worker's observation of the one before.
const LOCKSTEP_WAIT: Duration = Duration::from_secs(2);

impl std::fmt::Debug for Capture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Capture({}, {})",
            self.cfg.camera,
            self.source.describe()
        )
    }
}

impl Capture {
    /// Opens the source, checks its size against the rig, and joins the rig.
    pub fn setup(cfg: CaptureConfig) -> Result<Self, CaptureError> {
        let cam = cfg.camera.clone();
        let transport = |source| CaptureError::Transport {
            camera: cam.clone(),
            source,
        };
        let ctx = &cfg.ctx;
        let rig = &ctx.rig.name;
        // Under a launcher, the run's start (its session) gives its file sources one clock.
        let run_start_ns = std::env::var(stereoscope_proto::names::SESSION_ENV)
            .ok()
            .and_then(|s| s.parse().ok());
        let source = stereoscope_sources::open_in_run(&ctx.rig, &cam, run_start_ns)?;
        let (w, h) = source.size();
        let header0 = FrameHeader::new(&cam, source.format(), w, h).map_err(|source| {
            CaptureError::Header {
                camera: cam.clone(),
                source,
            }
        })?;
        let mut node =
            ServiceNode::start(ctx.node_spec(&format!("capture/{cam}"))).map_err(transport)?;
        let frames = FramePublisher::new(
            &node.iox,
            &iox_names::frames(rig, &cam),
            header0.payload_len() as usize,
        )
        .map_err(transport)?;
        let truth = match source.truth() {
            Some(_) => Some(
                node.outlet(&iox_names::truth(rig, &cam), &[], &keys::truth(rig, &cam))
                    .map_err(transport)?,
            ),
            None => None,
        };
        let lockstep = if source.lockstep() {
            let camera = cam.clone();
            let sub = Inlet::iox(
                &node.iox,
                &iox_names::observations(rig, &cam),
                rig,
                "observation",
            )
            .map_err(transport)?
            .expecting(move |_, o: &Observation| {
                if o.camera == camera {
                    Ok(())
                } else {
                    Err(format!("of camera {:?}, not {camera:?}", o.camera).into())
                }
            });
            Some((sub, None))
        } else {
            None
        };
        tracing::info!(camera = %cam, "capturing from {}", source.describe());
        node.counters.set(Detail::Source, source.describe());
        let realtime = cfg.realtime.unwrap_or(source.realtime());
        let period_ns = source
            .fps()
            .filter(|f| *f > 0.0 && f.is_finite())
            .map(|f| (1e9 / f).round().max(1.0) as u64);
        // Real-time frames sit on a grid shared by every camera of the same rate: slot n is
        // due at n · period since the Unix epoch, so cameras on one clock expose "together"
        // and a synthetic scene is rendered at the same instant in every camera.
        let start_ns = now_ns();
        let first_slot = period_ns.map(|p| start_ns / p + 1).unwrap_or(0);
        Ok(Capture {
            cfg,
            node,
            source,
            frames,
            truth,
            header0,
            realtime,
            period_ns,
            start: Instant::now(),
            start_ns,
            first_slot,
            next_slot: first_slot,
            index: 0,
            summary: CaptureSummary::default(),
            lockstep,
        })
    }

    /// With a lockstep source: waits (up to [`LOCKSTEP_WAIT`]) until the worker has published
    /// its observation of the last frame sent, so that no frame is overwritten unread.
    fn wait_for_worker(&mut self, shutdown: &Shutdown) {
        let Some((sub, Some(sent))) = &self.lockstep else {
            return;
        };
        let sent = *sent;
        let end = Instant::now() + LOCKSTEP_WAIT;
        let counters = &mut self.node.counters;
        while Instant::now() < end && !shutdown.requested() {
            while let Some(o) = sub.try_next(counters) {
                if o.sequence >= sent {
                    return;
                }
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        tracing::warn!(
            camera = %self.cfg.camera,
            "no observation of frame {sent} from the worker within {LOCKSTEP_WAIT:?}; going on"
        );
    }

    /// The next slot to fill, its scene time and its nominal timestamp, after waiting for it
    /// on the real-time grid; `None` when shutdown came while waiting.
    fn next_slot(&mut self, shutdown: &Shutdown) -> Option<(u64, f64, u64)> {
        match (self.realtime, self.period_ns) {
            (true, Some(p)) => {
                // More than a period behind (a source slower than its rate): skip to the
                // current slot rather than publish ever older frames; the gap shows in the
                // sequence numbers and is counted as dropped.
                let now_slot = (self.start_ns + self.start.elapsed().as_nanos() as u64) / p;
                if now_slot > self.next_slot + 1 {
                    self.node.counters.lost_frames(
                        &self.cfg.camera,
                        self.next_slot - self.first_slot,
                        now_slot - 1 - self.first_slot,
                    );
                    self.next_slot = now_slot;
                }
                let slot = self.next_slot;
                self.next_slot += 1;
                let due_ns = slot * p;
                let due = Duration::from_nanos(due_ns.saturating_sub(self.start_ns));
                let now = self.start.elapsed();
                if due > now && shutdown.sleep(due - now) {
                    return None;
                }
                Some((slot, due_ns as f64 / 1e9, due_ns))
            }
            (_, p) => Some((
                self.index,
                p.map(|p| (self.index * p) as f64 / 1e9).unwrap_or(0.0),
                now_ns(),
            )),
        }
    }
}

impl Service for Capture {
    type Summary = CaptureSummary;
    type Error = CaptureError;

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Reads one frame from the source into a loaned shared-memory frame and publishes it
    /// (with the scene's truth, for a synthetic source).
    fn step(&mut self, shutdown: &Shutdown) -> Result<Flow, CaptureError> {
        self.wait_for_worker(shutdown);
        let Some((slot, scene_time_s, nominal_ns)) = self.next_slot(shutdown) else {
            return Ok(Flow::Stop);
        };
        let cam = &self.cfg.camera;
        let transport = |source| CaptureError::Transport {
            camera: cam.clone(),
            source,
        };
        let mut header = self.header0;
        // Real-time frames are numbered by their slot, so skipped slots leave a gap.
        header.sequence = if self.realtime && self.period_ns.is_some() {
            slot - self.first_slot
        } else {
            self.index
        };
        header.timestamp_ns = nominal_ns;
        let mut loan = self.frames.loan(header).map_err(transport)?;
        self.index += 1;
        match self.source.read(slot, scene_time_s, loan.pixels_mut()) {
            Ok(Read::Frame {
                timestamp_ns,
                sequence,
            }) => {
                let sent = sequence.unwrap_or(header.sequence);
                loan.send(FrameStamp {
                    timestamp_ns,
                    sequence,
                })
                .map_err(transport)?;
                if let Some((_, last)) = &mut self.lockstep {
                    *last = Some(sent);
                }
            }
            Ok(Read::End) => {
                tracing::info!(camera = %cam, frames = self.index - 1, "end of source");
                return Ok(Flow::Stop);
            }
            Err(SourceError::BadFrame(bad)) => {
                let m = stereoscope_transport::error_chain(&bad);
                tracing::warn!(camera = %cam, "skipped a frame: {m}");
                self.node.counters.reject("bad_frame", &m);
                self.summary.bad_frames += 1;
                return Ok(Flow::Continue);
            }
            Err(source) => {
                return Err(CaptureError::Source {
                    camera: cam.clone(),
                    source,
                });
            }
        }
        if let (Some(truth), Some(outlet)) = (self.source.truth(), &mut self.truth) {
            let t = Truth {
                schema: SCHEMA_VERSION,
                camera: cam.clone(),
                sequence: header.sequence,
                timestamp_ns: nominal_ns,
                targets: truth,
            };
            outlet.publish(&t, &mut self.node.counters);
        }
        self.summary.frames += 1;
        self.node.counters.processed = self.summary.frames;
        Ok(Flow::Continue)
    }

    /// Frames published.
    fn limit(&self) -> Option<u64> {
        self.cfg.max_frames
    }

    fn summary(&self) -> CaptureSummary {
        self.summary
    }
}
