//! The launcher's judgement of its running services: silent ones (no health report), ones
//! that did not rejoin a restarted router, ones that make no progress while their inputs
//! flow (`progress`), and ones whose liveliness token this PC's router lost (`tokens`).

use crate::{LaunchError, REJOIN, ROUTER_SERVICE, Running, WATCHDOG, progress, tokens};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Detail, Health, Message, SCHEMA_VERSION, TokenRenewal};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_transport::net;
use zenoh::Wait;

/// What the launcher hears through this PC's router, as one of its clients (the session
/// rejoins a restarted router): its services' newest health reports (they come every second
/// from each service's own loop, so none means the loop is stuck or the process stopped);
/// every host's reports where a service here takes another PC's output (fusion: every
/// worker; the VR feed: fusion), for what flows (`progress`) — a capture PC's launcher draws
/// no other PC's health across the network, toward a PC whose link may be cut; and the
/// liveliness tokens the router holds, beside the reports, for tokens it lost.
pub(crate) struct Watch {
    pub reports: Arc<Mutex<HashMap<String, Instant>>>,
    pub progress: Arc<Mutex<progress::Progress>>,
    tokens: Arc<Mutex<tokens::Tokens>>,
    rig: String,
    host: String,
    _health: net::NetSubscriber,
    _alive: net::NetSubscriber,
    session: zenoh::Session,
}

impl Watch {
    pub fn start(
        session: zenoh::Session,
        rig: &str,
        host: &str,
        elsewhere: bool,
    ) -> Result<Watch, LaunchError> {
        let reports: Arc<Mutex<HashMap<String, Instant>>> = Arc::default();
        let progress: Arc<Mutex<progress::Progress>> = Arc::default();
        let tokens: Arc<Mutex<tokens::Tokens>> = Arc::default();
        let all = format!("stereoscope/{rig}/health/");
        let here = format!("{all}{host}/");
        let key = if elsewhere {
            format!("{all}**")
        } else {
            format!("{here}**")
        };
        let health = {
            let (reports, progress, tokens) = (reports.clone(), progress.clone(), tokens.clone());
            net::subscribe(&session, &key, move |key, bytes| {
                let now = Instant::now();
                if let Some(service) = key.strip_prefix(&here)
                    && let Ok(mut r) = reports.lock()
                {
                    r.insert(service.to_string(), now);
                }
                // A report that does not decode, or comes on another's key, is no one's.
                let Ok(h) = Health::from_json(bytes) else {
                    return;
                };
                let id = format!("{}/{}", h.host, h.service);
                if key.strip_prefix(&all) != Some(id.as_str()) {
                    return;
                }
                if let Ok(mut p) = progress.lock() {
                    p.report(&h.host, &h.service, h.processed, h.started_ns, now);
                    if h.service == "fusion" {
                        let live = h.detail.get(Detail::CamerasLive.key());
                        p.fusion_hears(&h.host, live.map_or("", String::as_str), now);
                    }
                }
                if let Ok(mut t) = tokens.lock() {
                    t.report(&id, now);
                }
            })?
        };
        let alive = {
            let tokens = tokens.clone();
            let prefix = format!("stereoscope/{rig}/alive/");
            session
                .liveliness()
                .declare_subscriber(keys::all_alive(rig))
                .history(true)
                .callback(move |sample| {
                    let Some(id) = sample.key_expr().as_str().strip_prefix(&prefix) else {
                        return;
                    };
                    let present = sample.kind() == zenoh::sample::SampleKind::Put;
                    if let Ok(mut t) = tokens.lock() {
                        t.token(id, present);
                    }
                })
                .wait()
                .map_err(|e| {
                    LaunchError::Transport(stereoscope_transport::TransportError::Zenoh {
                        what: format!("liveliness subscriber {}", keys::all_alive(rig)),
                        source: stereoscope_transport::ZenohCause(e),
                    })
                })?
        };
        Ok(Watch {
            reports,
            progress,
            tokens,
            rig: rig.to_string(),
            host: host.to_string(),
            _health: health,
            _alive: alive,
            session,
        })
    }

