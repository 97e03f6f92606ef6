//! The recorder service and what reads its sessions: `stereoscope replay` and `stereoscope
//! export` (`docs/recording.md`).
//!
//! The recorder subscribes to the rig's pose frames and every camera's observations on Zenoh
//! (and, for cameras named with `--frames`, to their raw frames in shared memory on this PC),
//! and appends them to a session folder ([`session`]). Lines are gathered in memory and
//! written whole every `flush_interval` (default 200 ms), then synced to disk: a crash or a
//! power cut loses at most the last interval, and a file never ends inside a record except
//! when the process dies in the middle of that one write, which readers detect and skip.

pub mod c3d;
pub mod cli;
pub mod export;
pub mod replay;
pub mod session;

use session::{POSES_CSV_HEADER, SESSION_SCHEMA, SessionInfo, csv_rows};
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::{Detail, Observation, PoseFrame, now_ns};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_service::Context;
use stereoscope_transport::iox::FrameSubscriber;
use stereoscope_transport::{Flow, Inlet, Service, ServiceNode, Shutdown, drive};

#[derive(Debug, Clone)]
pub struct RecorderConfig {
    pub ctx: Context,
    /// The session folder (created; must not exist or be empty).
    pub out: PathBuf,
    pub flush_interval: Duration,
    /// Cameras (on this PC) whose raw frames to record as Y4M.
    pub frames: Vec<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum RecorderError {
    #[error("recorder: {} exists and is not empty: give a new session folder", .0.display())]
    NotEmpty(std::path::PathBuf),
    #[error("recorder: {}", .dir.display())]
    CreateDir {
        dir: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("recorder: reading the rig {}", .file.display())]
    ReadRig {
        file: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("recorder: encoding session.json")]
    Encode(#[from] serde_json::Error),
    #[error("recorder")]
    Transport(#[from] stereoscope_transport::TransportError),
    #[error("recorder: writing {file}: {source}")]
    Write {
        file: String,
        #[source]
        source: std::io::Error,
    },
}

struct Out {
    name: String,
    file: File,
    buf: Vec<u8>,
}

impl Out {
    fn create(dir: &std::path::Path, name: &str) -> Result<Out, RecorderError> {
        let path = dir.join(name);
        let file = File::create(&path).map_err(|e| RecorderError::Write {
            file: path.display().to_string(),
            source: e,
        })?;
        Ok(Out {
            name: path.display().to_string(),
            file,
            buf: Vec::new(),
        })
    }

    fn flush(&mut self) -> Result<(), RecorderError> {
        if self.buf.is_empty() {
            return Ok(());
        }
        let w = |e| RecorderError::Write {
            file: self.name.clone(),
            source: e,
        };
        self.file.write_all(&self.buf).map_err(w)?;
        self.file.sync_data().map_err(|e| RecorderError::Write {
            file: self.name.clone(),
            source: e,
        })?;
        self.buf.clear();
        Ok(())
    }
}

/// A camera's Y4M file being written. The stream header needs the frame rate, which the first
/// two frames give (their sequence numbers and exposure times), so the first frame waits for
/// the second; each frame line carries `Xts=<timestamp_ns> Xseq=<sequence>` for replay.
#[derive(Default)]
struct Y4mState {
    header_done: bool,
    last_sequence: Option<u64>,
    /// The first frame (its FRAME line and luma), its sequence and time, and the header's
    /// fields.
    first: Option<(Vec<u8>, u64, u64, String)>,
}

impl Y4mState {
    fn header(h: &FrameHeader, format: PixelFormat, rate: &str) -> String {
        let c = if format == PixelFormat::Gray16 {
            "mono16"
        } else {
            "mono"
        };
        format!(
            "YUV4MPEG2 W{} H{} F{rate} Ip A1:1 C{c}\n",
            h.width, h.height
        )
    }

    fn push(&mut self, buf: &mut Vec<u8>, h: &FrameHeader, format: PixelFormat, frame: Vec<u8>) {
        if self.header_done {
            buf.extend_from_slice(&frame);
            return;
        }
        match self.first.take() {
            None => {
                self.first = Some((
                    frame,
                    h.sequence,
                    h.timestamp_ns,
                    Self::header(h, format, "30:1"),
                ))
            }
            Some((first, seq0, t0, fallback)) => {
                let (dseq, dt) = (
                    h.sequence.saturating_sub(seq0),
                    h.timestamp_ns.saturating_sub(t0),
                );
                let header = if dseq > 0 && dt > 0 {
                    // Frames per second in thousandths.
                    let milli = (dseq as f64 * 1e12 / dt as f64).round().max(1.0) as u64;
                    Self::header(h, format, &format!("{milli}:1000"))
                } else {
                    fallback
                };
                buf.extend_from_slice(header.as_bytes());
                buf.extend_from_slice(&first);
                buf.extend_from_slice(&frame);
                self.header_done = true;
            }
        }
    }

    /// At the end: a lone first frame goes out with a nominal 30 frames/s.
    fn finish(&mut self, buf: &mut Vec<u8>) {
        if let Some((first, _, _, header)) = self.first.take() {
            buf.extend_from_slice(header.as_bytes());
            buf.extend_from_slice(&first);
            self.header_done = true;
        }
    }
}

/// Records until shutdown; returns `(pose frames, observations)` written.
pub fn run(cfg: RecorderConfig, shutdown: Shutdown) -> Result<(u64, u64), RecorderError> {
    drive(Recorder::setup(cfg)?, &shutdown)
}

/// One camera's raw frames being recorded.
struct FrameTrack {
    camera: String,
    sub: FrameSubscriber,
    out: Out,
    y4m: Y4mState,
}

/// A running recorder: its session files and the subscriptions that feed them.
pub struct Recorder {
    cfg: RecorderConfig,
    node: ServiceNode,
    /// Only messages that decode within the protocol's limits and name this rig are recorded
    /// (a session replays and exports what it holds), each as the bytes that came.
    poses: Inlet<PoseFrame>,
    observations: Inlet<Observation>,
    /// Of the inlets' overflow, what is already counted as dropped.
    overflow_counted: u64,
    poses_out: Out,
    obs_out: Out,
    csv_out: Out,
    frames: Vec<FrameTrack>,
    n_poses: u64,
    n_obs: u64,
    last_flush: Instant,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Recorder({})", self.cfg.out.display())
    }
}

impl Recorder {
    /// Joins the rig, then makes the session folder and its files and subscribes.
    pub fn setup(cfg: RecorderConfig) -> Result<Self, RecorderError> {
        let ctx = &cfg.ctx;
        let rig = ctx.rig.name.clone();
        if cfg.out.exists()
            && std::fs::read_dir(&cfg.out)
                .map(|mut d| d.next().is_some())
                .unwrap_or(true)
        {
            return Err(RecorderError::NotEmpty(cfg.out.clone()));
        }
        let rig_text =
            std::fs::read_to_string(&ctx.rig_path).map_err(|source| RecorderError::ReadRig {
                file: ctx.rig_path.clone(),
                source,
            })?;
        // Connected before anything is written: a recorder that cannot reach the rig leaves
        // no half-made session folder in the way of the next try.
        let node = ServiceNode::start(stereoscope_transport::NodeSpec {
            exclusive: stereoscope_transport::Exclusive::No,
            ..ctx.node_spec("recorder")
        })?;
        let create = |source| RecorderError::CreateDir {
            dir: cfg.out.clone(),
            source,
        };
        std::fs::create_dir_all(&cfg.out).map_err(create)?;
        let info = SessionInfo {
            schema: SESSION_SCHEMA,
            rig: rig.clone(),
            started_ns: now_ns(),
            rig_file: rig_text,
        };
        // session.json whole, through a temporary name.
        let tmp = cfg.out.join("session.json.tmp");
        let text = serde_json::to_vec_pretty(&info)?;
        std::fs::write(&tmp, text)
            .and_then(|_| std::fs::rename(&tmp, cfg.out.join("session.json")))
            .map_err(create)?;
        let poses_out = Out::create(&cfg.out, "poses.jsonl")?;
        let obs_out = Out::create(&cfg.out, "observations.jsonl")?;
        let mut csv_out = Out::create(&cfg.out, "poses.csv")?;
        csv_out.buf.extend_from_slice(POSES_CSV_HEADER.as_bytes());

        // Raw frames, through shared memory — subscribed before the poses, so that every pose
        // recorded has its frames (a shared-memory subscriber gets every frame published
        // after it exists; creating one takes a while).
        let mut frames = Vec::new();
        for cam in &cfg.frames {
            frames.push(FrameTrack {
                camera: cam.clone(),
                sub: FrameSubscriber::new(&node.iox, &iox_names::frames(&rig, cam))?,
                out: Out::create(&cfg.out, &format!("frames-{cam}.y4m"))?,
                y4m: Y4mState::default(),
            });
        }
        let poses = Inlet::zenoh(
            &node.session,
            &[keys::poses(&rig)],
            &rig,
            "pose frame",
            4096,
        )?;
        let obs_rig = rig.clone();
        let observations = Inlet::zenoh(
            &node.session,
            &[keys::all_observations(&rig)],
            &rig,
            "observation",
            4096,
        )?
        .expecting(move |key, o: &Observation| {
            if key == keys::observations(&obs_rig, &o.camera) {
                Ok(())
            } else {
                Err(format!("of camera {:?} on another camera's key", o.camera).into())
            }
        });
        tracing::info!(out = %cfg.out.display(), "recording");
        Ok(Recorder {
            cfg,
            node,
            poses,
            observations,
            overflow_counted: 0,
            poses_out,
            obs_out,
            csv_out,
            frames,
            n_poses: 0,
            n_obs: 0,
            last_flush: Instant::now(),
        })
    }

    /// Takes the messages queued (waiting up to `wait` for the first pose frame) into the
    /// buffers, until a flush is due; how many it took.
    fn take_messages(&mut self, wait: Duration) -> usize {
        let mut taken = 0;
        let counters = &mut self.node.counters;
        let first = self.poses.next_with_bytes(wait, counters);
        let mut poses = first.into_iter().chain(std::iter::from_fn(|| {
            self.poses.next_with_bytes(Duration::ZERO, counters)
        }));
        for (f, bytes) in poses.by_ref() {
            self.poses_out.buf.extend_from_slice(&bytes);
            self.poses_out.buf.push(b'\n');
            self.csv_out.buf.extend_from_slice(csv_rows(&f).as_bytes());
            self.n_poses += 1;
            taken += 1;
            if self.last_flush.elapsed() >= self.cfg.flush_interval {
                return taken;
            }
        }
        drop(poses);
        while let Some((_, bytes)) = self.observations.next_with_bytes(Duration::ZERO, counters) {
            self.obs_out.buf.extend_from_slice(&bytes);
            self.obs_out.buf.push(b'\n');
            self.n_obs += 1;
            taken += 1;
            if self.last_flush.elapsed() >= self.cfg.flush_interval {
                break;
            }
        }
        taken
    }

    /// Every frame waiting, oldest first, into its camera's Y4M buffer; a gap in the
    /// sequence numbers is a frame the recorder was too slow for (counted as dropped).
    fn take_frames(&mut self) {
        let counters = &mut self.node.counters;
        for t in self.frames.iter_mut() {
            while let Ok(Some(s)) = t.sub.next_oldest() {
                let h = *s.user_header();
                if let Some(last) = t.y4m.last_sequence
                    && h.sequence > last + 1
                {
                    counters.lost_frames(&t.camera, last + 1, h.sequence - 1);
                }
                t.y4m.last_sequence = Some(h.sequence);
                match h.validate(s.payload().len()) {
                    Ok(format) => {
                        let mut frame =
                            format!("FRAME Xts={} Xseq={}\n", h.timestamp_ns, h.sequence)
                                .into_bytes();
                        let row = h.width as usize * format.bytes_per_pixel();
                        for y in 0..h.height as usize {
                            let start = y * h.stride_bytes as usize;
                            frame.extend_from_slice(&s.payload()[start..start + row]);
                        }
                        t.y4m.push(&mut t.out.buf, &h, format, frame);
                    }
                    Err(e) => {
                        counters.reject(
                            "bad_frame",
                            &format!("frame {} of {}: {e}", h.sequence, t.camera),
                        );
                    }
                }
            }
        }
    }

    /// Writes and syncs every buffer; `last` also writes a camera's lone first frame.
    fn flush(&mut self, last: bool) -> Result<(), RecorderError> {
        // Observations before the poses made from them: a crash between the two writes
        // leaves observations without poses, never poses without their observations.
        self.obs_out.flush()?;
        self.poses_out.flush()?;
        self.csv_out.flush()?;
        for t in self.frames.iter_mut() {
            if last {
                t.y4m.finish(&mut t.out.buf);
            }
            t.out.flush()?;
        }
        self.last_flush = Instant::now();
        Ok(())
    }

    fn count(&mut self) {
        let counters = &mut self.node.counters;
        // Messages that came while 4096 were queued are lost: counted as dropped.
        let overflowed = self.poses.overflowed() + self.observations.overflowed();
        counters.dropped += overflowed.saturating_sub(self.overflow_counted);
        self.overflow_counted = overflowed;
        // Every message written counts: a recording of observations alone (no fusion running)
        // shows its rate too.
        counters.processed = self.n_poses + self.n_obs;
        counters.set(Detail::Observations, self.n_obs);
    }
}

impl Service for Recorder {
    type Summary = (u64, u64);
    type Error = RecorderError;

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    /// Waits for one message (1 ms when recording frames, which must be read at least every
    /// frame period; 20 ms otherwise), buffers what is queued, and flushes when due.
    fn step(&mut self, _shutdown: &Shutdown) -> Result<Flow, RecorderError> {
        let wait = if self.frames.is_empty() { 20 } else { 1 };
        self.take_messages(Duration::from_millis(wait));
        self.take_frames();
        if self.last_flush.elapsed() >= self.cfg.flush_interval {
            self.flush(false)?;
        }
        self.count();
        Ok(Flow::Continue)
    }

    /// Takes what is still queued and writes everything.
    fn stop(&mut self) -> Result<(), RecorderError> {
        // No more messages after these: the queues below end.
        self.poses.close();
        self.observations.close();
        while self.take_messages(Duration::ZERO) > 0 {
            self.flush(false)?;
        }
        self.take_frames();
        self.flush(true)?;
        self.count();
        Ok(())
    }

    fn summary(&self) -> (u64, u64) {
        (self.n_poses, self.n_obs)
    }
}
