//! The launcher: one per PC. It reads the rig file, starts the services assigned to this host
//! (a capture and a moment worker per camera here, fusion if it is here) as separate
//! processes, prefixes their log lines with the service name, restarts one that fails with a
//! growing delay (0.5 s doubling to 10 s; reset once it has run 30 s) — a service that exits
//! successfully has finished (a capture at the end of a file) and is not restarted —, removes what dead
//! iceoryx2 nodes left behind before each start, and on Ctrl-C/SIGTERM stops every child
//! (SIGTERM, then SIGKILL after 3 s). It also runs this PC's Zenoh router, which its services
//! join as clients and other PCs' routers connect to (`docs/deploy.md`), as a child process
//! supervised like the services (`stereoscope service router`): a router that crashes or
//! hangs is restarted and the services' sessions rejoin it, and the launcher itself — which
//! holds no router — stays up (`docs/reliability.md`).
//!
//! Children die with the launcher (PR_SET_PDEATHSIG), so nothing is left running if it is
//! killed outright.

pub mod progress;
mod router;
pub mod tokens;
mod watch;

pub use router::{DEFAULT_ROUTER, router_cli, router_specs, run_router};
use router::{wait_for_port_free, wait_for_router};
use watch::{restart_stuck, slowest_fps, watchdog};

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use stereoscope_rig::RigError;
use stereoscope_service::Context;
use stereoscope_transport::net::ZenohSpec;
use stereoscope_transport::{Shutdown, iox, net};

/// One service to run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceSpec {
    /// "capture/cam0", "moments/cam0", "fusion".
    pub name: String,
    /// Arguments after the program prefix.
    pub args: Vec<String>,
    /// On a frame's way to a pose and out (captures, moment workers, fusion, the VR feed,
    /// serial outputs): run under the rig's `[realtime]` priority when it has one.
    pub frame_path: bool,
}

/// What the launcher runs and how.
#[derive(Debug, Clone)]
pub struct LaunchConfig {
    pub ctx: Context,
    /// The command that starts a service, before its own arguments (e.g. the `stereoscope`
    /// binary and `service`).
    pub program: Vec<String>,
    /// Extra environment for every child.
    pub env: Vec<(String, String)>,
    /// Run this PC's Zenoh router (default true; off when the PC has a `zenohd`).
    pub router: bool,
    /// Stop once every capture has finished (its finite source ended) and the workers and
    /// fusion have had the last frames: for replaying recorded frames. A fusion that forms a
    /// recording's sets (`[fusion] replay_sets`) finishes by itself after the last one, and is
    /// waited for (at most [`MAX_DRAIN_AFTER_SOURCES_END`]); otherwise the rest run on for
    /// [`DRAIN_AFTER_SOURCES_END`].
    pub until_sources_end: bool,
}

/// A running service silent this long (no health report) is killed and restarted.
pub const WATCHDOG: Duration = Duration::from_secs(3);

/// After this PC's router (re)started, a service that reported before it and has not been
/// heard since for this long did not rejoin it: it is restarted.
pub const REJOIN: Duration = Duration::from_secs(10);

/// How long the launcher waits for its router to take connections before starting the
/// services.
pub const ROUTER_START: Duration = Duration::from_secs(10);

/// The router's name among the launcher's children (and in health reports).
pub const ROUTER_SERVICE: &str = "router";

/// The delay before a failed service's first restart.
pub const FIRST_RESTART_DELAY: Duration = Duration::from_millis(500);

/// A service that ran this long before it failed is restarted after [`FIRST_RESTART_DELAY`]
/// again; one that fails sooner waits twice as long each time, up to 10 s.
pub const RAN_WELL: Duration = Duration::from_secs(2);

/// How long the other services run on after the last capture finished, with
/// [`LaunchConfig::until_sources_end`] and a fusion that does not finish by itself.
pub const DRAIN_AFTER_SOURCES_END: Duration = Duration::from_millis(1500);

/// The longest wait for a replaying fusion to finish its last set after the sources ended
/// (it waits up to its `max_wait_ms` for a frame lost in the replay).
pub const MAX_DRAIN_AFTER_SOURCES_END: Duration = Duration::from_secs(10);

