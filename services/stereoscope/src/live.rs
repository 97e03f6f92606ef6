//! `stereoscope run`, `demo` and `status`: the live system from the command line (the
//! launcher and the demo are `stereoscope_launcher`'s and `stereoscope_demo`'s); recorded
//! sessions are `sessions.rs`'s.

use anyhow::Context as _;
use std::path::PathBuf;
use stereoscope_demo::{DemoConfig, DemoSummary};
use stereoscope_launcher::{LaunchConfig, run};
use stereoscope_service::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

/// Runs this host's services of `rig` until Ctrl-C.
pub fn run_rig(
    rig: PathBuf,
    place: stereoscope_service::HostArgs,
    router: bool,
    program: anyhow::Result<Vec<String>>,
) -> anyhow::Result<usize> {
    init_logging("launcher");
    let shutdown = Shutdown::on_signals()?;
    let ctx = CommonArgs {
        rig,
        place,
        zenoh_mode: None,
        zenoh_connect: Vec::new(),
        zenoh_listen: Vec::new(),
        tls: Default::default(),
    }
    .resolve()?;
    stereoscope_sources::check_supported(&ctx.rig, &ctx.cameras_here())?;
    if ctx.rig.spec.fusion.is_none() {
        tracing::warn!(
            "{} has no [fusion] section: no fusion will run, so no poses are made",
            ctx.rig_path.display()
        );
    }
    let restarts = run(
        LaunchConfig {
            ctx,
            program: program?,
            env: Vec::new(),
            router,
            until_sources_end: false,
        },
        shutdown,
    )?;
    tracing::info!(restarts, "launcher stopped");
    Ok(0)
}

fn ms(v: f64) -> String {
    format!("{v:.2} ms")
}

/// The summary as text.
pub fn summary_text(s: &DemoSummary) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "Demo summary: {:.1} s, {} pose frames ({:.1}/s)\n",
        s.seconds, s.pose_frames, s.poses_per_s
    ));
    out.push_str(&format!(
        "  latency, frame published → poses published: p50 {}, p99 {}\n",
        ms(s.latency_p50_ms),
        ms(s.latency_p99_ms)
    ));
    out.push_str(&format!(
        "  latency, exposure → poses (includes rendering the synthetic frame): p50 {}\n",
        ms(s.exposure_latency_p50_ms)
    ));
    out.push_str(&format!(
        "  position error RMS {:.2} mm; heading error RMS {}\n",
        s.position_rms_m * 1000.0,
        s.heading_rms_deg
            .map(|h| format!("{h:.2}°"))
            .unwrap_or_else(|| "-".into())
    ));
    out.push_str(&format!(
        "  frames with every visible target found within 5 cm: {} of {}; poses that were no target (ghosts): {}\n",
        s.complete_frames, s.pose_frames, s.ghost_poses
    ));
    out.push_str("  target  matched  missed  RMS mm  heading RMS  id switches\n");
    for t in &s.targets {
        out.push_str(&format!(
            "  {:>6}  {:>7}  {:>6}  {:>6.2}  {:>11}  {:>11}\n",
            t.target,
            t.matched,
            t.missed,
            t.position_rms_m * 1000.0,
            t.heading_rms_deg
                .map(|h| format!("{h:.2}°"))
                .unwrap_or_else(|| "-".into()),
            t.id_switches
        ));
    }
    if !s.bodies.is_empty() {
        out.push_str("  body      measured  missed  position RMS mm  rotation RMS\n");
        for b in &s.bodies {
            out.push_str(&format!(
                "  {:<8}  {:>8}  {:>6}  {:>15.2}  {:>11.3}°\n",
                b.name,
                b.matched,
                b.missed,
                b.position_rms_m * 1000.0,
                b.rotation_rms_deg
            ));
        }
    }
    for m in &s.models {
        let joints: Vec<String> = m
            .joints_rms
            .iter()
            .filter_map(|(n, r)| r.map(|r| format!("{n} {r:.3}")))
            .collect();
        out.push_str(&format!(
            "  model {}: {} of {} frames valid, {} with every joint determined; joint RMS (degrees; mm for a slide): {}; tool RMS {:.2} mm; object ids passed between its markers {}, ids per marker {:.2}\n",
            m.name,
            m.valid,
            m.frames,
            m.whole,
            joints.join(", "),
            m.tool_rms_m * 1000.0,
            m.ids_passed,
            m.ids_per_marker
        ));
        if let Some(h) = &m.hidden {
            out.push_str(&format!("  model {}: {}\n", m.name, h.line()));
        }
    }
    let listening: Vec<&str> = s
        .servers
        .iter()
        .filter(|v| v.state == "listening")
        .map(|v| v.protocol.as_str())
        .collect();
    if let (Some(p50), Some(p99)) = (s.vr_latency_p50_us, s.vr_latency_p99_us) {
        out.push_str(&format!(
            "  feed, frame published → sent (servers listening: {}): p50 {:.2} ms, p99 {:.2} ms\n",
            if listening.is_empty() {
                "none".to_string()
            } else {
                listening.join(", ")
            },
            p50 / 1000.0,
            p99 / 1000.0
        ));
    }
    for v in s.servers.iter().filter(|v| v.state != "listening") {
        out.push_str(&format!(
            "  {} is not listening: {} (see `stereoscope status`)\n",
            v.protocol, v.state
        ));
    }
    if s.restarts > 0 {
        out.push_str(&format!("  services restarted: {}\n", s.restarts));
    }
    for l in &s.losses {
        out.push_str(&format!("  lost: {l}\n"));
    }
    out
}

