//! The launcher: one per PC. It reads the rig file, starts the services assigned to this host
//! (a capture and a moment worker per camera here, fusion if it is here) as separate
//! processes, prefixes their log lines with the service name, restarts one that fails with a
//! growing delay (0.5 s doubling to 10 s; reset once it has run 30 s) — a service that exits
//! successfully has finished (a capture at the end of a file) and is not restarted —, removes what dead
//! iceoryx2 nodes left behind before each start, and on Ctrl-C/SIGTERM stops every child
//! (SIGTERM, then SIGKILL after 3 s). It also runs this PC's Zenoh router, which its services
//! join as clients and other PCs' routers connect to (`docs/deploy.md`).
//!
//! Children die with the launcher (PR_SET_PDEATHSIG), so nothing is left running if it is
//! killed outright.

pub mod demo;
pub mod status;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use stereoscope_rig::Context;
use stereoscope_rig::context::local_endpoint;
use stereoscope_transport::net::{ZenohMode, ZenohSpec};
use stereoscope_transport::{Shutdown, iox, net};

/// One service to run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceSpec {
    /// "capture/cam0", "moments/cam0", "fusion".
    pub name: String,
    /// Arguments after the program prefix.
    pub args: Vec<String>,
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
    /// Stop once every capture has finished (its finite source ended), after
    /// [`DRAIN_AFTER_SOURCES_END`] for the workers and fusion to finish the last frames: for
    /// replaying recorded frames.
    pub until_sources_end: bool,
}

/// How long the other services run on after the last capture finished, with
/// [`LaunchConfig::until_sources_end`].
pub const DRAIN_AFTER_SOURCES_END: Duration = Duration::from_millis(1500);

#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    #[error("launcher: {0}")]
    Setup(String),
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
        });
    }
    if ctx.fusion_here() && ctx.rig.spec.fusion.is_some() {
        let mut args = vec!["fusion".to_string()];
        args.extend(common);
        out.push(ServiceSpec {
            name: "fusion".into(),
            args,
        });
    }
    out
}

struct Running {
    spec: ServiceSpec,
    child: Option<Child>,
    started: Instant,
    backoff: Duration,
    restart_at: Option<Instant>,
    restarts: u32,
    /// Exited successfully: done, not restarted.
    finished: bool,
}

fn pipe_lines(name: String, stream: impl std::io::Read + Send + 'static, to_err: bool) {
    std::thread::spawn(move || {
        for line in BufReader::new(stream).lines() {
            let Ok(line) = line else { break };
            if to_err {
                eprintln!("[{name}] {line}");
            } else {
                println!("[{name}] {line}");
            }
        }
    });
}