    /// Asks each service whose token this PC's router lost to declare it again
    /// ([`tokens::Tokens::due`]).
    pub fn renew_lost_tokens(&self) {
        let due = match self.tokens.lock() {
            Ok(mut t) => t.due(Instant::now()),
            Err(_) => return,
        };
        for ask in due {
            let id = format!("{}/{}", ask.host, ask.service);
            tracing::warn!(
                "{id}: reporting, but this PC's router has held no liveliness token for it for \
                 {:.1} s; asking it to declare it again",
                ask.missing.as_secs_f64()
            );
            let request = TokenRenewal {
                schema: SCHEMA_VERSION,
                rig: self.rig.clone(),
                host: ask.host.clone(),
                service: ask.service.clone(),
                asked_by: self.host.clone(),
                missing_s: ask.missing.as_secs_f64(),
            };
            let key = keys::renew(&self.rig, &ask.host, &ask.service);
            if let Err(e) = self.session.put(key, request.to_json()).wait() {
                tracing::warn!("asking {id} to renew its token: {e}");
            }
        }
    }
}

/// Kills (SIGKILL) a service that reported its health since it started and then fell silent
/// for [`WATCHDOG`]: stopped (SIGSTOP), or stuck in a step. The restart follows as for any
/// service that died. (One that never reported — still starting, or not a Stereoscope
/// service — is left to itself.)
///
/// With the router a child of the launcher (`supervised_router`), reports reach the launcher
/// through it: while it is down nothing is judged; after it (re)started, a service is judged
/// by its reports since then, and one that reported before the restart and is not heard for
/// [`REJOIN`] after it did not rejoin the router, and is restarted too.
pub(crate) fn watchdog(
    running: &mut [Running],
    reports: &Mutex<HashMap<String, Instant>>,
    supervised_router: bool,
) {
    let router_since = if supervised_router {
        match running.iter().find(|r| r.spec.name == ROUTER_SERVICE) {
            Some(r) if r.child.is_some() => Some(r.started),
            // Down, or waiting for its restart: no report can arrive.
            _ => return,
        }
    } else {
        None
    };
    let Ok(reports) = reports.lock() else {
        return;
    };
    for r in running.iter_mut() {
        let Some(child) = &mut r.child else {
            continue;
        };
        let Some(last) = reports
            .get(&r.spec.name)
            .copied()
            .filter(|t| *t > r.started)
        else {
            continue;
        };
        let silent = match router_since {
            // Heard since the router's start: the usual bound.
            Some(since) if last <= since && r.started <= since => {
                (since.elapsed() > REJOIN).then(|| {
                    format!(
                        "not heard since the router restarted {:.1} s ago (it did not rejoin it)",
                        since.elapsed().as_secs_f64()
                    )
                })
            }
            _ => (last.elapsed() > WATCHDOG)
                .then(|| format!("no health report for {:.1} s", last.elapsed().as_secs_f64())),
        };
        if let Some(why) = silent {
            tracing::warn!("{}: {why}; killing it to restart it", r.spec.name);
            let _ = child.kill();
        }
    }
}

/// Kills a service that makes no progress while its inputs flow ([`progress`]) for `stall`
/// — doubled after each such kill of it that did not bring its progress back, up to a
/// minute, so that an input it cannot reach (a link's access rules) does not restart it
/// every few seconds. The restart follows as for any service that died.
pub(crate) fn restart_stuck(
    running: &mut [Running],
    p: &progress::Progress,
    host: &str,
    stall: Duration,
) {
    let now = Instant::now();
    for r in running.iter_mut() {
        let Some(child) = &mut r.child else {
            continue;
        };
        if r.stuck_kills > 0 && p.progressed_since(host, &r.spec.name, r.started) {
            r.stuck_kills = 0;
        }
        let bound = (stall * 2u32.saturating_pow(r.stuck_kills.min(5)))
            .min(Duration::from_secs(60))
            .max(stall);
        if let Some(input) = p.stuck(host, &r.spec.name, r.started, now, bound) {
            tracing::warn!(
                "{}: no progress for {:.1} s while {input} flows; killing it to restart it",
                r.spec.name,
                bound.as_secs_f64()
            );
            // Reaped here (a killed process goes at once), so the next check does not count
            // it again; the loop below sees its status and restarts it.
            let _ = child.kill();
            let _ = child.wait();
            r.stuck_kills += 1;
        }
    }
}

/// The frame rate of the rig's slowest camera whose source states one.
pub(crate) fn slowest_fps(rig: &stereoscope_rig::Rig) -> Option<f64> {
    use stereoscope_rig::schema::SourceSpec;
    rig.spec
        .cameras
        .iter()
        .filter_map(|c| match c.source.as_ref()? {
            SourceSpec::Synthetic { fps, .. } | SourceSpec::Images { fps, .. } => Some(*fps),
            SourceSpec::V4l { fps, .. } | SourceSpec::Genicam { fps, .. } => *fps,
            SourceSpec::Y4m { .. } => None,
        })
        .min_by(f64::total_cmp)
}
