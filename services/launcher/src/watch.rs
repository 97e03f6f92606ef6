//! The launcher's judgement of its running services: silent ones (no health report), ones
//! that did not rejoin a restarted router, and ones that make no progress while their inputs
//! flow (`progress`).

use crate::{REJOIN, ROUTER_SERVICE, Running, WATCHDOG, progress};
use std::sync::Mutex;
use std::time::{Duration, Instant};

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
    reports: &Mutex<std::collections::HashMap<String, Instant>>,
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