#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("launcher: {} assigns no service to host {host:?}", .rig.display())]
    NothingHere {
        rig: std::path::PathBuf,
        host: String,
    },
    #[error("launcher: starting {service}")]
    Spawn {
        service: String,
        #[source]
        source: std::io::Error,
    },
    #[error("launcher")]
    Transport(#[from] stereoscope_transport::TransportError),
    #[error(transparent)]
    Rig(#[from] RigError),

    /// Another launcher runs this host of the rig (same iceoryx2 prefix) on this PC.
    #[error(
        "a launcher for host {host:?} with iceoryx2 prefix {prefix:?} already runs on this PC (lock {}): stop it first, or give this rig its own iceoryx2_prefix",
        .lock.display()
    )]
    AlreadyRunning {
        host: String,
        prefix: String,
        lock: std::path::PathBuf,
    },
    #[error("launcher: the lock file {}", .lock.display())]
    Lock {
        lock: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The rig asks for real-time priorities this user may not set.
    #[error(
        "{}: [realtime] priority = {priority}: this user may not run services under SCHED_FIFO (run as root, grant CAP_SYS_NICE, or allow the priority: ulimit -r, systemd LimitRTPRIO={priority}; or remove [realtime])",
        .rig.display()
    )]
    Realtime {
        rig: std::path::PathBuf,
        priority: u32,
        source: std::io::Error,
    },

    /// This PC's router (a child of the launcher) ended before it took connections.
    #[error(
        "launcher: this PC's Zenoh router exited as it started ({status}); its own lines above say why"
    )]
    RouterExited { status: String },
    /// This PC's router did not take connections in time.
    #[error("launcher: this PC's Zenoh router took no connection within {waited:?}: {why}")]
    RouterNotUp { waited: Duration, why: String },

    /// A service refused its configuration: no restart would mend it, so the rig stopped.
    #[error(
        "{service} refused its configuration (exit status {}): {message}; stopped the rig",
        stereoscope_service::exit::CONFIG_EXIT_STATUS
    )]
    ServiceConfig { service: String, message: String },
}

/// The services of `ctx.host`, in start order (capture before its worker, outputs, fusion last).
pub fn services_here(ctx: &Context, service_zenoh: &ZenohSpec) -> Vec<ServiceSpec> {
    let common = ctx.to_args(service_zenoh);
    let mut out = Vec::new();
    for cam in ctx.cameras_here() {
        for kind in ["capture", "moments"] {
            let mut args = vec![kind.to_string()];
            args.extend(common.clone());
            args.extend(["--camera".to_string(), cam.clone()]);
            out.push(ServiceSpec {
                name: format!("{kind}/{cam}"),
                args,
                frame_path: true,
            });
        }
    }
    for s in &ctx.rig.spec.serial {
        if s.host.as_deref().is_some_and(|h| h != ctx.host) {
            continue;
        }
        let mut args = vec!["serial".to_string()];
        args.extend(common.clone());
        args.extend(["--port".to_string(), s.port.clone()]);
        args.extend(["--baud".to_string(), s.baud.unwrap_or(9600).to_string()]);
        args.extend(["--mode".to_string(), s.mode.unwrap_or_default().to_string()]);
        if !s.objects.is_empty() {
            let ids: Vec<String> = s.objects.iter().map(|i| i.to_string()).collect();
            args.extend(["--objects".to_string(), ids.join(",")]);
        }
        out.push(ServiceSpec {
            name: format!("serial/{}", s.port.rsplit('/').next().unwrap_or("port")),
            args,
            frame_path: true,
        });
    }
    if ctx.fusion_here() && ctx.rig.spec.fusion.is_some() {
        let mut args = vec!["fusion".to_string()];
        args.extend(common.clone());
        out.push(ServiceSpec {
            name: "fusion".into(),
            args,
            frame_path: true,
        });
    }
    if let Some(v) = &ctx.rig.spec.vr
        && v.host.as_deref().is_none_or(|h| h == ctx.host)
    {
        let mut args = vec!["vrfeed".to_string()];
        args.extend(common.clone());
        out.push(ServiceSpec {
            name: "vrfeed".into(),
            args,
            frame_path: true,
        });
    }
    if let Some(v) = &ctx.rig.spec.viewer
        && v.host.as_deref().is_none_or(|h| h == ctx.host)
    {
        let mut args = vec!["viewer".to_string()];
        args.extend(common.clone());
        out.push(ServiceSpec {
            name: "viewer".into(),
            args,
            frame_path: false,
        });
    }
    if let Some(r) = &ctx.rig.spec.recorder
        && r.host.as_deref().is_none_or(|h| h == ctx.host)
    {
        // Every start records a new session folder inside the rig's folder.
        let mut args = vec!["recorder".to_string()];
        args.extend(common);
        args.extend([
            "--into".to_string(),
            ctx.rig.source_path(&r.folder).display().to_string(),
        ]);
        if !r.frames.is_empty() {
            args.extend(["--frames".to_string(), r.frames.join(",")]);
        }
        if let Some(f) = r.flush_ms {
            args.extend(["--flush-ms".to_string(), f.to_string()]);
        }
        out.push(ServiceSpec {
            name: "recorder".into(),
            args,
            frame_path: false,
        });
    }
    out
}

