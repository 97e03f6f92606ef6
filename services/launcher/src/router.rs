//! This PC's Zenoh router: its endpoints from the rig, the process that runs it
//! (`stereoscope service router`, reporting health like a service), and the launcher's waits
//! around its start.

use crate::{LaunchError, ROUTER_SERVICE, ROUTER_START};
use std::process::Child;
use std::time::{Duration, Instant};
use stereoscope_proto::messages::Detail;
use stereoscope_rig::{RigError, security};
use stereoscope_service::Context;
use stereoscope_transport::net::{ZenohMode, ZenohSpec};
use stereoscope_transport::{Shutdown, net};
use zenoh::Wait;

/// Where a PC's router listens when the rig file names no `[[host]]`: loopback only.
pub const DEFAULT_ROUTER: &str = "tcp/127.0.0.1:7447";

/// The Zenoh spec of this host's router, and that of its services (clients of it). A rig with
/// no `[[host]]` runs on one PC with its router on [`DEFAULT_ROUTER`]; with TLS the router
/// also listens on loopback for its services and enforces the rig's access control
/// (`stereoscope_rig::security`).
pub fn router_specs(ctx: &Context) -> Result<Option<(ZenohSpec, ZenohSpec)>, RigError> {
    if ctx.rig.spec.hosts.is_empty() {
        return Ok(Some((
            ZenohSpec {
                mode: ZenohMode::Router,
                connect: Vec::new(),
                listen: vec![DEFAULT_ROUTER.to_string()],
                tls: None,
                access_control: None,
            },
            ZenohSpec::client_of(DEFAULT_ROUTER),
        )));
    }
    let base = ctx.rig.base_dir.as_deref();
    let Some(router) = stereoscope_service::router::router_spec(&ctx.rig.spec, &ctx.host, base)?
    else {
        return Ok(None);
    };
    let local = ctx
        .rig
        .spec
        .hosts
        .iter()
        .find(|h| h.name == ctx.host)
        .and_then(security::service_endpoint);
    // With local_auth the services show the host's certificate, as the router does.
    let local_auth = ctx
        .rig
        .spec
        .hosts
        .iter()
        .any(|h| h.name == ctx.host && h.local_auth);
    Ok(local.map(|l| {
        let mut client = ZenohSpec::client_of(&l);
        if local_auth {
            client.tls = router.tls.clone();
        }
        (router, client)
    }))
}

/// Runs only this host's Zenoh router (`stereoscope service router`) until shutdown: for a
/// PC that runs no service but should relay (a consumer PC), or to keep the router out of a
/// process that measures it (`stereoscope demo`).
pub fn run_router(ctx: &Context, shutdown: &Shutdown) -> Result<(), LaunchError> {
    let Some((router, _)) = router_specs(ctx).map_err(|e| e.in_file(&ctx.rig_path))? else {
        return Err(LaunchError::NothingHere {
            rig: ctx.rig_path.clone(),
            host: ctx.host.clone(),
        });
    };
    let session = net::open(&router)?;
    tracing::info!("zenoh router listening on {:?}", router.listen);
    // Alive and reporting like a service, so `status`, the viewer and the launcher's watchdog
    // see it: what it listens on, and the routers of other PCs it is linked to.
    let mut health = stereoscope_transport::health::HealthReporter::new(
        &session,
        &ctx.rig.name,
        &ctx.host,
        ROUTER_SERVICE,
    )?;
    let mut counters = stereoscope_transport::Counters::default();
    counters.set(Detail::Listen, router.listen.join(" "));
    loop {
        if health.due() {
            let linked = session.info().routers_zid().wait().count();
            counters.set(Detail::Routers, linked);
            health.report(&counters);
        }
        if shutdown.sleep(Duration::from_millis(200)) {
            break;
        }
    }
    health.report(&counters);
    Ok(())
}

/// The router's command line (`stereoscope service router`).
pub mod router_cli {
    use stereoscope_service::{CommonArgs, ServiceArgs};
    use stereoscope_transport::Shutdown;

    #[derive(clap::Args, Debug, Clone)]
    pub struct Args {
        #[command(flatten)]
        pub common: CommonArgs,
    }

    impl ServiceArgs for Args {
        const NAME: &'static str = "router";
        const ABOUT: &'static str =
            "Run this host's Zenoh router (with the rig's TLS and access control)";

        /// Runs the router until SIGINT/SIGTERM.
        fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
            let ctx = self.common.resolve()?;
            super::run_router(&ctx, &shutdown)?;
            Ok(format!("host {}", ctx.host))
        }
    }
}

/// Waits, for at most [`ROUTER_START`], until nothing takes connections at the services'
/// endpoint of this PC's router: the router of a launcher of this host that was just killed
/// may still be stopping (its children get SIGTERM), and a new router would find its port
/// taken, or the new services would join the old router as it goes.
pub(crate) fn wait_for_port_free(services: &ZenohSpec, shutdown: &Shutdown) {
    let end = Instant::now() + ROUTER_START;
    while net::why_unreachable(services).is_none() && Instant::now() < end {
        if shutdown.sleep(Duration::from_millis(50)) {
            return;
        }
    }
}

/// Waits until this PC's router (`child`, just started) takes connections at the services'
/// endpoint, for at most [`ROUTER_START`].
pub(crate) fn wait_for_router(
    child: &mut Child,
    services: &ZenohSpec,
    shutdown: &Shutdown,
) -> Result<(), LaunchError> {
    let end = Instant::now() + ROUTER_START;
    loop {
        if let Ok(Some(status)) = child.try_wait() {
            return Err(LaunchError::RouterExited {
                status: status.to_string(),
            });
        }
        let why = net::why_unreachable(services);
        match why {
            None => return Ok(()),
            Some(_) if shutdown.requested() => return Ok(()),
            Some(why) if Instant::now() >= end => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(LaunchError::RouterNotUp {
                    waited: ROUTER_START,
                    why,
                });
            }
            Some(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}
