//! `stereoscope process`: a rig's recorded video fused offline, in process, as fast as the
//! machine goes — the pipeline the services run (`stereoscope_pipeline`: each camera's moment
//! worker, then fusion and bodies), over every camera's file source in step: frame k of every
//! camera makes set k. Each frame's time is its recorded `Xts` where the file has one, else its
//! index over the file's rate from 0. Deterministic: the same files give the same session,
//! byte for byte. Writes a session folder (`session.json`, `poses.jsonl`,
//! `observations.jsonl`) that `export`, `replay` and `calibrate` read (docs/recording.md).

use anyhow::{Context as _, bail};
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::{Message, Observation, PoseFrame, SCHEMA_VERSION};
use stereoscope_rig::Rig;
use stereoscope_rig::schema::SourceSpec;
use stereoscope_sources::Read;

#[derive(Debug, Clone)]
pub struct ProcessOptions {
    pub rig: PathBuf,
    pub out: PathBuf,
    /// Stop after this many frames of each camera.
    pub max_frames: Option<u64>,
}

/// What a run did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ProcessSummary {
    pub frames: u64,
    pub pose_frames: u64,
    pub object_poses: u64,
    pub seconds: f64,
    /// Seconds of video (frames over the first camera's rate) per second of processing.
    pub times_real_time: Option<f64>,
}

