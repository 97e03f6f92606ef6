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
pub mod replay;
pub mod session;

use session::{POSES_CSV_HEADER, SESSION_SCHEMA, SessionInfo, csv_rows};
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::{Message, Observation, PoseFrame, now_ns};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_rig::Context;
use stereoscope_transport::iox::FrameSubscriber;
use stereoscope_transport::{ServiceNode, Shutdown, net};

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

enum Item {
    Poses(Vec<u8>, PoseFrame),
    Observation(Vec<u8>),
    Bad(String),
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
    // Connected before anything is written: a recorder that cannot reach the rig leaves no
    // half-made session folder in the way of the next try.
    let mut node = ServiceNode::start(ctx.node_spec("recorder"))?;
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
    let mut poses_out = Out::create(&cfg.out, "poses.jsonl")?;
    let mut obs_out = Out::create(&cfg.out, "observations.jsonl")?;
    let mut csv_out = Out::create(&cfg.out, "poses.csv")?;
    csv_out.buf.extend_from_slice(POSES_CSV_HEADER.as_bytes());

    // Raw frames, through shared memory — subscribed before the poses, so that every pose
    // recorded has its frames (a shared-memory subscriber gets every frame published after
    // it exists; creating one takes a while).
    let mut frame_subs = Vec::new();
    for cam in &cfg.frames {
        let sub = FrameSubscriber::new(&node.iox, &iox_names::frames(&rig, cam))?;
        let out = Out::create(&cfg.out, &format!("frames-{cam}.y4m"))?;
        frame_subs.push((cam.clone(), sub, out, Y4mState::default()));
    }
    let (tx, rx) = mpsc::sync_channel::<Item>(4096);
    let tx2 = tx.clone();
    let _p = net::subscribe(&node.session, &keys::poses(&rig), move |k, b| {
        let item = match PoseFrame::from_json(b) {
            Ok(f) => Item::Poses(b.to_vec(), f),
            Err(e) => Item::Bad(format!("{k}: {e}")),
        };
        let _ = tx.send(item);
    })?;
    let _o = net::subscribe(&node.session, &keys::all_observations(&rig), move |k, b| {
        let item = match Observation::from_json(b) {
            Ok(_) => Item::Observation(b.to_vec()),
            Err(e) => Item::Bad(format!("{k}: {e}")),
        };
        let _ = tx2.send(item);
    })?;
    tracing::info!(out = %cfg.out.display(), "recording");
    let (mut n_poses, mut n_obs) = (0u64, 0u64);
    let mut last_flush = Instant::now();
    loop {
        let stopping = shutdown.requested();
        let wait = if frame_subs.is_empty() { 20 } else { 1 };
        // Wait for one message, then take whatever else is queued, without waiting: the
        // frames below must be read at least every frame period.
        let first = rx.recv_timeout(Duration::from_millis(wait)).ok();
        let counters = &mut node.counters;
        for item in first
            .into_iter()
            .chain(std::iter::from_fn(|| rx.try_recv().ok()))
        {
            match item {
                Item::Poses(bytes, f) => {
                    poses_out.buf.extend_from_slice(&bytes);
                    poses_out.buf.push(b'\n');
                    csv_out.buf.extend_from_slice(csv_rows(&f).as_bytes());
                    n_poses += 1;
                }
                Item::Observation(bytes) => {
                    obs_out.buf.extend_from_slice(&bytes);
                    obs_out.buf.push(b'\n');
                    n_obs += 1;
                }
                Item::Bad(m) => {
                    counters.rejected += 1;
                    counters.last_error = Some(m);
                }
            }
            if last_flush.elapsed() >= cfg.flush_interval {
                break;
            }
        }
        for (cam, sub, out, state) in frame_subs.iter_mut() {
            // Every frame waiting, oldest first; a gap in the sequence numbers is a frame the
            // recorder was too slow for (counted as dropped).
            while let Ok(Some(s)) = sub.next_oldest() {
                let h = *s.user_header();
                if let Some(last) = state.last_sequence
                    && h.sequence > last + 1
                {
                    counters.dropped += h.sequence - last - 1;
                }
                state.last_sequence = Some(h.sequence);
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
                        state.push(&mut out.buf, &h, format, frame);
                    }
                    Err(e) => {
                        counters.rejected += 1;
                        counters.last_error = Some(format!("frame {} of {cam}: {e}", h.sequence));
                    }
                }
            }
        }
        if last_flush.elapsed() >= cfg.flush_interval || stopping {
            // Observations before the poses made from them: a crash between the two writes
            // leaves observations without poses, never poses without their observations.
            obs_out.flush()?;
            poses_out.flush()?;
            csv_out.flush()?;
            for (_, _, out, state) in frame_subs.iter_mut() {
                if stopping {
                    state.finish(&mut out.buf);
                }
                out.flush()?;
            }
            last_flush = Instant::now();
        }
        counters.processed = n_poses;
        counters
            .detail
            .insert("observations".into(), n_obs.to_string());
        node.tick();
        if stopping {
            break;
        }
    }
    node.finish();
    Ok((n_poses, n_obs))
}