struct Running {
    spec: ServiceSpec,
    child: Option<Child>,
    /// The last line the service wrote to standard error, and the thread copying it.
    last_error_line: Arc<Mutex<String>>,
    stderr_copier: Option<JoinHandle<()>>,
    started: Instant,
    backoff: Duration,
    restart_at: Option<Instant>,
    restarts: u32,
    /// Exited successfully: done, not restarted.
    finished: bool,
    /// Killed this many times in a row for making no progress while its inputs flowed.
    stuck_kills: u32,
}

fn pipe_lines(
    name: String,
    stream: impl std::io::Read + Send + 'static,
    last: Option<Arc<Mutex<String>>>,
) -> JoinHandle<()> {
    std::thread::spawn(move || {
        for line in BufReader::new(stream).lines() {
            let Ok(line) = line else { break };
            if let Some(last) = &last {
                if let Ok(mut l) = last.lock() {
                    line.clone_into(&mut l);
                }
                eprintln!("[{name}] {line}");
            } else {
                println!("[{name}] {line}");
            }
        }
    })
}

fn spawn(
    cfg: &LaunchConfig,
    spec: &ServiceSpec,
    session: &str,
    last_error_line: &Arc<Mutex<String>>,
) -> std::io::Result<(Child, Option<JoinHandle<()>>)> {
    let (prog, pre) = cfg
        .program
        .split_first()
        .ok_or_else(|| std::io::Error::other("empty program"))?;
    let mut cmd = Command::new(prog);
    cmd.args(pre)
        .args(&spec.args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    cmd.env(stereoscope_proto::names::SESSION_ENV, session);
    for (k, v) in &cfg.env {
        cmd.env(k, v);
    }
    let realtime = spec
        .frame_path
        .then(|| cfg.ctx.rig.spec.realtime.as_ref().map(|r| r.priority))
        .flatten();
    // SAFETY: prctl and sched_setscheduler are system calls, async-signal-safe; nothing else
    // runs between fork and exec.
    unsafe {
        use std::os::unix::process::CommandExt;
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if let Some(priority) = realtime {
                set_fifo(priority)?;
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn()?;
    if let Some(out) = child.stdout.take() {
        pipe_lines(spec.name.clone(), out, None);
    }
    let copier = child
        .stderr
        .take()
        .map(|err| pipe_lines(spec.name.clone(), err, Some(last_error_line.clone())));
    Ok((child, copier))
}

/// Puts the calling thread under `SCHED_FIFO` at `priority`.
fn set_fifo(priority: u32) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority as libc::c_int,
    };
    // SAFETY: a system call on the calling thread with a valid parameter.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Whether services may be started under `SCHED_FIFO` at `priority`: tried on a thread of
/// the launcher's own that then ends, so the launcher keeps its ordinary policy and a rig
/// this user may not run so is refused before anything starts.
fn check_realtime(priority: u32) -> std::io::Result<()> {
    std::thread::spawn(move || set_fifo(priority))
        .join()
        .unwrap_or_else(|_| Err(std::io::Error::other("the probe thread stopped")))
}

fn terminate(children: &mut [Running]) {
    for r in children.iter() {
        if let Some(c) = &r.child {
            // SAFETY: sending a signal to a child we own.
            unsafe {
                libc::kill(c.id() as libc::pid_t, libc::SIGTERM);
            }
        }
    }
    let deadline = Instant::now() + Duration::from_secs(3);
    for r in children.iter_mut() {
        if let Some(c) = &mut r.child {
            loop {
                match c.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(10))
                    }
                    _ => {
                        let _ = c.kill();
                        let _ = c.wait();
                        break;
                    }
                }
            }
        }
        r.child = None;
    }
}