/// Runs the demo and prints its summary.
pub fn demo(
    seconds: f64,
    rig: Option<PathBuf>,
    live: bool,
    json: bool,
    view: Option<std::net::SocketAddr>,
    program: anyhow::Result<Vec<String>>,
) -> anyhow::Result<usize> {
    if !(seconds.is_finite() && seconds > 0.0) {
        anyhow::bail!("--seconds {seconds} must be a number above zero");
    }
    init_logging("demo");
    let shutdown = Shutdown::on_signals()?;
    let rig_text = match &rig {
        Some(p) => Some(std::fs::read_to_string(p).with_context(|| p.display().to_string())?),
        None => None,
    };
    let work_dir = std::env::temp_dir().join(format!("stereoscope-demo-{}", std::process::id()));
    if let Some(a) = view {
        // Another program on the port would be the page the URL opens: refuse before
        // starting rather than print its address.
        std::net::TcpListener::bind(a).map_err(|e| {
            anyhow::anyhow!(
                "--view-listen {a}: the live view cannot listen there: {e} (another program has the port; give --view-listen another address)"
            )
        })?;
        eprintln!("Live view: http://{a}/ (open it in a browser)");
    }
    let summary = stereoscope_demo::run(
        DemoConfig {
            seconds,
            program: program?,
            rig_text,
            rig_dir: rig.as_ref().map(|p| {
                let dir = p.parent().unwrap_or(std::path::Path::new("."));
                std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf())
            }),
            live,
            work_dir: work_dir.clone(),
            view,
        },
        shutdown,
    );
    let _ = std::fs::remove_dir_all(&work_dir);
    let summary = summary?;
    if json {
        println!("{}", summary.to_json());
    } else {
        print!("{}", summary_text(&summary));
    }
    Ok(0)
}

/// `stereoscope status`.
pub fn status(
    rig: Option<PathBuf>,
    connect: Option<String>,
    rig_name: Option<String>,
    watch: bool,
    json: bool,
    stall_ms: u64,
    tls: stereoscope_service::context::TlsArgs,
) -> anyhow::Result<usize> {
    use stereoscope_status::{Monitor, StatusConfig, to_json, to_text};
    let loaded = rig
        .as_ref()
        .map(|p| stereoscope_rig::Rig::load(p))
        .transpose()?;
    let name = match (&loaded, rig_name) {
        (Some(r), _) => r.name.clone(),
        (None, Some(n)) => n,
        (None, None) => anyhow::bail!("give a rig file or --rig-name"),
    };
    let zenoh = crate::mask::tool_zenoh(loaded.as_ref(), connect, &tls)?;
    let endpoint = zenoh.connect.join(", ");
    let shutdown = Shutdown::on_signals()?;
    let monitor = Monitor::connect(StatusConfig {
        rig: name,
        zenoh,
        listen: std::time::Duration::from_millis(1500),
        stall: std::time::Duration::from_millis(stall_ms),
    })
    .with_context(|| format!("asking the router at {endpoint}"))?;
    loop {
        if shutdown.sleep(monitor.listen()) {
            return Ok(0);
        }
        let s = monitor.snapshot()?;
        if json {
            println!("{}", to_json(&s));
        } else {
            if watch {
                print!("\x1b[2J\x1b[H");
            }
            print!("{}", to_text(&s));
        }
        if !watch {
            return Ok(0);
        }
    }
}
