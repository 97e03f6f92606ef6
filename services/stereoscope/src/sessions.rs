//! `stereoscope replay` and `stereoscope export`: a recorded session fused again (its sets, or
//! its frames through the chain), compared with what it recorded, or written in another format.

use crate::progress::Progress;
use anyhow::Context as _;
use std::path::PathBuf;
use stereoscope_launcher::{LaunchConfig, run};
use stereoscope_transport::Shutdown;
use stereoscope_transport::inlet::Admission;

/// `stereoscope replay`.
pub fn replay(
    session: PathBuf,
    publish: Option<String>,
    max_speed: bool,
    json: bool,
) -> anyhow::Result<usize> {
    use stereoscope_recorder::replay::{refuse, schedule};
    use stereoscope_recorder::session::Session;
    let s = Session::read(&session)?;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(endpoint) = publish {
        use stereoscope_proto::messages::Message;
        use stereoscope_transport::net::{self, JsonPublisher, ZenohSpec};
        let zs = net::open(&ZenohSpec::client_of(&endpoint))?;
        let mut pubs = std::collections::HashMap::new();
        let start = std::time::Instant::now();
        let plan = schedule(&s);
        let total = plan.len();
        let mut progress = Progress::new();
        for (i, (delay_ns, o)) in plan.into_iter().enumerate() {
            if !max_speed {
                let due = std::time::Duration::from_nanos(delay_ns);
                if let Some(wait) = due.checked_sub(start.elapsed()) {
                    std::thread::sleep(wait);
                }
            }
            if !pubs.contains_key(&o.camera) {
                let key = stereoscope_proto::names::zenoh::observations(&o.rig, &o.camera);
                pubs.insert(o.camera.clone(), JsonPublisher::new(&zs, &key)?);
            }
            if let Some(p) = pubs.get(&o.camera) {
                p.put_bytes(o.to_json())?;
            }
            progress.update(
                &format!("publishing observations {}/{total}", i + 1),
                i + 1 == total,
            );
        }
        progress.finish();
    }
    let mut progress = Progress::new();
    let r = refuse(&s, |done, total| {
        progress.update(
            &format!("re-fusing pose frames {done}/{total}"),
            done == total,
        );
    })
    .with_context(|| session.display().to_string())?;
    progress.finish();
    if json {
        let v = serde_json::json!({
            "frames": r.frames,
            "identical": r.identical,
            "identical_last_frames": r.identical_last_frames,
            "incomplete": r.incomplete,
            "renumbered": r.renumbered,
            "first_difference": r.first_difference,
            "reformed": r.reformed,
            "gaps": r.gaps,
            "heading_reversed": r.heading_reversed,
        });
        println!("{v}");
    } else {
        println!(
            "{} of {} pose frames reproduced exactly ({} lacked recorded observations); the last {} all identical",
            r.identical, r.frames, r.incomplete, r.identical_last_frames
        );
        if !r.renumbered.is_empty() {
            let pairs: Vec<String> = r
                .renumbered
                .iter()
                .take(8)
                .map(|(a, b)| format!("{a} as {b}"))
                .collect();
            println!(
                "object ids renumbered ({} objects: the recording began after fusion started): {}{}",
                r.renumbered.len(),
                pairs.join(", "),
                if r.renumbered.len() > 8 { ", …" } else { "" }
            );
        }
        if !r.reformed.is_empty() {
            println!(
                "{} pose frame(s) fusion published were not recorded ({}): their sets were formed again from the recorded observations and fused in their place",
                r.reformed.len(),
                list_of(r.reformed.iter().map(u64::to_string))
            );
        }
        if !r.gaps.is_empty() {
            println!(
                "pose frames missing from the recording whose sets could not be formed again (frames after them may differ): {}",
                list_of(r.gaps.iter().map(|(a, b)| if a == b {
                    a.to_string()
                } else {
                    format!("{a}–{b}")
                }))
            );
        }
        if !r.heading_reversed.is_empty() {
            println!(
                "undirected headings reversed along the same axis (the sense is chosen when fusion first sees an object; the recording began after fusion started): objects {}",
                list_of(r.heading_reversed.iter().map(u32::to_string))
            );
        }
        if let Some(d) = &r.first_difference {
            println!("first difference: {d}");
        }
    }
    Ok(if r.identical == r.frames { 0 } else { 1 })
}

/// Up to eight items, comma-separated, then "…" and how many in all.
fn list_of(items: impl ExactSizeIterator<Item = String>) -> String {
    let n = items.len();
    let shown: Vec<String> = items.take(8).collect();
    if n > 8 {
        format!("{}, … ({n} in all)", shown.join(", "))
    } else {
        shown.join(", ")
    }
}