/// Runs this host's services until shutdown. Returns how many restarts happened.
pub fn run(cfg: LaunchConfig, shutdown: Shutdown) -> Result<u32, LaunchError> {
    let ctx = &cfg.ctx;
    if let Some(r) = &ctx.rig.spec.realtime {
        check_realtime(r.priority).map_err(|source| LaunchError::Realtime {
            rig: ctx.rig_path.clone(),
            priority: r.priority,
            source,
        })?;
    }
    // One launcher per rig prefix and host on this PC: a second would start a second set of
    // every service (two fusions publishing interleaved poses).
    let _lock = lock_host(&ctx.iox_prefix, &ctx.host)?;
    // This run is one session: a restarted fusion continues its numbering.
    let session = stereoscope_proto::messages::now_ns().to_string();
    // The router first, so the services' clients find it: a child process like the
    // services, so that its failure is not the launcher's.
    let (router, service_zenoh) = match router_specs(ctx).map_err(|e| e.in_file(&ctx.rig_path))? {
        Some((r, s)) if cfg.router => (Some(r), s),
        Some((_, s)) => (None, s),
        None => (None, ctx.zenoh.clone()),
    };
    let specs = services_here(ctx, &service_zenoh);
    if specs.is_empty() {
        return Err(LaunchError::NothingHere {
            rig: ctx.rig_path.clone(),
            host: ctx.host.clone(),
        });
    }
    match iox::cleanup_dead_nodes(&ctx.iox_prefix) {
        Ok(n) if n > 0 => tracing::info!("removed the leftovers of {n} dead iceoryx2 nodes"),
        Ok(_) => {}
        Err(e) => tracing::warn!(
            "cleaning dead iceoryx2 nodes: {}",
            stereoscope_transport::error_chain(&e)
        ),
    }
    let mut running: Vec<Running> = Vec::new();
    let router_spec = router.as_ref().map(|_| {
        let mut args = vec![ROUTER_SERVICE.to_string()];
        args.extend(ctx.to_args(&service_zenoh));
        ServiceSpec {
            name: ROUTER_SERVICE.into(),
            args,
            frame_path: false,
        }
    });
    for spec in router_spec.into_iter().chain(specs) {
        let is_router = spec.name == ROUTER_SERVICE && router.is_some() && running.is_empty();
        if is_router {
            wait_for_port_free(&service_zenoh, &shutdown);
        }
        let last_error_line = Arc::new(Mutex::new(String::new()));
        let (child, stderr_copier) =
            spawn(&cfg, &spec, &session, &last_error_line).map_err(|source| {
                LaunchError::Spawn {
                    service: spec.name.clone(),
                    source,
                }
            })?;
        tracing::info!("started {} (pid {})", spec.name, child.id());
        let mut child = child;
        if is_router {
            wait_for_router(&mut child, &service_zenoh, &shutdown)?;
        }
        running.push(Running {
            spec,
            child: Some(child),
            last_error_line,
            stderr_copier,
            started: Instant::now(),
            backoff: FIRST_RESTART_DELAY,
            restart_at: None,
            restarts: 0,
            finished: false,
            stuck_kills: 0,
        });
    }
    // The watchdog: each service's newest health report (they come every second from the
    // service's own loop, so none means the loop is stuck or the process stopped). Heard
    // through this PC's router, as one of its clients (the session rejoins a restarted
    // router); a launcher without one (`--no-router`) runs without the watchdog.
    let stall = progress::stall_bound(slowest_fps(&ctx.rig));
    let watch = match &router {
        Some(_) => Some(watch::Watch::start(
            net::open(&service_zenoh)?,
            &ctx.rig.name,
            &ctx.host,
            services_inputs_elsewhere(&running),
        )?),
        None => None,
    };
    let mut restarts = 0;
    let mut refused: Option<LaunchError> = None;
    // A fusion forming a recording's sets finishes by itself after the last one.
    let replaying = ctx
        .rig
        .spec
        .fusion
        .as_ref()
        .is_some_and(|f| f.replay_sets.is_some());
    let mut sources_ended: Option<Instant> = None;
    while !shutdown.requested() && refused.is_none() {
        if let Some(w) = &watch {
            watchdog(&mut running, &w.reports, true);
            if let Ok(p) = w.progress.lock() {
                restart_stuck(&mut running, &p, &ctx.host, stall);
            }
            w.renew_lost_tokens();
        }
        for r in running.iter_mut() {
            if let Some(c) = &mut r.child
                && let Ok(Some(status)) = c.try_wait()
            {
                r.child = None;
                if status.success() {
                    tracing::info!("{} finished", r.spec.name);
                    r.finished = true;
                    continue;
                }
                if status.code() == Some(stereoscope_service::exit::CONFIG_EXIT_STATUS.into()) {
                    // The copier ends at the pipe's end, after the service's last line.
                    if let Some(t) = r.stderr_copier.take() {
                        let _ = t.join();
                    }
                    let message = r
                        .last_error_line
                        .lock()
                        .map(|l| l.clone())
                        .unwrap_or_default();
                    tracing::error!("{} refused its configuration; stopping", r.spec.name);
                    refused = Some(LaunchError::ServiceConfig {
                        service: r.spec.name.clone(),
                        message,
                    });
                    break;
                }
                // A service that was up for a while (not failing at start) is restarted at
                // the first delay again: killing it five times in a row costs 0.5 s each
                // time, not 0.5, 1, 2, 4, 8 s. Only quick failures back off.
                if r.started.elapsed() >= RAN_WELL {
                    r.backoff = FIRST_RESTART_DELAY;
                }
                tracing::warn!(
                    "{} exited ({status}); restarting in {:.1} s",
                    r.spec.name,
                    r.backoff.as_secs_f64()
                );
                r.restart_at = Some(Instant::now() + r.backoff);
                r.backoff = (r.backoff * 2).min(Duration::from_secs(10));
            }
            if r.child.is_none()
                && let Some(at) = r.restart_at
                && Instant::now() >= at
            {
                if let Err(e) = iox::cleanup_dead_nodes(&ctx.iox_prefix) {
                    tracing::warn!(
                        "cleaning dead iceoryx2 nodes: {}",
                        stereoscope_transport::error_chain(&e)
                    );
                }
                match spawn(&cfg, &r.spec, &session, &r.last_error_line) {
                    Ok((c, copier)) => {
                        tracing::info!("restarted {} (pid {})", r.spec.name, c.id());
                        r.child = Some(c);
                        r.stderr_copier = copier;
                        r.started = Instant::now();
                        r.restart_at = None;
                        r.restarts += 1;
                        restarts += 1;
                    }
                    Err(e) => {
                        tracing::error!("restarting {}: {e}", r.spec.name);
                        r.restart_at = Some(Instant::now() + r.backoff);
                    }
                }
            }
        }
        if cfg.until_sources_end {
            let captures = running
                .iter()
                .filter(|r| r.spec.name.starts_with("capture/"));
            if captures.clone().count() > 0 && captures.clone().all(|r| r.finished) {
                let ended = *sources_ended.get_or_insert_with(|| {
                    tracing::info!("every source ended");
                    Instant::now()
                });
                let fusion_done = running
                    .iter()
                    .filter(|r| r.spec.name == "fusion")
                    .all(|r| r.finished);
                let drain = if replaying {
                    MAX_DRAIN_AFTER_SOURCES_END
                } else {
                    DRAIN_AFTER_SOURCES_END
                };
                if (replaying && fusion_done) || ended.elapsed() >= drain {
                    if replaying && !fusion_done {
                        tracing::warn!(
                            "fusion did not finish the recording's sets within {drain:?} of the sources' end"
                        );
                    }
                    break;
                }
            }
        }
        shutdown.sleep(Duration::from_millis(50));
    }
    tracing::info!("stopping {} services", running.len());
    // The router last: the services' last reports and poses still reach their consumers.
    let (mut routers, mut services): (Vec<Running>, Vec<Running>) = running
        .into_iter()
        .partition(|r| r.spec.name == ROUTER_SERVICE && router.is_some());
    terminate(&mut services);
    drop(watch);
    terminate(&mut routers);
    // Nothing of the run stays behind in /dev/shm (unless another process still uses the
    // prefix: then it is left alone).
    if let Err(e) = iox::release_prefix(&ctx.iox_prefix) {
        tracing::warn!("cleaning up iceoryx2 files of {}: {e}", ctx.iox_prefix);
    }
    match refused {
        Some(e) => Err(e),
        None => Ok(restarts),
    }
}

