//! A service's health: a liveliness token while it runs, and a `Health` report on Zenoh every
//! second (`docs/protocol.md`, "Health").

use crate::TransportError;
use crate::net::JsonPublisher;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Detail, Health, SCHEMA_VERSION, limits, now_ns};
use stereoscope_proto::names::zenoh as keys;
use zenoh::Wait;

/// What a service counts, reported by [`HealthReporter::tick`]. The last error is kept
/// within [`limits::MAX_TEXT_BYTES`] whatever an input put in it.
#[derive(Debug, Clone, Default)]
pub struct Counters {
    pub processed: u64,
    pub dropped: u64,
    pub rejected: u64,
    last_error: Option<String>,
    pub detail: BTreeMap<String, String>,
}

/// `text` cut to at most `max` bytes at a character boundary, marked with "…" when cut.
pub fn bounded(text: &str, max: usize) -> String {
    if text.len() <= max {
        return text.to_string();
    }
    let mut end = max.saturating_sub('…'.len_utf8());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &text[..end])
}

impl Counters {
    /// The last problem met.
    pub fn last_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    /// Keeps `message` as the last problem (bounded).
    pub fn set_error(&mut self, message: &str) {
        self.last_error = Some(bounded(message, limits::MAX_TEXT_BYTES));
    }

    /// Reports `value` as the service's figure `key` (`detail` in its health).
    pub fn set(&mut self, key: Detail, value: impl std::fmt::Display) {
        self.detail.insert(key.key().to_string(), value.to_string());
    }

    /// [`Counters::set`] for a count worth reporting only once it is not zero.
    pub fn set_nonzero(&mut self, key: Detail, count: u64) {
        if count > 0 {
            self.set(key, count);
        }
    }

    /// Counts one rejected input under `reason` (`detail["rejected.<reason>"]`) and keeps its
    /// message as the last error.
    pub fn reject(&mut self, reason: &str, message: &str) {
        self.rejected += 1;
        let n = self
            .detail
            .entry(format!("rejected.{reason}"))
            .or_insert_with(|| "0".into());
        *n = (n.parse::<u64>().unwrap_or(0) + 1).to_string();
        self.set_error(message);
    }

    /// What was refused, for a person: "3 refused (foreign 2, schema 1); the last: …", or
    /// `None` when nothing was.
    pub fn refusals(&self) -> Option<String> {
        if self.rejected == 0 {
            return None;
        }
        let reasons: Vec<String> = self
            .detail
            .iter()
            .filter_map(|(k, v)| Some(format!("{} {v}", k.strip_prefix("rejected.")?)))
            .collect();
        Some(format!(
            "{} refused ({}); the last: {}",
            self.rejected,
            reasons.join(", "),
            self.last_error().unwrap_or("")
        ))
    }

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
        self.set(Detail::LastLost, frames);
    }

    /// Keeps the error of a failed publication (or any side effect the service carries on
    /// after) as the last error; the service goes on either way.
    pub fn note<T, E: std::error::Error + 'static>(&mut self, result: Result<T, E>) {
        if let Err(e) = result {
            self.set_error(&crate::error_chain(&e));
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

    /// An input that carries megabytes of text leaves a bounded last error, counted by reason.
    #[test]
    fn rejections_are_counted_by_reason_and_their_text_is_bounded() {
        let mut c = Counters::default();
        let huge = "é".repeat(5_000_000);
        c.reject("invalid", &huge);
        c.reject("invalid", "short");
        c.reject("future", &huge);
        assert_eq!(c.rejected, 3);
        assert_eq!(c.detail["rejected.invalid"], "2");
        assert_eq!(c.detail["rejected.future"], "1");
        let e = c.last_error().unwrap();
        assert!(
            e.len() <= limits::MAX_TEXT_BYTES && e.ends_with('…'),
            "{}",
            e.len()
        );
        assert_eq!(bounded("abc", 10), "abc");
    }
}
