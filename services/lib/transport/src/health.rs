//! A service's health: a liveliness token while it runs, and a `Health` report on Zenoh every
//! second (`docs/protocol.md`, "Health"); the token declared anew when a launcher asks
//! (`TokenRenewal`: a router lost it while the service ran).

use crate::TransportError;
use crate::net::{JsonPublisher, NetSubscriber};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{
    Detail, Health, Message, SCHEMA_VERSION, TokenRenewal, limits, now_ns,
};
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

/// A service's token is declared anew at most this often, however often it is asked (a
/// client with a host's certificate asking in a loop makes it flap no faster).
pub const RENEW_AT_MOST_EVERY: Duration = Duration::from_secs(2);

pub struct HealthReporter {
    publisher: JsonPublisher,
    session: zenoh::Session,
    token: Option<zenoh::liveliness::LivelinessToken>,
    /// The newest renewal request not yet acted on.
    asked: Arc<Mutex<Option<TokenRenewal>>>,
    _renew: NetSubscriber,
    renewed: u64,
    last_renewal: Option<Instant>,
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
        let token = declare_token(session, rig, host, service)?;
        let asked: Arc<Mutex<Option<TokenRenewal>>> = Arc::default();
        let renew = {
            let asked = asked.clone();
            let (rig, host, service) = (rig.to_string(), host.to_string(), service.to_string());
            crate::net::subscribe(session, &keys::renew(&rig, &host, &service), move |_, b| {
                // Only a well-formed request for this very service is acted on.
                match TokenRenewal::from_json(b) {
                    Ok(r) if r.rig == rig && r.host == host && r.service == service => {
                        if let Ok(mut a) = asked.lock() {
                            *a = Some(r);
                        }
                    }
                    Ok(_) => {}
                    Err(e) => tracing::warn!("a token renewal request that does not decode: {e}"),
                }
            })?
        };
        Ok(HealthReporter {
            publisher,
            session: session.clone(),
            token: Some(token),
            asked,
            _renew: renew,
            renewed: 0,
            last_renewal: None,
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

    /// Publishes a report now (a service's last, as it stops: its final counts), after
    /// declaring the token anew if a launcher asked (at most every [`RENEW_AT_MOST_EVERY`]).
    pub fn report(&mut self, c: &Counters) {
        self.renew_if_asked();
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
            detail: self.with_renewals(&c.detail),
        };
        if let Err(e) = self.publisher.put(&h) {
            tracing::warn!("health report: {}", crate::error_chain(&e));
        }
    }

    /// Token renewals so far.
    pub fn renewals(&self) -> u64 {
        self.renewed
    }

    fn with_renewals(&self, detail: &BTreeMap<String, String>) -> BTreeMap<String, String> {
        let mut d = detail.clone();
        if self.renewed > 0 {
            d.insert(
                Detail::TokenRenewals.key().to_string(),
                self.renewed.to_string(),
            );
        }
        d
    }

    /// Withdraws the token and declares it again when asked: every router between here and
    /// the asker passes the new one on (Zenoh's routers pass a key's first token on, not a
    /// second one beside it, so the old one goes first; watchers elsewhere see it go and
    /// come back at once).
    fn renew_if_asked(&mut self) {
        if self
            .last_renewal
            .is_some_and(|t| t.elapsed() < RENEW_AT_MOST_EVERY)
        {
            return;
        }
        let Some(r) = self.asked.lock().ok().and_then(|mut a| a.take()) else {
            return;
        };
        self.last_renewal = Some(Instant::now());
        if let Some(old) = self.token.take()
            && let Err(e) = old.undeclare().wait()
        {
            tracing::warn!("withdrawing the liveliness token: {e}");
        }
        match declare_token(&self.session, &self.rig, &self.host, &self.service) {
            Ok(t) => {
                self.token = Some(t);
                self.renewed += 1;
                tracing::warn!(
                    "{}'s router had lost this service's liveliness token for {:.1} s; declared \
                     it again",
                    r.asked_by,
                    r.missing_s
                );
            }
            // Asked again by the launcher if it is still missing; tried at the next report.
            Err(e) => {
                tracing::warn!("{}", crate::error_chain(&e));
                if let Ok(mut a) = self.asked.lock() {
                    a.get_or_insert(r);
                }
            }
        }
    }
}

fn declare_token(
    session: &zenoh::Session,
    rig: &str,
    host: &str,
    service: &str,
) -> Result<zenoh::liveliness::LivelinessToken, TransportError> {
    session
        .liveliness()
        .declare_token(keys::alive(rig, host, service))
        .wait()
        .map_err(|e| TransportError::Zenoh {
            what: format!("liveliness token for {service}"),
            source: crate::ZenohCause(e),
        })
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

    /// Asked to renew, a service withdraws its token and declares it again (a watcher sees
    /// it go and come back), once however often it is asked within
    /// [`RENEW_AT_MOST_EVERY`]; a request for another service, or one that does not decode,
    /// changes nothing.
    #[test]
    fn a_token_is_declared_again_when_asked_and_no_more_often_than_allowed() {
        use zenoh::sample::SampleKind;
        let session = crate::net::open(&crate::net::ZenohSpec::lone_peer()).unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let tx = Mutex::new(tx);
        let _watch = session
            .liveliness()
            .declare_subscriber(keys::alive("r", "pc", "capture/cam0"))
            .history(true)
            .callback(move |s| {
                if let Ok(tx) = tx.lock() {
                    let _ = tx.send(s.kind());
                }
            })
            .wait()
            .unwrap();
        let mut h = HealthReporter::new(&session, "r", "pc", "capture/cam0").unwrap();
        let c = Counters::default();
        let next = || rx.recv_timeout(Duration::from_secs(5)).ok();
        assert_eq!(next(), Some(SampleKind::Put));
        let ask = |service: &str, body: Option<&[u8]>| {
            let r = TokenRenewal {
                schema: SCHEMA_VERSION,
                rig: "r".into(),
                host: "pc".into(),
                service: service.into(),
                asked_by: "fusion".into(),
                missing_s: 3.5,
            };
            let bytes = body.map(<[u8]>::to_vec).unwrap_or_else(|| r.to_json());
            session
                .put(keys::renew("r", "pc", "capture/cam0"), bytes)
                .wait()
                .unwrap();
        };
        // Another service's request (on this key) and a malformed one: nothing happens.
        ask("capture/cam1", None);
        ask("capture/cam0", Some(b"{\"schema\": 1}"));
        std::thread::sleep(Duration::from_millis(300));
        h.report(&c);
        assert_eq!(h.renewals(), 0);
        assert_eq!(rx.recv_timeout(Duration::from_millis(300)).ok(), None);
        // Asked: the token goes and comes back at the next report.
        ask("capture/cam0", None);
        let end = Instant::now() + Duration::from_secs(5);
        while h.renewals() == 0 && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(20));
            h.report(&c);
        }
        assert_eq!(h.renewals(), 1);
        assert_eq!(next(), Some(SampleKind::Delete));
        assert_eq!(next(), Some(SampleKind::Put));
        // Asked again at once: not before RENEW_AT_MOST_EVERY has passed since.
        ask("capture/cam0", None);
        std::thread::sleep(Duration::from_millis(300));
        h.report(&c);
        assert_eq!(h.renewals(), 1);
        let end = Instant::now() + RENEW_AT_MOST_EVERY + Duration::from_secs(5);
        while h.renewals() == 1 && Instant::now() < end {
            std::thread::sleep(Duration::from_millis(50));
            h.report(&c);
        }
        assert_eq!(h.renewals(), 2);
        assert!(h.last_renewal.is_some());
        assert_eq!(h.with_renewals(&c.detail)["token_renewals"], "2");
    }
}