/// Whether a service among `running` takes its input from other PCs' services (fusion, the
/// VR feed), so that the launcher follows their progress too.
fn services_inputs_elsewhere(running: &[Running]) -> bool {
    running
        .iter()
        .any(|r| r.spec.name == "fusion" || r.spec.name == "vrfeed")
}

/// Holds `<temp>/stereoscope-launchers/<prefix><host>.lock` for as long as the returned file
/// lives (the lock goes with the process, however it ends).
fn lock_host(prefix: &str, host: &str) -> Result<std::fs::File, LaunchError> {
    let dir = std::env::temp_dir().join("stereoscope-launchers");
    let lock = dir.join(format!("{prefix}{host}.lock"));
    let io = |source| LaunchError::Lock {
        lock: lock.clone(),
        source,
    };
    std::fs::create_dir_all(&dir).map_err(io)?;
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock)
        .map_err(io)?;
    match file.try_lock() {
        Ok(()) => Ok(file),
        Err(std::fs::TryLockError::WouldBlock) => Err(LaunchError::AlreadyRunning {
            host: host.to_string(),
            prefix: prefix.to_string(),
            lock,
        }),
        Err(std::fs::TryLockError::Error(e)) => Err(io(e)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_transport::net::ZenohMode;

    #[test]
    fn a_second_launcher_for_the_same_host_and_prefix_is_refused() {
        let prefix = format!("stsc_lock{}_", std::process::id());
        let first = lock_host(&prefix, "pc").unwrap();
        let err = lock_host(&prefix, "pc").unwrap_err();
        assert!(matches!(err, LaunchError::AlreadyRunning { .. }), "{err:?}");
        assert!(err.to_string().contains("already runs"), "{err}");
        // Another host, or another prefix, is another rig's business.
        let _other = lock_host(&prefix, "pc2").unwrap();
        drop(first);
        // Free again. Other tests of this process start children meanwhile, and a child
        // holds a copy of every open descriptor (the lock's too) from its fork until its
        // exec closes them: the lock comes free within that moment.
        let end = Instant::now() + Duration::from_secs(2);
        let again = loop {
            match lock_host(&prefix, "pc") {
                Ok(f) => break f,
                Err(e) if Instant::now() > end => panic!("{e}"),
                Err(_) => std::thread::sleep(Duration::from_millis(5)),
            }
        };
        drop(again);
    }

    /// A running child standing for service `name` (a real process: `sleep`).
    fn sleeping(name: &str, started: Instant) -> Running {
        Running {
            spec: ServiceSpec {
                name: name.into(),
                args: Vec::new(),
                frame_path: false,
            },
            child: Some(Command::new("sleep").arg("30").spawn().unwrap()),
            last_error_line: Arc::default(),
            stderr_copier: None,
            started,
            backoff: FIRST_RESTART_DELAY,
            restart_at: None,
            restarts: 0,
            finished: false,
            stuck_kills: 0,
        }
    }

    fn still_running(r: &mut Running) -> bool {
        r.child.as_mut().unwrap().try_wait().unwrap().is_none()
    }

    /// Fusion reporting no progress while a worker's count goes up is killed once the bound
    /// passed, then given twice the bound after its restart; the worker itself, progressing,
    /// is left alone; progress after the restart resets the bound.
    #[test]
    fn a_service_without_progress_while_its_inputs_flow_is_killed() {
        let s = Duration::from_secs(1);
        let stall = Duration::from_secs(3);
        let t0 = Instant::now() - s * 20;
        let mut p = progress::Progress::default();
        for i in 0..=20u32 {
            let at = t0 + s * i;
            p.report("pc", "moments/cam0", 100 * (u64::from(i) + 1), 1, at);
            p.report("pc", "fusion", 40, 2, at);
        }
        let mut running = vec![sleeping("moments/cam0", t0), sleeping("fusion", t0)];
        restart_stuck(&mut running, &p, "pc", stall);
        let status = running[1].child.as_mut().unwrap().wait().unwrap();
        assert!(!status.success(), "fusion was not killed: {status}");
        assert_eq!(running[1].stuck_kills, 1);
        assert!(still_running(&mut running[0]));
        // Restarted 4 s ago and still without progress: under twice the bound, left alone.
        let mut again = sleeping("fusion", Instant::now() - s * 4);
        again.stuck_kills = 1;
        let mut running = vec![again];
        restart_stuck(&mut running, &p, "pc", stall);
        assert!(still_running(&mut running[0]));
        assert_eq!(running[0].stuck_kills, 1);
        // It progresses after its restart: the count of kills starts again.
        p.report("pc", "fusion", 1, 3, Instant::now());
        restart_stuck(&mut running, &p, "pc", stall);
        assert_eq!(running[0].stuck_kills, 0);
        for r in &mut running {
            let c = r.child.as_mut().unwrap();
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    const DEMO_RIG: &str = include_str!("../../../deploy/rigs/demo.toml");
    use stereoscope_rig::Rig;

    fn ctx(text: &str, host: &str) -> Context {
        let rig = Rig::from_toml(text).unwrap();
        Context {
            rig_path: "r.toml".into(),
            rig,
            host: host.into(),
            iox_prefix: "p_".into(),
            zenoh: ZenohSpec::client_of("tcp/127.0.0.1:1"),
        }
    }

    /// Runs the launcher over the demo rig with every service replaced by `script` (a real
    /// child process); `until` decides, from how many times a service started so far, when to
    /// ask it to stop. Returns the launcher's result and the start count.
    fn supervise(script: &str, until: impl Fn(usize) -> bool) -> (Result<u32, LaunchError>, usize) {
        let dir = std::env::temp_dir().join(format!(
            "stereoscope-launcher-{}-{}",
            std::process::id(),
            script.len()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let count = dir.join("starts");
        let _ = std::fs::remove_file(&count);
        let mut c = ctx(DEMO_RIG, "local");
        c.iox_prefix = format!("stsc_l{}_{}_", std::process::id(), script.len());
        let cfg = LaunchConfig {
            ctx: c,
            program: vec![
                "sh".into(),
                "-c".into(),
                format!("echo x >> '{}'; {script}", count.display()),
                "sh".into(),
            ],
            env: Vec::new(),
            router: false,
            until_sources_end: false,
        };
        let starts = || {
            std::fs::read_to_string(&count)
                .map(|t| t.lines().count())
                .unwrap_or(0)
        };
        let shutdown = Shutdown::new();
        let (tx, rx) = std::sync::mpsc::channel();
        let s = shutdown.clone();
        let handle = std::thread::spawn(move || {
            let _ = tx.send(run(cfg, s));
        });
        let deadline = Instant::now() + Duration::from_secs(30);
        let result = loop {
            if let Ok(r) = rx.recv_timeout(Duration::from_millis(20)) {
                break r;
            }
            assert!(Instant::now() < deadline, "the launcher did not stop");
            if until(starts()) {
                shutdown.request();
            }
        };
        handle.join().unwrap();
        let n = starts();
        let _ = std::fs::remove_dir_all(&dir);
        (result, n)
    }

    #[test]
    fn a_service_that_refuses_its_configuration_stops_the_rig_unrestarted() {
        // Six services (capture and worker per camera, fusion, the VR feed); none is asked to
        // stop.
        let (result, starts) = supervise(
            "echo 'error: r.toml: camera[0].moments.max_objects: 0 is not between 1 and 64' >&2; exit 78",
            |_| false,
        );
        match result {
            Err(LaunchError::ServiceConfig { service, message }) => {
                assert!(!service.is_empty());
                assert!(
                    message.contains("camera[0].moments.max_objects"),
                    "{message}"
                );
            }
            other => panic!("expected a configuration stop, got {other:?}"),
        }
        assert!(starts <= 6, "a service was restarted: {starts} starts");
    }

    #[test]
    fn a_crashing_service_is_restarted() {
        let (result, starts) = supervise("exit 3", |n| n > 6);
        let restarts = result.unwrap();
        assert!(
            restarts >= 1 && starts > 6,
            "{restarts} restarts, {starts} starts"
        );
    }

    #[test]
    fn each_host_runs_its_own_services() {
        let text = "insecure = true\n".to_string()
            + &DEMO_RIG
                .replacen("id = \"cam0\"", "id = \"cam0\"\nhost = \"a\"", 1)
                .replacen("id = \"cam1\"", "id = \"cam1\"\nhost = \"b\"", 1)
                .replacen("[fusion]\n", "[fusion]\nhost = \"b\"\n", 1)
                .replacen("[vr]\n", "[vr]\nhost = \"b\"\n", 1)
            + "\n[[host]]\nname = \"a\"\nzenoh_listen = [\"tcp/0.0.0.0:7447\"]\n[[host]]\nname = \"b\"\nzenoh_listen = [\"tcp/127.0.0.1:7448\"]\nzenoh_connect = [\"tcp/10.0.0.1:7447\"]\n[[serial]]\nhost = \"b\"\nport = \"/dev/ttyUSB0\"\nmode = \"legacy\"\nobjects = [3, 1]\n";
        let a = ctx(&text, "a");
        let (router, client) = router_specs(&a).unwrap().unwrap();
        assert_eq!(router.mode, ZenohMode::Router);
        assert_eq!(client.connect, vec!["tcp/127.0.0.1:7447".to_string()]);
        let names: Vec<String> = services_here(&a, &client)
            .into_iter()
            .map(|s| s.name)
            .collect();
        assert_eq!(names, ["capture/cam0", "moments/cam0"]);
        let b = ctx(&text, "b");
        let (router, client) = router_specs(&b).unwrap().unwrap();
        assert_eq!(router.connect, vec!["tcp/10.0.0.1:7447".to_string()]);
        let specs = services_here(&b, &client);
        let names: Vec<&str> = specs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "capture/cam1",
                "moments/cam1",
                "serial/ttyUSB0",
                "fusion",
                "vrfeed"
            ]
        );
        assert!(
            specs[2].args.windows(2).any(|w| w == ["--mode", "legacy"]),
            "{:?}",
            specs[2].args
        );
        assert!(
            specs[2].args.windows(2).any(|w| w == ["--objects", "3,1"]),
            "{:?}",
            specs[2].args
        );
        let fusion = &specs[3].args;
        assert_eq!(fusion[0], "fusion");
        assert!(
            fusion.windows(2).any(|w| w == ["--host", "b"]),
            "{fusion:?}"
        );
    }

    /// A deployment rig as its PCs read it: from its folder, beside the `certs/` that
    /// `deploy/make-certs.sh` makes (here empty files: the router is not opened).
    fn deployed(text: &str, host: &str) -> Context {
        let dir = std::env::temp_dir().join(format!("stereoscope-deployed-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("certs")).unwrap();
        for h in [
            "capture1", "capture2", "fusion", "station", "ca", "pc0", "pc1", "pc2", "pc3", "pc4",
            "pc5",
        ] {
            for ext in ["pem", "key"] {
                std::fs::write(dir.join("certs").join(format!("{h}.{ext}")), "").unwrap();
            }
        }
        let path = dir.join("rig.toml");
        std::fs::write(&path, text).unwrap();
        let mut c = ctx(text, host);
        c.rig = Rig::load(&path).unwrap();
        c.rig_path = path;
        c
    }

    /// The deployment rigs in `deploy/rigs/` load, and each host runs what their comments say.
    #[test]
    fn the_deployment_rigs_give_each_host_its_services() {
        let names = |text: &str, host: &str| -> Vec<String> {
            let c = deployed(text, host);
            let (_, client) = router_specs(&c).unwrap().unwrap();
            services_here(&c, &client)
                .into_iter()
                .map(|s| s.name)
                .collect()
        };
        let three = include_str!("../../../deploy/rigs/three-pcs.toml");
        assert_eq!(
            names(three, "capture1"),
            [
                "capture/cam0",
                "moments/cam0",
                "capture/cam1",
                "moments/cam1"
            ]
        );
        assert_eq!(
            names(three, "capture2"),
            [
                "capture/cam2",
                "moments/cam2",
                "capture/cam3",
                "moments/cam3"
            ]
        );
        assert_eq!(names(three, "fusion"), ["fusion"]);
        let c = deployed(three, "capture1");
        let (router, client) = router_specs(&c).unwrap().unwrap();
        assert_eq!(router.connect, ["tls/192.168.10.20:7447"]);
        // The router also listens on loopback for its services, which connect there.
        assert_eq!(
            router.listen,
            ["tls/192.168.10.11:7447", "tcp/127.0.0.1:7446"]
        );
        assert_eq!(client.connect, ["tcp/127.0.0.1:7446"]);
        let tls = router.tls.unwrap();
        assert!(tls.cert.ends_with("certs/capture1.pem"), "{tls:?}");
        let acl: serde_json::Value = serde_json::from_str(&router.access_control.unwrap()).unwrap();
        assert_eq!(acl["default_permission"], "deny");
        // Without its certificate a PC does not start its router, and says which file.
        std::fs::remove_file(c.rig_path.parent().unwrap().join("certs/capture1.key")).unwrap();
        let e = router_specs(&c).unwrap_err();
        assert_eq!(e.key, "host[0].tls.key");
        assert!(e.message.contains("capture1.key"), "{e}");
        let ring = include_str!("../../../deploy/rigs/one-pc-per-camera.toml");
        for k in 0..6 {
            assert_eq!(
                names(ring, &format!("pc{k}")),
                [format!("capture/cam{k}"), format!("moments/cam{k}")]
            );
        }
        assert_eq!(names(ring, "station"), ["fusion"]);
    }
}