/// `stereoscope replay SESSION --rig RIG --out FILE`: the recorded observations fused again
/// with another rig file of the same cameras (a new calibration), the pose frames written as
/// JSON lines (the recorder's `poses.jsonl` form, so `calibrate floor --poses` and `export`
/// read them).
pub fn refuse_with_rig(session: PathBuf, rig: PathBuf, out: PathBuf) -> anyhow::Result<usize> {
    use std::io::Write as _;
    use stereoscope_proto::messages::Message;
    let s = stereoscope_recorder::session::Session::read(&session)?;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    let new_rig = stereoscope_rig::Rig::load(&rig)?;
    let recorded = stereoscope_rig::Rig::from_recording(&s.info.rig_file)?;
    for c in &recorded.cameras {
        if new_rig.camera_index(&c.id).is_none() {
            anyhow::bail!(
                "{}: no camera {:?}, which {} recorded (its cameras: {:?})",
                rig.display(),
                c.id,
                session.display(),
                new_rig.cameras.iter().map(|c| &c.id).collect::<Vec<_>>()
            );
        }
    }
    let mut text = Vec::new();
    let mut progress = Progress::new();
    let r = stereoscope_recorder::replay::refuse_with(
        &s,
        &new_rig,
        |done, total| {
            progress.update(
                &format!("re-fusing pose frames {done}/{total}"),
                done == total,
            );
        },
        |f| {
            text.extend_from_slice(&f.to_json());
            text.push(b'\n');
        },
    )
    .with_context(|| session.display().to_string())?;
    progress.finish();
    let mut file =
        std::fs::File::create(&out).with_context(|| format!("writing {}", out.display()))?;
    file.write_all(&text)
        .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{} pose frames re-fused with {} into {} ({} lacked recorded observations)",
        r.frames,
        rig.display(),
        out.display(),
        r.incomplete
    );
    Ok(0)
}

