//! `stereoscope demo`: the whole chain on this PC as separate processes — two synthetic
//! cameras of the thesis's lab (`deploy/rigs/demo.toml`), their moment workers and fusion,
//! started by the launcher — watched from outside over Zenoh like any client would: poses
//! against the synthetic cameras' ground truth (read from shared memory on this PC), live, then a summary (poses/s, capture→pose
//! latency, position and heading error, identity switches).

use stereoscope_launcher::{LaunchConfig, LaunchError};

/// Why the demo could not run.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("demo: the demo rig")]
    Rig(#[from] stereoscope_rig::RigError),
    #[error(
        "demo: camera[{index}] ({id:?}) has no synthetic source; the demo scores synthetic cameras against their scene's truth (run a rig of real sources with `stereoscope run`)"
    )]
    NotSynthetic { index: usize, id: String },
    #[error("demo: {}", .path.display())]
    File {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("demo: no free loopback port for the router")]
    NoPort(#[source] std::io::Error),
    #[error("demo: no poses within 30 s of starting: see the services' log lines above")]
    NoPoses,
    #[error("demo: the launcher thread panicked")]
    LauncherPanicked,
    #[error("demo")]
    Launch(#[from] LaunchError),
    #[error("demo")]
    Transport(#[from] stereoscope_transport::TransportError),
}
mod models;
mod summary;

pub use models::{HiddenStats, ModelStats};
use models::{ModelAcc, ModelTruth, score_models};
use std::collections::{BTreeMap, VecDeque};
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereoscope_numeric::angle::{wrap_half_turn_deg, wrap_turn_deg};
use stereoscope_numeric::assign::assign_min_cost;
use stereoscope_numeric::quantiles::LogHistogram;
use stereoscope_proto::messages::{Detail, Health, PoseFrame, Truth};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_rig::Rig;
use stereoscope_rig::truth::Layouts;
use stereoscope_service::Context;
use stereoscope_transport::Inlet;
use stereoscope_transport::Shutdown;
use stereoscope_transport::net::{self, ZenohSpec};
pub use summary::{BodyStats, DemoSummary, GHOST_EXAMPLES, GhostExample, ServerState, TargetStats};

/// The built-in rig.
pub const DEMO_RIG: &str = include_str!("../../../deploy/rigs/demo.toml");

#[derive(Debug, Clone)]
pub struct DemoConfig {
    /// How long to measure, from the first pose.
    pub seconds: f64,
    /// The command that starts a service (see [`LaunchConfig::program`]).
    pub program: Vec<String>,
    /// Rig text to run instead of the built-in one (it must have synthetic cameras).
    pub rig_text: Option<String>,
    /// The folder the rig text came from: a model's relative `urdf` path starts there.
    pub rig_dir: Option<std::path::PathBuf>,
    /// Print the live table.
    pub live: bool,
    /// Where to write the rig file the services read.
    pub work_dir: std::path::PathBuf,
    /// Run the viewer too, serving the live view here (`docs/viewer.md`).
    pub view: Option<std::net::SocketAddr>,
}

/// `(target, matched object id, error m)`.
type Scored = (u32, Option<u32>, f64);

/// What the watcher scores against besides the truth messages.
struct Truths {
    layouts: Layouts,
    models: ModelTruth,
}

#[derive(Default)]
struct BodyAcc {
    sq: f64,
    rsq: f64,
    n: u64,
    missed: u64,
}

#[derive(Default)]
struct Acc {
    sq: f64,
    n: u64,
    hsq: f64,
    hn: u64,
    missed: u64,
    last_id: Option<u32>,
    switches: u32,
}

/// Runs the demo until `seconds` of poses were measured or shutdown.
pub fn run(cfg: DemoConfig, shutdown: Shutdown) -> Result<DemoSummary, DemoError> {
    let port = net::free_loopback_port().map_err(DemoError::NoPort)?;
    let prefix = format!("stsc_demo{}_", std::process::id());
    let mut base = cfg.rig_text.clone().unwrap_or_else(|| DEMO_RIG.to_string());
    // The services read the rig from the work folder: a model's URDF and a recorder's folder
    // are named by their full paths (both are relative to the rig file).
    if let Some(dir) = &cfg.rig_dir {
        let mut file = stereoscope_rig::RigFile::from_toml(&base).map_err(|e| {
            DemoError::Rig(stereoscope_rig::RigError {
                kind: stereoscope_rig::RigErrorKind::Syntax,
                file: None,
                key: String::new(),
                message: e.to_string(),
            })
        })?;
        let mut moved = false;
        for m in &mut file.models {
            if let Some(u) = &mut m.urdf
                && std::path::Path::new(u.as_str()).is_relative()
            {
                *u = dir.join(&*u).display().to_string();
                moved = true;
            }
        }
        if let Some(r) = &mut file.recorder
            && std::path::Path::new(&r.folder).is_relative()
        {
            r.folder = dir.join(&r.folder).display().to_string();
            moved = true;
        }
        if moved {
            base = file.to_toml().map_err(|e| {
                DemoError::Rig(stereoscope_rig::RigError {
                    kind: stereoscope_rig::RigErrorKind::Value,
                    file: None,
                    key: "model".into(),
                    message: e.to_string(),
                })
            })?;
        }
    }
    let mut text = format!(
        "{base}\n[[host]]\nname = \"demo\"\nzenoh_listen = [\"tcp/127.0.0.1:{port}\"]\niceoryx2_prefix = \"{prefix}\"\n"
    );
    if let Some(addr) = cfg.view {
        // A rig of the user's that has its own [viewer] keeps it (and its address).
        if !base.lines().any(|l| l.trim() == "[viewer]") {
            text.push_str(&format!("\n[viewer]\nlisten = \"{addr}\"\n"));
        }
    }
    let rig = Rig::from_toml(&text)?;
    // The demo scores against the synthetic scene's truth: every camera must render it.
    if let Some((i, c)) = rig.spec.cameras.iter().enumerate().find(|(_, c)| {
        !matches!(
            c.source,
            Some(stereoscope_rig::schema::SourceSpec::Synthetic { .. })
        )
    }) {
        return Err(DemoError::NotSynthetic {
            index: i,
            id: c.id.clone(),
        });
    }
    std::fs::create_dir_all(&cfg.work_dir).map_err(|source| DemoError::File {
        path: cfg.work_dir.clone(),
        source,
    })?;
    let rig_path = cfg.work_dir.join("demo-rig.toml");
    std::fs::write(&rig_path, &text).map_err(|source| DemoError::File {
        path: rig_path.clone(),
        source,
    })?;
    let client = ZenohSpec::client_of(&format!("tcp/127.0.0.1:{port}"));
    let ctx = Context {
        rig_path: rig_path.clone(),
        rig: rig.clone(),
        host: "demo".into(),
        iox_prefix: prefix.clone(),
        zenoh: client.clone(),
    };
    let first_cam = rig
        .cameras
        .first()
        .map(|c| c.id.clone())
        .ok_or(DemoError::Rig(stereoscope_rig::RigError {
            kind: stereoscope_rig::RigErrorKind::Value,
            file: None,
            key: "camera".into(),
            message: "the demo rig has no cameras".into(),
        }))?;
    // The router runs in a process of its own, the launcher's child, as `stereoscope run`
    // runs it: sharing this process (and Zenoh's runtime) with the watcher put a tail of
    // three frame periods on the latency it measures.
    let launch_stop = Shutdown::new();
    let launcher = {
        let stop = launch_stop.clone();
        let lc = LaunchConfig {
            ctx,
            program: cfg.program.clone(),
            env: Vec::new(),
            router: true,
            until_sources_end: false,
        };
        std::thread::spawn(move || stereoscope_launcher::run(lc, stop))
    };
    let truth_fps = rig.spec.cameras.first().and_then(|c| match c.source {
        Some(stereoscope_rig::schema::SourceSpec::Synthetic {
            fps, loop_frames, ..
        }) => Some((fps, loop_frames)),
        _ => None,
    });
    let truth = Truths {
        layouts: Layouts::of(&rig),
        models: ModelTruth {
            motions: stereoscope_rig::models::model_motions(&rig.spec, &rig.models),
            fps: truth_fps.map_or(0.0, |f| f.0),
            loop_frames: truth_fps.and_then(|f| f.1),
        },
    };
    let result = watch(
        &cfg, &shutdown, &client, &rig.name, &first_cam, &prefix, &truth,
    );
    launch_stop.request();
    let restarts = match launcher.join() {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => return Err(e.into()),
        Err(_) => return Err(DemoError::LauncherPanicked),
    };
    let _ = std::fs::remove_file(&rig_path);
    let mut s = result?;
    s.restarts = restarts;
    Ok(s)
}

fn watch(
    cfg: &DemoConfig,
    shutdown: &Shutdown,
    client: &ZenohSpec,
    rig: &str,
    truth_cam: &str,
    iox_prefix: &str,
    truth: &Truths,
) -> Result<DemoSummary, DemoError> {
    let layouts = &truth.layouts;
    // The router starts in the launcher thread: give it a moment, then connect.
    let mut session = None;
    let deadline = Instant::now() + Duration::from_secs(10);
    while session.is_none() {
        match net::open(client) {
            Ok(s) => session = Some(s),
            Err(e) if Instant::now() > deadline => return Err(e.into()),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
        if shutdown.requested() {
            return Ok(DemoSummary::default());
        }
    }
    let Some(session) = session else {
        return Ok(DemoSummary::default());
    };
    // What the watcher refuses (another rig's messages, or ones that do not decode) is
    // counted and said in the summary's log.
    let mut refused = stereoscope_transport::Counters::default();
    let poses = Inlet::<PoseFrame>::zenoh(&session, &[keys::poses(rig)], rig, "pose frame", 1024)?;
    // Each service's newest health report, for what it lost.
    let health: Arc<Mutex<BTreeMap<String, Health>>> = Arc::default();
    let sink = health.clone();
    let _health = stereoscope_transport::inlet::listen(
        &session,
        &[keys::all_health(rig)],
        stereoscope_transport::inlet::Admission::<Health>::new(rig, "health"),
        move |h, _| {
            if let Ok(mut m) = sink.lock() {
                m.insert(h.service.clone(), h);
            }
        },
        |_| {},
    )?;
    // Ground truth comes from the synthetic camera on this PC, through shared memory.
    let node = stereoscope_transport::iox::node(iox_prefix, "demo-watcher")?;
    let truth_sub = Inlet::<Truth>::iox(
        &node,
        &stereoscope_proto::names::iox::truth(rig, truth_cam),
        rig,
        "truth",
    )?;

    let startup_deadline = Instant::now() + Duration::from_secs(30);
    let mut first: Option<Instant> = None;
    let mut truths: VecDeque<Truth> = VecDeque::new();
    let mut pending: VecDeque<PoseFrame> = VecDeque::new();
    // Fixed memory however long the run (0.1 µs to 100 s, to 0.25 %).
    let mut latencies = LogHistogram::new(1e-4, 1e5);
    let mut exposure = LogHistogram::new(1e-4, 1e5);
    let mut frames = 0u64;
    let mut complete = 0u64;
    let mut acc: BTreeMap<u32, Acc> = BTreeMap::new();
    let mut body_acc: BTreeMap<String, BodyAcc> = BTreeMap::new();
    let mut model_acc: BTreeMap<String, ModelAcc> = BTreeMap::new();
    let mut last_print = Instant::now();
    let mut latest: Option<(PoseFrame, Vec<Scored>, Vec<BodyError>)> = None;
    let mut ghosts = 0u64;
    let mut ghost_examples: Vec<GhostExample> = Vec::new();
    let out = std::io::stdout();
    loop {
        if shutdown.requested() {
            break;
        }
        if let Some(f) = first
            && f.elapsed().as_secs_f64() >= cfg.seconds
        {
            break;
        }
        if first.is_none() && Instant::now() > startup_deadline {
            return Err(DemoError::NoPoses);
        }
        if let Some(p) = poses.next_within(Duration::from_millis(50), &mut refused) {
            if first.is_none() {
                first = Some(Instant::now());
            }
            frames += 1;
            latencies.add(p.published_ns.saturating_sub(p.frame_published_ns) as f64 / 1e6);
            exposure.add(p.published_ns.saturating_sub(p.timestamp_ns) as f64 / 1e6);
            pending.push_back(p);
        }
        while let Some(t) = truth_sub.try_next(&mut refused) {
            truths.push_back(t);
        }
        while truths.len() > 600 {
            truths.pop_front();
        }
        // Score pose frames whose truth has arrived; give up on one whose truth can no longer
        // come (a later truth arrived: it came before the truth subscription, or was lost) or
        // after 100 frames. Waiting on such a frame used to hold back every later one: a run
        // whose first pose frame had no truth scored nothing.
        while let Some(p) = pending.front() {
            let t = truths
                .iter()
                .find(|t| t.timestamp_ns.abs_diff(p.timestamp_ns) < 1_000_000);
            match t {
                Some(t) => {
                    let scored = score(p, t, &mut acc);
                    let body_errors = score_bodies(p, t, &mut body_acc);
                    score_models(p, t, &truth.models, &mut model_acc);
                    let found = layouts.ghosts(&p.poses, &t.targets);
                    ghosts += found.len() as u64;
                    for g in found {
                        if ghost_examples.len() < GHOST_EXAMPLES {
                            ghost_examples.push(GhostExample {
                                timestamp_ns: p.timestamp_ns,
                                object_id: g.object_id,
                                position_m: g.position_m,
                                method: g.method,
                                cameras: g.cameras.clone(),
                                body: g.body.clone(),
                            });
                        }
                    }
                    if scored.iter().all(|(_, id, e)| id.is_some() && *e < 0.05) {
                        complete += 1;
                    }
                    latest = Some((p.clone(), scored, body_errors));
                    pending.pop_front();
                }
                None if pending.len() > 100
                    || truths
                        .back()
                        .is_some_and(|t| t.timestamp_ns > p.timestamp_ns + 1_000_000) =>
                {
                    pending.pop_front();
                }
                None => break,
            }
        }
        if cfg.live && last_print.elapsed() > Duration::from_millis(500) {
            last_print = Instant::now();
            if let Some((p, scored, body_errors)) = &latest {
                let mut o = out.lock();
                let _ = writeln!(
                    o,
                    "-- pose frame {} ({} cameras: {}) --",
                    p.sequence,
                    p.cameras.len(),
                    p.cameras.join(",")
                );
                let _ = writeln!(
                    o,
                    "  obj        x m      y m      z m   heading  method         err mm  marker of"
                );
                for b in &p.bodies {
                    let err = body_errors
                        .iter()
                        .find(|e| e.0 == b.name)
                        .map(|e| format!(", error {:.1} mm {:.2}°", e.1 * 1e3, e.2))
                        .unwrap_or_default();
                    let _ = writeln!(
                        o,
                        "  body {:<8} {:>8.4} {:>8.4} {:>8.4}  {}/{} markers, residual {:.2} mm{}{err}",
                        b.name,
                        b.position_m[0],
                        b.position_m[1],
                        b.position_m[2],
                        b.markers_seen,
                        b.markers,
                        b.residual_mm,
                        if b.held { " (held)" } else { "" }
                    );
                }
                for pose in &p.poses {
                    let err = scored
                        .iter()
                        .find(|(_, id, _)| *id == Some(pose.object_id))
                        .map(|(_, _, e)| format!("{:6.1}", e * 1000.0))
                        .unwrap_or_else(|| "     -".into());
                    // Which body's marker a pose is, by the body's own numbering.
                    let of = pose
                        .body
                        .as_ref()
                        .map(|b| format!("{} m{}", b.name, b.marker))
                        .unwrap_or_else(|| "-".into());
                    let _ = writeln!(
                        o,
                        "  {:>3}  {:>8.4} {:>8.4} {:>8.4}  {:>8}  {:<13} {err}  {of}",
                        pose.object_id,
                        pose.position_m[0],
                        pose.position_m[1],
                        pose.position_m[2],
                        pose.heading_deg
                            .map(|h| format!("{h:6.1}°"))
                            .unwrap_or("-".into()),
                        format!("{:?}", pose.method).to_lowercase(),
                    );
                }
                for m in &p.models {
                    let joints: Vec<String> = m
                        .joints
                        .iter()
                        .filter(|j| j.values.len() == 1)
                        .map(|j| {
                            format!(
                                "{} {:.2}{}",
                                j.name,
                                j.values[0].to_degrees(),
                                if j.determined { "°" } else { "° (held)" }
                            )
                        })
                        .collect();
                    let _ = writeln!(
                        o,
                        "  model {:<8} {}/{} markers, residual {:.2} mm{}: {}",
                        m.name,
                        m.markers_seen,
                        m.markers,
                        m.rms_mm,
                        if m.valid { "" } else { " (not valid)" },
                        joints.join(", ")
                    );
                }
            }
        }
    }
    let secs = first.map(|f| f.elapsed().as_secs_f64()).unwrap_or(0.0);
    let (mut sq, mut n, mut hsq, mut hn) = (0.0, 0u64, 0.0, 0u64);
    let targets: Vec<TargetStats> = acc
        .iter()
        .map(|(k, a)| {
            sq += a.sq;
            n += a.n;
            hsq += a.hsq;
            hn += a.hn;
            TargetStats {
                target: *k,
                matched: a.n,
                missed: a.missed,
                position_rms_m: if a.n > 0 {
                    (a.sq / a.n as f64).sqrt()
                } else {
                    f64::NAN
                },
                heading_rms_deg: (a.hn > 0).then(|| (a.hsq / a.hn as f64).sqrt()),
                id_switches: a.switches,
            }
        })
        .collect();
    if let Some(r) = refused.refusals() {
        eprintln!("demo watcher: messages {r}");
    }
    Ok(DemoSummary {
        seconds: secs,
        pose_frames: frames,
        poses_per_s: if secs > 0.0 {
            frames as f64 / secs
        } else {
            0.0
        },
        latency_p50_ms: latencies.quantile(0.5),
        latency_p99_ms: latencies.quantile(0.99),
        exposure_latency_p50_ms: exposure.quantile(0.5),
        position_rms_m: if n > 0 {
            (sq / n as f64).sqrt()
        } else {
            f64::NAN
        },
        heading_rms_deg: (hn > 0).then(|| (hsq / hn as f64).sqrt()),
        complete_frames: complete,
        ghost_poses: ghosts,
        ghosts: ghost_examples,
        targets,
        models: models::stats(&truth.models, model_acc),
        bodies: body_acc
            .into_iter()
            .map(|(name, a)| BodyStats {
                name,
                matched: a.n,
                missed: a.missed,
                position_rms_m: if a.n > 0 {
                    (a.sq / a.n as f64).sqrt()
                } else {
                    f64::NAN
                },
                rotation_rms_deg: if a.n > 0 {
                    (a.rsq / a.n as f64).sqrt()
                } else {
                    f64::NAN
                },
            })
            .collect(),
        vr_latency_p50_us: vr_detail(&health, Detail::LatencyP50Us),
        vr_latency_p99_us: vr_detail(&health, Detail::LatencyP99Us),
        servers: server_states(&health),
        restarts: 0,
        losses: health
            .lock()
            .map(|m| m.values().flat_map(Health::losses).collect())
            .unwrap_or_default(),
    })
}

/// The feed's servers and their states, from its last health report.
fn server_states(health: &Mutex<BTreeMap<String, Health>>) -> Vec<ServerState> {
    let Ok(m) = health.lock() else {
        return Vec::new();
    };
    let Some(h) = m.get("vrfeed") else {
        return Vec::new();
    };
    [
        ("VRPN", Detail::Vrpn),
        ("NatNet", Detail::Natnet),
        ("Qualisys RT", Detail::Qualisys),
    ]
    .into_iter()
    .filter_map(|(protocol, key)| {
        Some(ServerState {
            protocol: protocol.into(),
            state: h.detail(key)?.to_string(),
        })
    })
    .collect()
}

/// A number from the VR feed's last health report.
fn vr_detail(health: &Mutex<BTreeMap<String, Health>>, key: Detail) -> Option<f64> {
    let m = health.lock().ok()?;
    m.get("vrfeed")?.detail(key)?.parse().ok()
}

/// Scores each body target of the truth against the frame's body of that name: position of
/// its origin, angle between the rotations.
fn score_bodies(p: &PoseFrame, t: &Truth, acc: &mut BTreeMap<String, BodyAcc>) -> Vec<BodyError> {
    let mut out = Vec::new();
    for tt in t.targets.iter().filter(|x| x.visible) {
        let (Some(name), Some(q)) = (&tt.body, tt.orientation_xyzw) else {
            continue;
        };
        // A model's link (`<model>/<link>`) is scored with its model (`score_models`).
        if name.contains('/') {
            continue;
        }
        let a = acc.entry(name.clone()).or_default();
        match p.bodies.iter().find(|b| &b.name == name && !b.held) {
            Some(b) => {
                let d2: f64 = (0..3)
                    .map(|i| (b.position_m[i] - tt.position_m[i]).powi(2))
                    .sum();
                let dot: f64 = (0..4).map(|i| b.orientation_xyzw[i] * q[i]).sum();
                let angle = 2.0 * dot.abs().min(1.0).acos();
                a.sq += d2;
                a.rsq += angle.to_degrees().powi(2);
                a.n += 1;
                out.push((name.clone(), d2.sqrt(), angle.to_degrees()));
            }
            None => a.missed += 1,
        }
    }
    out
}

/// A body's error in one frame: name, position error (m), rotation error (degrees).
type BodyError = (String, f64, f64);

/// Matches one pose frame to its truth; returns `(target, object id, error m)` per visible
/// target.
fn score(p: &PoseFrame, t: &Truth, acc: &mut BTreeMap<u32, Acc>) -> Vec<Scored> {
    // Rigid bodies are scored as bodies (`score_bodies`); their markers are not loose targets.
    let visible: Vec<&stereoscope_proto::messages::TargetTruth> = t
        .targets
        .iter()
        .filter(|x| x.visible && x.body.is_none())
        .collect();
    let gate = 0.05;
    let cost: Vec<Vec<f64>> = visible
        .iter()
        .map(|tt| {
            p.poses
                .iter()
                .map(|pose| {
                    if pose.body.is_some() {
                        return f64::INFINITY;
                    }
                    let d = (0..3)
                        .map(|i| (pose.position_m[i] - tt.position_m[i]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    if d < gate { d } else { f64::INFINITY }
                })
                .collect()
        })
        .collect();
    let a = if p.poses.is_empty() {
        vec![None; visible.len()]
    } else {
        assign_min_cost(&cost)
    };
    let mut out = Vec::new();
    for (tt, m) in visible.iter().zip(a) {
        let e = acc.entry(tt.target).or_default();
        match m {
            Some(j) => {
                let pose = &p.poses[j];
                let d = cost[out.len()][j];
                e.sq += d * d;
                e.n += 1;
                if e.last_id.is_some_and(|l| l != pose.object_id) {
                    e.switches += 1;
                }
                e.last_id = Some(pose.object_id);
                if tt.has_axis
                    && let Some(h) = pose.heading_deg
                {
                    let diff = if tt.symmetric || !pose.heading_directed {
                        wrap_half_turn_deg(h - tt.heading_deg)
                    } else {
                        wrap_turn_deg(h - tt.heading_deg)
                    };
                    e.hsq += diff * diff;
                    e.hn += 1;
                }
                out.push((tt.target, Some(pose.object_id), d));
            }
            None => {
                e.missed += 1;
                out.push((tt.target, None, f64::INFINITY));
            }
        }
    }
    out
}
