//! Liveliness tokens a router lost while their owner runs (issue 41's "tokens lost at a
//! router"): a service whose health reports reach this PC's router but whose liveliness token
//! this router does not hold is asked to declare it again (`TokenRenewal`), after
//! [`MISSING_BEFORE_ASKING`], and again after 5 s, 10 s, … up to a minute while it stays
//! missing. Zenoh 1.10.2's routers keep another PC's tokens by that PC's router, not by link:
//! after a link is cut and restored, a late notice of the old link's loss can take the tokens
//! the new link brought, and nothing brings them back (`docs/reliability.md`).

use std::collections::{HashMap, HashSet};
use std::time::{Duration, Instant};

/// A token missing this long while its service reports is asked for again: longer than a
/// token takes to cross the routers after its service's first report.
pub const MISSING_BEFORE_ASKING: Duration = Duration::from_secs(3);

/// A service whose newest report is older than this is not reporting (they come every
/// second): its token's absence is its end, not a loss.
pub const REPORTING_WITHIN: Duration = Duration::from_secs(2);

/// The wait before asking a service again, doubled each time, up to [`ASK_AT_MOST_EVERY`].
const FIRST_ASK_AGAIN: Duration = Duration::from_secs(5);
const ASK_AT_MOST_EVERY: Duration = Duration::from_secs(60);

/// One service heard (by `host/service`).
#[derive(Debug)]
struct Heard {
    /// The first of its reports without a gap longer than [`REPORTING_WITHIN`] since.
    reporting_since: Instant,
    last_report: Instant,
    missing_since: Option<Instant>,
    next_ask: Option<Instant>,
    ask_again_after: Duration,
}

/// What this PC's router holds and hears: tokens present, services reporting.
#[derive(Debug, Default)]
pub struct Tokens {
    present: HashSet<String>,
    heard: HashMap<String, Heard>,
}

/// A renewal to ask for.
#[derive(Debug, Clone, PartialEq)]
pub struct Ask {
    pub host: String,
    pub service: String,
    pub missing: Duration,
}

impl Tokens {
    /// The token of `host/service` appeared (`alive`) or went.
    pub fn token(&mut self, id: &str, alive: bool) {
        if alive {
            self.present.insert(id.to_string());
        } else {
            self.present.remove(id);
        }
    }

    /// A health report of `host/service` arrived at `now`.
    pub fn report(&mut self, id: &str, now: Instant) {
        let h = self.heard.entry(id.to_string()).or_insert(Heard {
            reporting_since: now,
            last_report: now,
            missing_since: None,
            next_ask: None,
            ask_again_after: FIRST_ASK_AGAIN,
        });
        if now.saturating_duration_since(h.last_report) > REPORTING_WITHIN {
            h.reporting_since = now;
        }
        h.last_report = now;
    }

    /// The services to ask at `now`: reporting for [`MISSING_BEFORE_ASKING`], their token
    /// missing as long, and not asked within their current wait.
    pub fn due(&mut self, now: Instant) -> Vec<Ask> {
        let mut out = Vec::new();
        self.heard.retain(|id, h| {
            let silent = now.saturating_duration_since(h.last_report);
            if self.present.contains(id) || silent > REPORTING_WITHIN {
                h.missing_since = None;
                h.next_ask = None;
                h.ask_again_after = FIRST_ASK_AGAIN;
                // Forgotten once long silent: a service gone for good is not kept.
                return silent < ASK_AT_MOST_EVERY;
            }
            let since = *h.missing_since.get_or_insert(now);
            let missing = now.saturating_duration_since(since);
            let reporting = now.saturating_duration_since(h.reporting_since);
            if missing >= MISSING_BEFORE_ASKING
                && reporting >= MISSING_BEFORE_ASKING
                && h.next_ask.is_none_or(|t| now >= t)
                && let Some((host, service)) = id.split_once('/')
            {
                out.push(Ask {
                    host: host.to_string(),
                    service: service.to_string(),
                    missing,
                });
                h.next_ask = Some(now + h.ask_again_after);
                h.ask_again_after = (h.ask_again_after * 2).min(ASK_AT_MOST_EVERY);
            }
            true
        });
        out.sort_by(|a, b| (&a.host, &a.service).cmp(&(&b.host, &b.service)));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reports every second for `seconds` from `t0`, checking what is due after each.
    fn run(t: &mut Tokens, id: &str, t0: Instant, seconds: u64) -> Vec<(u64, Ask)> {
        let mut asked = Vec::new();
        for s in 0..=seconds {
            let now = t0 + Duration::from_secs(s);
            t.report(id, now);
            asked.extend(t.due(now).into_iter().map(|a| (s, a)));
        }
        asked
    }

    /// A service reporting without its token is asked after 3 s, then 5, 10, 20 s later;
    /// its token back, nothing more; missing again, asked again 3 s later.
    #[test]
    fn a_missing_token_is_asked_for_with_growing_waits() {
        let mut t = Tokens::default();
        let t0 = Instant::now();
        let asked = run(&mut t, "capture2/moments/cam2", t0, 40);
        let at: Vec<u64> = asked.iter().map(|(s, _)| *s).collect();
        assert_eq!(at, [3, 8, 18, 38]);
        assert_eq!(asked[0].1.host, "capture2");
        assert_eq!(asked[0].1.service, "moments/cam2");
        assert_eq!(asked[0].1.missing, Duration::from_secs(3));
        t.token("capture2/moments/cam2", true);
        assert!(
            run(
                &mut t,
                "capture2/moments/cam2",
                t0 + Duration::from_secs(41),
                10
            )
            .is_empty()
        );
        t.token("capture2/moments/cam2", false);
        let again = run(
            &mut t,
            "capture2/moments/cam2",
            t0 + Duration::from_secs(52),
            4,
        );
        assert_eq!(again.iter().map(|(s, _)| *s).collect::<Vec<_>>(), [3]);
    }

    /// A token present, a service that stopped reporting (its end: its token goes with its
    /// last report), and one that only just started: nobody is asked.
    #[test]
    fn present_ended_and_starting_services_are_not_asked() {
        let mut t = Tokens::default();
        let t0 = Instant::now();
        t.token("fusion/fusion", true);
        assert!(run(&mut t, "fusion/fusion", t0, 10).is_empty());
        // The last report at 0 s, then silence: never asked, and forgotten after a minute.
        t.report("pc/capture/cam0", t0);
        for s in 1..=70 {
            assert!(t.due(t0 + Duration::from_secs(s)).is_empty());
        }
        assert!(!t.heard.contains_key("pc/capture/cam0"));
        // Restarted after a long silence: its reporting starts again from 0.
        let later = t0 + Duration::from_secs(100);
        t.report("pc/moments/cam0", t0);
        t.report("pc/moments/cam0", later);
        assert!(t.due(later + Duration::from_secs(2)).is_empty());
        // A token that comes within the grace is never asked for.
        let mut t = Tokens::default();
        for s in 0..=2 {
            t.report("pc/fusion", t0 + Duration::from_secs(s));
            assert!(t.due(t0 + Duration::from_secs(s)).is_empty());
        }
        t.token("pc/fusion", true);
        assert!(run(&mut t, "pc/fusion", t0 + Duration::from_secs(3), 10).is_empty());
    }
}