/// `stereoscope replay SESSION --frames`: the recorded frames through the real services (a
/// launcher with capture from the Y4M files, moment workers and fusion, on a router of its
/// own), then the poses compared with the recorded ones.
pub fn replay_frames(
    session: PathBuf,
    publish: Option<String>,
    speed: f64,
    json: bool,
    program: anyhow::Result<Vec<String>>,
) -> anyhow::Result<usize> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(anyhow::anyhow!(
            "--speed {speed}: must be a number above zero"
        ));
    }
    use std::sync::{Arc, Mutex};
    use stereoscope_proto::messages::PoseFrame;
    use stereoscope_recorder::replay::{compare_frames, frames_rig};
    use stereoscope_recorder::session::Session;
    use stereoscope_rig::Rig;
    use stereoscope_service::Context;
    use stereoscope_transport::net::{self, ZenohSpec};
    let s = Session::read(&session)?;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    let listen = match publish {
        Some(e) => e,
        None => format!("tcp/127.0.0.1:{}", net::free_loopback_port()?),
    };
    let prefix = format!("stsc_replay{}_", std::process::id());
    // The services take a second or two to start: the session's start replays 3 s from now.
    let start_wall_ns = stereoscope_proto::messages::now_ns() + 3_000_000_000;
    let text = frames_rig(&s, &session, start_wall_ns, speed, &listen, &prefix)
        .with_context(|| session.display().to_string())?;
    let work = std::env::temp_dir().join(format!("stereoscope-replay-{}", std::process::id()));
    std::fs::create_dir_all(&work).with_context(|| work.display().to_string())?;
    let rig_path = work.join("replay-rig.toml");
    std::fs::write(&rig_path, &text).with_context(|| rig_path.display().to_string())?;
    let rig = Rig::load(&rig_path).map_err(|e| anyhow::anyhow!("the replay rig: {e}"))?;
    let client = ZenohSpec::client_of(&stereoscope_rig::security::local_endpoint(&listen));
    let ctx = Context {
        rig_path,
        rig: rig.clone(),
        host: "replay".into(),
        iox_prefix: prefix,
        zenoh: client.clone(),
    };
    let shutdown = Shutdown::on_signals()?;
    let launcher = {
        let lc = LaunchConfig {
            ctx,
            program: program?,
            env: Vec::new(),
            router: true,
            until_sources_end: true,
        };
        let stop = shutdown.clone();
        std::thread::spawn(move || run(lc, stop))
    };
    // The router starts in the launcher's thread; subscribe once it is up.
    let replayed: Arc<Mutex<Vec<PoseFrame>>> = Arc::default();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let zs = loop {
        match net::open(&client) {
            Ok(z) => break Some(z),
            Err(_) if std::time::Instant::now() < deadline && !launcher.is_finished() => {
                std::thread::sleep(std::time::Duration::from_millis(100))
            }
            Err(e) => {
                eprintln!("no replay router at {listen}: {e}");
                break None;
            }
        }
    };
    // Every service's last health report: what each dropped, rejected or got late, so a
    // mismatch can be traced to the frame losses behind it.
    let health: Arc<
        Mutex<std::collections::BTreeMap<String, stereoscope_proto::messages::Health>>,
    > = Arc::default();
    // Messages refused on the way (another rig's, or ones that do not decode): the first
    // ten, said after the replay.
    let refused = Arc::new(Mutex::new(Vec::<stereoscope_transport::Refusal>::new()));
    let _health_sub = match &zs {
        Some(z) => {
            let sink = health.clone();
            let keep = refused.clone();
            Some(stereoscope_transport::inlet::listen(
                z,
                &[stereoscope_proto::names::zenoh::all_health(&rig.name)],
                Admission::<stereoscope_proto::messages::Health>::new(&rig.name, "health"),
                move |h, _| {
                    if let Ok(mut m) = sink.lock() {
                        m.insert(h.service.clone(), h);
                    }
                },
                move |r| keep_first(&keep, r),
            )?)
        }
        None => None,
    };
    let _sub = match &zs {
        Some(z) => {
            let sink = replayed.clone();
            let keep = refused.clone();
            Some(stereoscope_transport::inlet::listen(
                z,
                &[stereoscope_proto::names::zenoh::poses(&rig.name)],
                Admission::<PoseFrame>::new(&rig.name, "pose frame"),
                move |p, _| {
                    if let Ok(mut v) = sink.lock() {
                        v.push(p);
                    }
                },
                move |r| keep_first(&keep, r),
            )?)
        }
        None => {
            shutdown.request();
            None
        }
    };
    let total = s.poses.len();
    let mut progress = Progress::new();
    loop {
        let done = launcher.is_finished();
        let n = replayed.lock().map(|v| v.len()).unwrap_or(0);
        progress.update(
            &format!("replaying frames: {n} pose frames (recorded: {total})"),
            done,
        );
        if done {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    progress.finish();
    let result = launcher
        .join()
        .map_err(|_| anyhow::anyhow!("the launcher thread panicked"));
    let _ = std::fs::remove_dir_all(&work);
    result??;
    let replayed = replayed.lock().map(|v| v.clone()).unwrap_or_default();
    if total == 0 {
        // Nothing recorded to compare with: the sets were formed as live fusion forms them.
        let objects: usize = replayed.iter().map(|p| p.poses.len()).sum();
        if json {
            println!(
                "{}",
                serde_json::json!({"replayed_frames": replayed.len(), "recorded_frames": 0, "objects": objects})
            );
        } else {
            println!(
                "{} pose frames ({objects} object poses) from the frames; the session recorded no pose frames to compare with",
                replayed.len()
            );
        }
        if replayed.is_empty() {
            anyhow::bail!(
                "{}: no pose frame formed from its frames (is any marker seen by two cameras?)",
                session.display()
            );
        }
        return Ok(0);
    }
    let c = compare_frames(&s.poses, &replayed);
    let losses = health.lock().map(|h| losses(&h)).unwrap_or_default();
    for r in refused.lock().map(|v| v.clone()).unwrap_or_default() {
        eprintln!("refused ({}): {}", r.reason, r.message);
    }
    if json {
        let mut v = serde_json::to_value(&c)?;
        v["losses"] = serde_json::json!(losses);
        println!("{v}");
    } else {
        println!(
            "{} pose frames from the replayed frames, {} at the time of a recorded one ({} recorded); {} objects compared, {} unmatched, {} identical; position difference RMS {:.3} mm, largest {:.3} mm; the last {} frames identical",
            c.replayed_frames,
            c.matched_frames,
            c.recorded_frames,
            c.objects_compared,
            c.objects_unmatched,
            c.objects_identical,
            c.position_rms_mm,
            c.position_max_mm,
            c.identical_last_frames
        );
        for m in &c.missing {
            println!(
                "not replayed: recorded pose frame {} (sequence {}, cameras {}, timestamp_ns {})",
                m.index,
                m.sequence,
                m.cameras.join(","),
                m.timestamp_ns
            );
        }
        for l in &losses {
            println!("lost in the replay: {l}");
        }
    }
    Ok(if c.matched_frames > 0 { 0 } else { 1 })
}

/// What the services' last health reports say was lost: frames a worker or the recorder
/// dropped, messages rejected, observations fusion got too late for their set.
fn losses(
    health: &std::collections::BTreeMap<String, stereoscope_proto::messages::Health>,
) -> Vec<String> {
    health.values().flat_map(|h| h.losses()).collect()
}

/// `stereoscope export --format csv|bodies-csv|models-csv|markers-csv|c3d`.
pub fn export(
    session: PathBuf,
    format: &str,
    out: Option<PathBuf>,
    fill_gaps: Option<usize>,
) -> anyhow::Result<usize> {
    if !["csv", "bodies-csv", "models-csv", "markers-csv", "c3d"].contains(&format) {
        anyhow::bail!("--format {format}: csv, bodies-csv, models-csv, markers-csv or c3d");
    }
    if fill_gaps.is_some() && !["c3d", "markers-csv"].contains(&format) {
        anyhow::bail!(
            "--fill-gaps: only --format c3d and markers-csv fill gaps (their frames are on one clock)"
        );
    }
    if format == "c3d" && out.is_none() {
        anyhow::bail!("--format c3d needs --out FILE (it is binary)");
    }
    let s = stereoscope_recorder::session::Session::read(&session)?;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    // The summary is said only once the file is written: a failed --out prints no success.
    let (bytes, summary) = if format == "c3d" {
        let e = stereoscope_recorder::export::export_c3d(&s, fill_gaps)
            .with_context(|| session.display().to_string())?;
        let bytes = stereoscope_recorder::c3d::write(&e.trial)
            .map_err(|e| anyhow::anyhow!("{}: {e}", session.display()))?;
        let summary = format!(
            "{} frames at {:.3} Hz, {} markers, from {} pose frames{}",
            e.trial.frames.len(),
            e.trial.frame_rate_hz,
            e.trial.labels.len(),
            e.pose_frames,
            if e.merged > 0 {
                format!(
                    " ({} poses closer than half a frame to another dropped)",
                    e.merged
                )
            } else {
                String::new()
            }
        );
        let summary = match fill_gaps {
            Some(max) => {
                use stereoscope_bodies::gaps::FillMethod;
                let rigid = e.filled.iter().filter(|f| f.2 == FillMethod::Rigid).count();
                format!(
                    "{summary}; {} samples filled in gaps of up to {max} frames ({rigid} from their body's other markers, {} on splines; residual 0, no camera bits)",
                    e.filled.len(),
                    e.filled.len() - rigid
                )
            }
            None => summary,
        };
        (bytes, Some(summary))
    } else if format == "markers-csv" {
        let csv = stereoscope_recorder::export::export_markers_csv(&s, fill_gaps)
            .with_context(|| session.display().to_string())?;
        (csv.into_bytes(), None)
    } else if format == "models-csv" {
        (
            stereoscope_recorder::export::export_models_csv(&s).into_bytes(),
            None,
        )
    } else if format == "bodies-csv" {
        (
            stereoscope_recorder::export::export_bodies_csv(&s).into_bytes(),
            None,
        )
    } else {
        (
            stereoscope_recorder::export::export_csv(&s).into_bytes(),
            None,
        )
    };
    match out {
        Some(p) => write_whole(&p, &bytes)?,
        None => {
            use std::io::Write;
            match std::io::stdout().lock().write_all(&bytes) {
                // `export … | head`: the reader has all it wanted; end quietly.
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(0),
                r => r?,
            }
        }
    }
    if let Some(summary) = summary {
        eprintln!("{summary}");
    }
    Ok(0)
}

/// Writes a file whole or not at all: into a temporary file beside it, synced, renamed.
fn write_whole(path: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    let name = path
        .file_name()
        .ok_or_else(|| anyhow::anyhow!("{}: not a file name", path.display()))?;
    let tmp = path.with_file_name(format!(
        ".{}.partial-{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(anyhow::anyhow!("{}: {e}", path.display()));
    }
    Ok(())
}

/// Keeps the first ten refusals of a listener for the command's report.
fn keep_first(
    kept: &std::sync::Mutex<Vec<stereoscope_transport::Refusal>>,
    r: stereoscope_transport::Refusal,
) {
    if let Ok(mut v) = kept.lock()
        && v.len() < 10
    {
        v.push(r);
    }
}