/// Runs the command; prints a progress line on `err` and the summary on `out`.
pub fn run(
    opts: &ProcessOptions,
    json: bool,
    out: &mut impl Write,
    err: &mut impl Write,
) -> anyhow::Result<usize> {
    let text = std::fs::read_to_string(&opts.rig)
        .with_context(|| format!("reading {}", opts.rig.display()))?;
    let rig = Rig::load(&opts.rig)?;
    for (i, c) in rig.spec.cameras.iter().enumerate() {
        if let Some(SourceSpec::V4l { device, .. }) = &c.source {
            bail!(
                "{}: camera[{i}] ({}) reads the live camera {device}: `process` reads recorded frames (Y4M files, image folders, the synthetic scene)",
                opts.rig.display(),
                c.id
            );
        }
    }
    let mut sources = Vec::new();
    let mut workers = Vec::new();
    for (i, c) in rig.cameras.iter().enumerate() {
        sources.push(stereoscope_sources::open(&rig, &c.id)?);
        workers.push(stereoscope_pipeline::worker::Worker::new(
            rig.worker_settings(i)?,
            &rig.name,
            &c.id,
        )?);
    }
    let fps = sources.first().and_then(|s| s.fps()).filter(|f| *f > 0.0);
    let period_ns = fps.map(|f| 1e9 / f);
    let mut fusion = stereoscope_pipeline::fusion::Fusion::of_rig(&rig);
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("making the folder {}", opts.out.display()))?;
    let file = |name: &str| -> anyhow::Result<std::io::BufWriter<std::fs::File>> {
        let p = opts.out.join(name);
        Ok(std::io::BufWriter::new(
            std::fs::File::create(&p).with_context(|| format!("writing {}", p.display()))?,
        ))
    };
    let mut poses_out = file("poses.jsonl")?;
    let mut obs_out = file("observations.jsonl")?;
    let buffers: Vec<Vec<u8>> = sources
        .iter()
        .map(|s| {
            let (w, h) = s.size();
            let bpp = match s.format() {
                PixelFormat::Gray8 => 1,
                PixelFormat::Gray16 => 2,
            };
            vec![0u8; w as usize * h as usize * bpp]
        })
        .collect();
    let mut buffers = buffers;
    let start = Instant::now();
    let mut last_said = Instant::now();
    let (mut frames, mut pose_frames, mut object_poses) = (0u64, 0u64, 0u64);
    let mut first_ns: Option<u64> = None;
    'frames: loop {
        if opts.max_frames.is_some_and(|m| frames >= m) {
            break;
        }
        let k = frames;
        let mut set: Vec<(usize, Observation)> = Vec::with_capacity(sources.len());
        let mut set_ns: Option<u64> = None;
        for (i, ((src, worker), buf)) in sources
            .iter_mut()
            .zip(workers.iter_mut())
            .zip(buffers.iter_mut())
            .enumerate()
        {
            let t_s = period_ns.map_or(0.0, |p| k as f64 * p * 1e-9);
            let read = src
                .read(k, t_s, buf)
                .with_context(|| format!("camera {}: frame {k}", rig.cameras[i].id))?;
            let (ts, seq) = match read {
                Read::End => break 'frames,
                Read::Frame {
                    timestamp_ns,
                    sequence,
                } => (
                    timestamp_ns.unwrap_or_else(|| period_ns.map_or(k, |p| (k as f64 * p) as u64)),
                    sequence.unwrap_or(k),
                ),
            };
            let (w, h) = src.size();
            let mut header = FrameHeader::new(&rig.cameras[i].id, src.format(), w, h)?;
            header.sequence = seq;
            header.timestamp_ns = ts;
            header.published_ns = ts;
            let mut obs = worker
                .process_frame(&header, buf)
                .with_context(|| format!("camera {}: frame {k}", rig.cameras[i].id))?;
            // Offline, nothing is published: the times are the frame's.
            obs.frame_published_ns = ts;
            obs.published_ns = ts;
            obs_out.write_all(&obs.to_json())?;
            obs_out.write_all(b"\n")?;
            set_ns = Some(set_ns.map_or(ts, |s: u64| s.min(ts)));
            set.push((i, obs));
        }
        let ts = set_ns.unwrap_or(0);
        first_ns.get_or_insert(ts);
        let cameras: Vec<String> = set
            .iter()
            .map(|(i, _)| rig.cameras[*i].id.clone())
            .collect();
        let (poses, bodies) = fusion.fuse(&set, ts);
        let models = fusion.take_models();
        let frame = PoseFrame {
            schema: SCHEMA_VERSION,
            rig: rig.name.clone(),
            sequence: k,
            timestamp_ns: ts,
            frame_published_ns: ts,
            published_ns: ts,
            cameras,
            poses,
            bodies,
            models,
        };
        frames += 1;
        if !frame.poses.is_empty() || !frame.bodies.is_empty() {
            pose_frames += 1;
            object_poses += frame.poses.len() as u64;
        }
        poses_out.write_all(&frame.to_json())?;
        poses_out.write_all(b"\n")?;
        if last_said.elapsed().as_secs_f64() >= 1.0 {
            last_said = Instant::now();
            let _ = write!(
                err,
                "\rprocessing: {frames} frames, {:.0} frames/s",
                frames as f64 / start.elapsed().as_secs_f64()
            );
        }
    }
    poses_out.flush()?;
    obs_out.flush()?;
    let info = serde_json::json!({
        "schema": stereoscope_recorder::session::SESSION_SCHEMA,
        "rig": rig.name,
        "started_ns": first_ns.unwrap_or(0),
        "rig_file": text,
    });
    std::fs::write(opts.out.join("session.json"), info.to_string())
        .with_context(|| format!("writing {}", opts.out.join("session.json").display()))?;
    let seconds = start.elapsed().as_secs_f64();
    let summary = ProcessSummary {
        frames,
        pose_frames,
        object_poses,
        seconds,
        times_real_time: fps.map(|f| frames as f64 / f / seconds.max(1e-9)),
    };
    let _ = writeln!(err);
    if json {
        writeln!(out, "{}", serde_json::to_string(&summary)?)?;
    } else {
        writeln!(
            out,
            "{frames} frames of {} cameras in {seconds:.2} s{}: {pose_frames} pose frames, {object_poses} object poses, in {}",
            rig.cameras.len(),
            summary
                .times_real_time
                .map(|x| format!(" ({x:.1}× real time)"))
                .unwrap_or_default(),
            opts.out.display()
        )?;
    }
    if frames == 0 {
        bail!("{}: no frame read", opts.rig.display());
    }
    Ok(0)
}