fn spawn(cfg: &LaunchConfig, spec: &ServiceSpec) -> std::io::Result<Child> {
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
    for (k, v) in &cfg.env {
        cmd.env(k, v);
    }
    // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        use std::os::unix::process::CommandExt;
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = cmd.spawn()?;
    if let Some(out) = child.stdout.take() {
        pipe_lines(spec.name.clone(), out, false);
    }
    if let Some(err) = child.stderr.take() {
        pipe_lines(spec.name.clone(), err, true);
    }
    Ok(child)
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

/// Where a PC's router listens when the rig file names no `[[host]]`: loopback only.
pub const DEFAULT_ROUTER: &str = "tcp/127.0.0.1:7447";

/// The Zenoh spec of this host's router, and that of its services (clients of it). A rig with
/// no `[[host]]` runs on one PC with its router on [`DEFAULT_ROUTER`].
pub fn router_specs(ctx: &Context) -> Option<(ZenohSpec, ZenohSpec)> {
    let (listen, connect) = match ctx.rig.spec.hosts.iter().find(|h| h.name == ctx.host) {
        Some(h) => (h.zenoh_listen.clone(), h.zenoh_connect.clone()),
        None if ctx.rig.spec.hosts.is_empty() => (vec![DEFAULT_ROUTER.to_string()], Vec::new()),
        None => return None,
    };
    let first = listen.first()?.clone();
    Some((
        ZenohSpec {
            mode: ZenohMode::Router,
            connect,
            listen,
        },
        ZenohSpec::client_of(&local_endpoint(&first)),
    ))
}

/// Runs this host's services until shutdown. Returns how many restarts happened.
pub fn run(cfg: LaunchConfig, shutdown: Shutdown) -> Result<u32, LaunchError> {
    let ctx = &cfg.ctx;
    // The router first, so the services' clients find it.
    let (router, service_zenoh) = match router_specs(ctx) {
        Some((r, s)) if cfg.router => (Some(r), s),
        Some((_, s)) => (None, s),
        None => (None, ctx.zenoh.clone()),
    };
    let _router = match &router {
        Some(r) => {
            let s = net::open(r).map_err(|e| LaunchError::Setup(e.to_string()))?;
            tracing::info!("zenoh router listening on {:?}", r.listen);
            Some(s)
        }
        None => None,
    };
    let specs = services_here(ctx, &service_zenoh);
    if specs.is_empty() {
        return Err(LaunchError::Setup(format!(
            "{} assigns no service to host {:?}",
            ctx.rig_path.display(),
            ctx.host
        )));
    }
    match iox::cleanup_dead_nodes(&ctx.iox_prefix) {
        Ok(n) if n > 0 => tracing::info!("removed the leftovers of {n} dead iceoryx2 nodes"),
        Ok(_) => {}
        Err(e) => tracing::warn!("cleaning dead iceoryx2 nodes: {e}"),
    }
    let mut running: Vec<Running> = Vec::new();
    for spec in specs {
        let child = spawn(&cfg, &spec)
            .map_err(|e| LaunchError::Setup(format!("starting {}: {e}", spec.name)))?;
        tracing::info!("started {} (pid {})", spec.name, child.id());
        running.push(Running {
            spec,
            child: Some(child),
            started: Instant::now(),
            backoff: Duration::from_millis(500),
            restart_at: None,
            restarts: 0,
            finished: false,
        });
    }
    let mut restarts = 0;
    while !shutdown.requested() {
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
                if r.started.elapsed() > Duration::from_secs(30) {
                    r.backoff = Duration::from_millis(500);
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
                    tracing::warn!("cleaning dead iceoryx2 nodes: {e}");
                }
                match spawn(&cfg, &r.spec) {
                    Ok(c) => {
                        tracing::info!("restarted {} (pid {})", r.spec.name, c.id());
                        r.child = Some(c);
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
                tracing::info!("every source ended");
                shutdown.sleep(DRAIN_AFTER_SOURCES_END);
                break;
            }
        }
        shutdown.sleep(Duration::from_millis(50));
    }
    tracing::info!("stopping {} services", running.len());
    terminate(&mut running);
    let _ = iox::cleanup_dead_nodes(&ctx.iox_prefix);
    Ok(restarts)
}

#[cfg(test)]
mod tests {
    use super::*;
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

    #[test]
    fn each_host_runs_its_own_services() {
        let text = demo::DEMO_RIG
            .replacen("id = \"cam0\"", "id = \"cam0\"\nhost = \"a\"", 1)
            .replacen("id = \"cam1\"", "id = \"cam1\"\nhost = \"b\"", 1)
            .replacen("[fusion]\n", "[fusion]\nhost = \"b\"\n", 1)
            + "\n[[host]]\nname = \"a\"\nzenoh_listen = [\"tcp/0.0.0.0:7447\"]\n[[host]]\nname = \"b\"\nzenoh_listen = [\"tcp/127.0.0.1:7448\"]\nzenoh_connect = [\"tcp/10.0.0.1:7447\"]\n[[serial]]\nhost = \"b\"\nport = \"/dev/ttyUSB0\"\nmode = \"legacy\"\nobjects = [3, 1]\n";
        let a = ctx(&text, "a");
        let (router, client) = router_specs(&a).unwrap();
        assert_eq!(router.mode, ZenohMode::Router);
        assert_eq!(client.connect, vec!["tcp/127.0.0.1:7447".to_string()]);
        let names: Vec<String> = services_here(&a, &client)
            .into_iter()
            .map(|s| s.name)
            .collect();
        assert_eq!(names, ["capture/cam0", "moments/cam0"]);
        let b = ctx(&text, "b");
        let (router, client) = router_specs(&b).unwrap();
        assert_eq!(router.connect, vec!["tcp/10.0.0.1:7447".to_string()]);
        let specs = services_here(&b, &client);
        let names: Vec<&str> = specs.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            ["capture/cam1", "moments/cam1", "serial/ttyUSB0", "fusion"]
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
}
