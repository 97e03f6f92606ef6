//! A service's health: a liveliness token while it runs, and a `Health` report on Zenoh every
//! second (`docs/protocol.md`, "Health").

use crate::TransportError;
use crate::net::JsonPublisher;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Health, SCHEMA_VERSION, now_ns};
use stereoscope_proto::names::zenoh as keys;
use zenoh::Wait;

/// What a service counts, reported by [`HealthReporter::tick`].
#[derive(Debug, Clone, Default)]
pub struct Counters {
    pub processed: u64,
    pub dropped: u64,
    pub rejected: u64,
    pub last_error: Option<String>,
    pub detail: BTreeMap<String, String>,
}

impl Counters {
    /// Counts frames `first..=last` of `what` as dropped and names them in the health
    /// report's `last_lost` detail, so a missing pose can be traced to the frame behind it.
    pub fn lost_frames(&mut self, what: &str, first: u64, last: u64) {
        if last < first {
            return;
        }
        self.dropped += last - first + 1;
        let frames = if first == last {
            format!("{what} frame {first}")
        } else {
            format!("{what} frames {first}–{last}")
        };
        self.detail.insert("last_lost".into(), frames);
    }

    /// Keeps the error of a failed publication (or any side effect the service carries on
    /// after) as the last error; the service goes on either way.
    pub fn note<T, E: std::error::Error + 'static>(&mut self, result: Result<T, E>) {
        if let Err(e) = result {
            self.last_error = Some(crate::error_chain(&e));
        }
    }
}

pub struct HealthReporter {
    publisher: JsonPublisher,
    _token: zenoh::liveliness::LivelinessToken,
    rig: String,
    host: String,
    service: String,
    started_ns: u64,
    interval: Duration,
    last: Instant,
    last_processed: u64,
}

impl std::fmt::Debug for HealthReporter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HealthReporter({}/{})", self.host, self.service)
    }
}

impl HealthReporter {
    /// `service` may contain one `/` (`capture/cam0`).
    pub fn new(
        session: &zenoh::Session,
        rig: &str,
        host: &str,
        service: &str,
    ) -> Result<Self, TransportError> {
        let publisher = JsonPublisher::new(session, &keys::health(rig, host, service))?;
        let token = session
            .liveliness()
            .declare_token(keys::alive(rig, host, service))
            .wait()
            .map_err(|e| TransportError::Zenoh {
                what: format!("liveliness token for {service}"),
                source: crate::ZenohCause(e),
            })?;
        Ok(HealthReporter {
            publisher,
            _token: token,
            rig: rig.into(),
            host: host.into(),
            service: service.into(),
            started_ns: now_ns(),
            interval: Duration::from_secs(1),
            last: Instant::now(),
            last_processed: 0,
        })
    }

    /// Whether the next [`HealthReporter::tick`] publishes: fill `Counters::detail` only
    /// then, so the per-frame loop does not format strings it throws away.
    pub fn due(&self) -> bool {
        self.last.elapsed() >= self.interval
    }

    /// Publishes a report when the interval has passed.
    pub fn tick(&mut self, c: &Counters) {
        if self.last.elapsed() >= self.interval {
            self.report(c);
        }
    }

    /// Publishes a report now (a service's last, as it stops: its final counts).
    pub fn report(&mut self, c: &Counters) {
        let elapsed = self.last.elapsed().max(Duration::from_millis(1));
        let rate = (c.processed.saturating_sub(self.last_processed)) as f64 / elapsed.as_secs_f64();
        self.last = Instant::now();
        self.last_processed = c.processed;
        let h = Health {
            schema: SCHEMA_VERSION,
            rig: self.rig.clone(),
            host: self.host.clone(),
            service: self.service.clone(),
            pid: std::process::id(),
            started_ns: self.started_ns,
            published_ns: now_ns(),
            processed: c.processed,
            rate_hz: rate,
            dropped: c.dropped,
            rejected: c.rejected,
            last_error: c.last_error.clone(),
            detail: c.detail.clone(),
        };
        if let Err(e) = self.publisher.put(&h) {
            tracing::warn!("health report: {}", crate::error_chain(&e));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lost_frames_are_counted_and_named() {
        let mut c = Counters::default();
        c.lost_frames("cam0", 5, 4);
        assert_eq!(c.dropped, 0);
        c.lost_frames("cam0", 7, 7);
        assert_eq!(c.detail["last_lost"], "cam0 frame 7");
        c.lost_frames("cam1", 10, 12);
        assert_eq!(c.dropped, 4);
        assert_eq!(c.detail["last_lost"], "cam1 frames 10–12");
    }
}
