//! Progress, not pulses: a service whose inputs flow and which handles none of them is stuck,
//! although it still reports its health every second (a session that lost its subscriptions
//! at a router, a loop waiting on something that never comes). The launcher restarts such a
//! service; the health reports it hears from every host tell it what flows.
//!
//! A service's *progress* is its reported `processed` count going up; an input *flows* when
//! its count went up in two reports since the service's own last progress, the last within
//! [`FLOWING`] (a capture that read one frame and waits for its start time does not flow).
//! The bound runs from the later of the service's last progress and the start of its input's
//! current flow: an input that paused (a camera unplugged for seconds) and flows again gives
//! its consumer the whole bound to take it up.
//! What feeds what:
//! `capture/<cam>` → `moments/<cam>` → `fusion` (any worker of the rig) → `vrfeed` (fusion).
//! And a PC's `router` carries its workers' observations to fusion on another PC: when fusion
//! reports (`cameras_live`) that it hears none of a camera whose worker here flows, the link
//! is cut inside the routers (seen once in four soaks after the fusion PC's router was
//! restarted: Zenoh's "Network graph doesn't contain destination node", the link up and
//! nothing routed), and this PC's router is restarted.
//! A serial output is left out (it handles nothing while its cable is out, which a restart
//! does not mend: its `port` detail says so), and so are the recorder and the viewer (they
//! count what their own clients ask for).

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// Reports come every second: a service is judged only after this many seconds without
/// progress, whatever the rig's rates.
pub const STALL_FLOOR: Duration = Duration::from_secs(3);

/// A service is stuck when it made no progress for this many frame periods of the rig's
/// slowest camera (at least [`STALL_FLOOR`]).
pub const STALL_FRAMES: f64 = 30.0;

/// An input flows when it progressed within this long (two report periods).
pub const FLOWING: Duration = Duration::from_millis(2500);

/// Services report every second. A report of an input's progress is taken as news to its
/// consumer only when it came a whole period after the consumer's last progress: reports of
/// different services arrive out of phase, and the input's report just after the consumer's
/// may count frames the consumer has already handled. An input whose reports showed no
/// progress for longer than one and a half periods paused: its flow starts again.
pub const REPORT_PERIOD: Duration = Duration::from_secs(1);

/// The bound for a rig whose slowest camera runs at `slowest_fps` (none known: the floor).
pub fn stall_bound(slowest_fps: Option<f64>) -> Duration {
    let frames = slowest_fps
        .filter(|f| f.is_finite() && *f > 0.0)
        .map_or(Duration::ZERO, |f| {
            Duration::from_secs_f64((STALL_FRAMES / f).min(600.0))
        });
    frames.max(STALL_FLOOR)
}

/// What one service (`host/service`) last reported.
#[derive(Debug, Clone, Copy)]
struct Seen {
    processed: u64,
    /// When `processed` last went up (or was first heard above zero).
    progressed: Option<Instant>,
    /// The report before that which showed progress: an input flows only when two reports
    /// showed it (one frame read, then a wait, is not a flow).
    progressed_before: Option<Instant>,
    /// The first report of the current run of progress: the first after a pause longer than
    /// one and a half report periods (or the first ever).
    flowing_since: Option<Instant>,
    /// The service's start time as it reports it (a restart starts its count again).
    started_ns: u64,
}

/// Every service's progress, from the health reports of every host.
#[derive(Debug, Default)]
pub struct Progress {
    seen: HashMap<(String, String), Seen>,
    /// Fusion's last report: its host, when it came, and when its current run of reports
    /// (none missing for longer than [`FLOWING`]) began.
    fusion: Option<(String, Instant, Instant)>,
    /// When fusion last said it heard each camera.
    heard: HashMap<String, Instant>,
}

impl Progress {
    /// Takes a health report of `service` on `host` heard at `at`.
    pub fn report(
        &mut self,
        host: &str,
        service: &str,
        processed: u64,
        started_ns: u64,
        at: Instant,
    ) {
        let key = (host.to_string(), service.to_string());
        let fresh = Seen {
            processed: 0,
            progressed: None,
            progressed_before: None,
            flowing_since: None,
            started_ns,
        };
        let s = self.seen.entry(key).or_insert(fresh);
        if s.started_ns != started_ns {
            // Another run of the service: its count starts again.
            *s = fresh;
        }
        if processed > s.processed {
            if s.progressed
                .is_none_or(|t| at.saturating_duration_since(t) > REPORT_PERIOD * 3 / 2)
            {
                s.flowing_since = Some(at);
            }
            s.progressed_before = s.progressed;
            s.progressed = Some(at);
        }
        s.processed = processed;
    }

    /// Takes fusion's `cameras_live` (comma-separated camera ids) from its report at `at`.
    pub fn fusion_hears(&mut self, host: &str, cameras_live: &str, at: Instant) {
        let since = match &self.fusion {
            Some((_, last, since)) if at.saturating_duration_since(*last) < FLOWING => *since,
            _ => at,
        };
        self.fusion = Some((host.to_string(), at, since));
        for cam in cameras_live.split(',').filter(|c| !c.is_empty()) {
            self.heard.insert(cam.to_string(), at);
        }
    }

    /// A camera of `host` whose worker there flows (for longer than `bound`) while fusion, on
    /// another host and reporting here without a break for longer than `bound`, has not heard
    /// it for `bound` (counted from no earlier than `since`, the router's start). Names it. (A
    /// link back after a cut brings fusion's reports first: the run of reports must be as old
    /// as the bound, or the report made while the cable was out would condemn the router.)
    fn cut_off(&self, host: &str, since: Instant, now: Instant, bound: Duration) -> Option<String> {
        let (fusion_host, at, reporting_since) = self.fusion.as_ref()?;
        if fusion_host == host
            || now.saturating_duration_since(*at) >= FLOWING
            || now.saturating_duration_since(*reporting_since) <= bound
        {
            return None;
        }
        self.seen.iter().find_map(|((h, name), s)| {
            let cam = name.strip_prefix("moments/").filter(|_| h == host)?;
            let flows = s
                .progressed
                .is_some_and(|t| now.duration_since(t) < FLOWING)
                && s.flowing_since
                    .is_some_and(|t| now.saturating_duration_since(t) > bound);
            let heard = self.heard.get(cam).map_or(since, |t| (*t).max(since));
            (flows && now.saturating_duration_since(heard) > bound)
                .then(|| format!("{name} on {host} (fusion on {fusion_host} has not heard {cam})"))
        })
    }

    /// Some service on `host` (any host: `None`) matching `input` that flows at `now` and has
    /// flowed for longer than `bound` without the consumer's progress: it progressed within
    /// [`FLOWING`] of `now` and in an earlier report after `since`, and its current flow began
    /// more than `bound` before `now`. Names it.
    fn flows(
        &self,
        host: Option<&str>,
        since: Instant,
        now: Instant,
        bound: Duration,
        input: impl Fn(&str) -> bool,
    ) -> Option<String> {
        self.seen
            .iter()
            .filter(|((h, name), _)| host.is_none_or(|host| host == h) && input(name))
            .find(|(_, s)| {
                s.progressed
                    .is_some_and(|t| now.duration_since(t) < FLOWING)
                    && s.progressed_before
                        .is_some_and(|t| t > since + REPORT_PERIOD)
                    && s.flowing_since
                        .is_some_and(|t| now.saturating_duration_since(t) > bound)
            })
            .map(|((host, name), _)| format!("{name} on {host}"))
    }

    /// Whether `service` on `host` progressed after `started`.
    pub fn progressed_since(&self, host: &str, service: &str, started: Instant) -> bool {
        self.seen
            .get(&(host.to_string(), service.to_string()))
            .and_then(|s| s.progressed)
            .is_some_and(|t| t > started)
    }

    /// Whether `service` on `host`, running since `started`, is stuck at `now`: an input of it
    /// flows and it made no progress for `bound` (counted from its start when it never
    /// progressed). `Some` names the input that flows.
    pub fn stuck(
        &self,
        host: &str,
        service: &str,
        started: Instant,
        now: Instant,
        bound: Duration,
    ) -> Option<String> {
        let own = self.seen.get(&(host.to_string(), service.to_string()));
        let last = own
            .and_then(|s| s.progressed)
            .map_or(started, |t| t.max(started));
        if now.duration_since(last) <= bound {
            return None;
        }
        // A worker's capture runs beside it; fusion's workers and the VR feed's fusion may
        // be on any PC of the rig.
        match service.split_once('/') {
            Some(("moments", cam)) => self.flows(Some(host), last, now, bound, |n| {
                n.strip_prefix("capture/") == Some(cam)
            }),
            None if service == "fusion" => {
                self.flows(None, last, now, bound, |n| n.starts_with("moments/"))
            }
            None if service == "vrfeed" => self.flows(None, last, now, bound, |n| n == "fusion"),
            None if service == crate::ROUTER_SERVICE => self.cut_off(host, started, now, bound),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: Duration = Duration::from_secs(1);

    #[test]
    fn the_bound_follows_the_slowest_camera_above_a_floor() {
        assert_eq!(stall_bound(None), STALL_FLOOR);
        assert_eq!(stall_bound(Some(120.0)), STALL_FLOOR);
        assert_eq!(stall_bound(Some(5.0)), Duration::from_secs(6));
        assert_eq!(stall_bound(Some(f64::NAN)), STALL_FLOOR);
        assert_eq!(stall_bound(Some(0.0)), STALL_FLOOR);
        assert_eq!(stall_bound(Some(1e-9)), Duration::from_secs(600));
    }

    /// A capture PC's router whose cameras fusion (on another PC) stops hearing while their
    /// workers here go on is named once that lasts `bound`; not while fusion hears them, not
    /// when fusion runs on this PC, not when fusion's reports stop, not before `bound`.
    #[test]
    fn a_router_whose_cameras_fusion_no_longer_hears_is_named() {
        let t0 = Instant::now();
        let bound = Duration::from_secs(3);
        let mut p = Progress::default();
        let router_started = t0;
        for i in 0..12u64 {
            let at = t0 + S * i as u32;
            p.report("cap1", "moments/cam0", 100 * (i + 1), 7, at);
            p.report("cap1", "moments/cam1", 100 * (i + 1), 7, at);
            p.report("fus", "fusion", 100 * (i + 1), 8, at);
            // Fusion hears both cameras for 4 s, then cam1 only.
            let live = if i < 4 { "cam0,cam1" } else { "cam1" };
            p.fusion_hears("fus", live, at);
            let now = at;
            let got = p.stuck("cap1", "router", router_started, now, bound);
            if i <= 6 {
                assert_eq!(got, None, "second {i}");
            } else {
                let why = got.unwrap_or_default();
                assert!(
                    why.contains("cam0") && why.contains("fus"),
                    "second {i}: {why}"
                );
            }
            // Fusion on the same PC: its cameras do not cross this router.
            assert_eq!(p.stuck("fus", "router", router_started, now, bound), None);
        }
        // Fusion's reports stop: nothing is judged.
        let later = t0 + S * 20;
        p.report("cap1", "moments/cam0", 5000, 7, later - S);
        p.report("cap1", "moments/cam0", 5100, 7, later);
        assert_eq!(
            p.stuck("cap1", "router", router_started, later, bound),
            None
        );
        // They come back (a cable back in): the first report, made while cam0 was away, does
        // not condemn the router; more than three seconds of reports still without cam0 do.
        for k in 0..5u32 {
            let at = later + S * k;
            p.report("cap1", "moments/cam0", 5200 + 100 * u64::from(k), 7, at);
            p.fusion_hears("fus", "cam1", at);
            let got = p.stuck("cap1", "router", router_started, at, bound);
            assert_eq!(
                got.is_some(),
                k >= 4,
                "second {k} after the reports came back"
            );
        }
        // A router restarted now gets the whole bound again.
        let mut q = Progress::default();
        for i in 0..6u64 {
            let at = t0 + S * i as u32;
            q.report("cap1", "moments/cam0", 100 * (i + 1), 7, at);
            q.fusion_hears("fus", "", at);
        }
        assert_eq!(
            q.stuck("cap1", "router", t0 + S * 4, t0 + S * 5, bound),
            None
        );
        assert!(q.stuck("cap1", "router", t0, t0 + S * 5, bound).is_some());
    }

    /// Fusion stuck while a worker's count goes up is named; fusion whose count goes up, or
    /// whose workers' counts stand (nothing to do), is not; nor is one just started.
    #[test]
    fn a_service_is_stuck_only_while_its_inputs_flow() {
        let t0 = Instant::now();
        let bound = Duration::from_secs(3);
        let mut p = Progress::default();
        let started = t0;
        for i in 0..10u64 {
            let at = t0 + S * i as u32;
            p.report("pc1", "moments/cam0", 100 * (i + 1), 7, at);
            // Fusion handled sets for 2 s, then nothing.
            p.report("pc2", "fusion", 30 * (i.min(2) + 1), 9, at);
        }
        let now = t0 + S * 9;
        let why = p.stuck("pc2", "fusion", started, now, bound);
        assert_eq!(why.as_deref(), Some("moments/cam0 on pc1"));
        // Before the bound passed: not yet.
        assert_eq!(p.stuck("pc2", "fusion", started, t0 + S * 4, bound), None);
        // Just restarted: judged from its start.
        assert_eq!(p.stuck("pc2", "fusion", now - S, now, bound), None);
        // The workers stand still too: nothing flows, nothing is stuck.
        let mut q = Progress::default();
        for i in 0..10u64 {
            let at = t0 + S * i as u32;
            q.report("pc1", "moments/cam0", 100, 7, at);
            q.report("pc2", "fusion", 30, 9, at);
        }
        assert_eq!(q.stuck("pc2", "fusion", started, now, bound), None);
        // A worker follows only its own camera's capture.
        let mut w = Progress::default();
        for i in 0..10u64 {
            let at = t0 + S * i as u32;
            w.report("pc1", "capture/cam1", 100 * (i + 1), 1, at);
            w.report("pc1", "moments/cam0", 5, 2, at);
        }
        assert_eq!(w.stuck("pc1", "moments/cam0", started, now, bound), None);
        for k in 1..=4u32 {
            w.report(
                "pc1",
                "capture/cam0",
                10 * u64::from(k),
                3,
                now - S * (5 - k),
            );
        }
        assert!(
            w.stuck("pc1", "moments/cam0", started, now, bound)
                .is_some()
        );
        // A capture that read one frame and then waited (a replay paced to start later)
        // does not flow: its worker is not judged stuck.
        let mut r = Progress::default();
        r.report("pc1", "capture/cam0", 1, 1, now - S * 2);
        r.report("pc1", "capture/cam0", 1, 1, now - S);
        assert_eq!(r.stuck("pc1", "moments/cam0", started, now, bound), None);
        // Another PC's capture of the same name is not this worker's input.
        let mut o = Progress::default();
        for i in 0..10u64 {
            o.report("pc9", "capture/cam0", 100 * (i + 1), 1, t0 + S * i as u32);
        }
        assert_eq!(o.stuck("pc1", "moments/cam0", started, now, bound), None);
        // Outputs other than the VR feed are not judged.
        assert_eq!(w.stuck("pc1", "serial/ttyUSB0", started, now, bound), None);
    }

    /// A restarted service (a new start time) starts its count again: its first report after
    /// the restart is progress when above zero, not a fall from the old count.
    #[test]
    fn a_restart_starts_the_count_again() {
        let t0 = Instant::now();
        let mut p = Progress::default();
        p.report("pc", "fusion", 5000, 1, t0);
        p.report("pc", "fusion", 12, 2, t0 + S);
        let seen = p.seen[&("pc".to_string(), "fusion".to_string())];
        assert_eq!(seen.progressed, Some(t0 + S));
        assert_eq!(seen.processed, 12);
    }

    /// A camera unplugged for 3 s and back (found by the GigE Vision system test: its worker
    /// was killed the moment the capture counted again): the worker's bound runs from the
    /// capture's new flow, not from the worker's last progress before the pause.
    #[test]
    fn an_input_that_paused_gives_its_consumer_the_whole_bound_again() {
        let t0 = Instant::now();
        let bound = Duration::from_secs(3);
        let mut p = Progress::default();
        for i in 0..=5u64 {
            let at = t0 + S * i as u32;
            p.report("pc", "capture/cam0", 100 * (i + 1), 1, at);
            p.report("pc", "moments/cam0", 100 * (i + 1), 2, at);
        }
        // The camera is away from 5 s to 9 s; the capture counts again at 9 and 10 s.
        for (i, n) in [(6u32, 600u64), (7, 600), (8, 600), (9, 650), (10, 700)] {
            p.report("pc", "capture/cam0", n, 1, t0 + S * i);
            p.report("pc", "moments/cam0", 600, 2, t0 + S * i);
        }
        let now = t0 + S * 10;
        assert_eq!(p.stuck("pc", "moments/cam0", t0, now, bound), None);
        // The worker still handles nothing while the capture has flowed for longer than the
        // bound: stuck.
        for (i, n) in [(11u32, 750u64), (12, 800), (13, 850)] {
            p.report("pc", "capture/cam0", n, 1, t0 + S * i);
            p.report("pc", "moments/cam0", 600, 2, t0 + S * i);
        }
        assert_eq!(
            p.stuck("pc", "moments/cam0", t0, t0 + S * 13, bound)
                .as_deref(),
            Some("capture/cam0 on pc")
        );
    }

    /// The race seen in the GenICam test under load: the worker reports at .29 s past each
    /// second, the capture at .95; the camera goes at 34.25 s and is back at 36.3 s. The
    /// capture's 34.95 report counts frames the worker handled before its 34.29 report, and
    /// its 36.95 report the first frames after the gap: at 37.32 the worker is not stuck. It
    /// is once the capture has flowed the whole bound again without it.
    #[test]
    fn an_input_report_out_of_phase_does_not_make_its_consumer_stuck() {
        let t0 = Instant::now();
        let ms = |v: u64| t0 + Duration::from_millis(v);
        let bound = Duration::from_secs(3);
        let mut p = Progress::default();
        for k in 30..=33u64 {
            p.report("pc", "moments/cam0", 20 * (k - 29), 2, ms(k * 1000 + 290));
            p.report(
                "pc",
                "capture/cam0",
                20 * (k - 29) + 13,
                1,
                ms(k * 1000 + 950),
            );
        }
        p.report("pc", "moments/cam0", 105, 2, ms(34_290));
        p.report("pc", "capture/cam0", 105, 1, ms(34_950));
        p.report("pc", "moments/cam0", 105, 2, ms(35_290));
        p.report("pc", "capture/cam0", 105, 1, ms(35_950));
        p.report("pc", "moments/cam0", 105, 2, ms(36_290));
        p.report("pc", "capture/cam0", 118, 1, ms(36_950));
        assert_eq!(p.stuck("pc", "moments/cam0", t0, ms(37_320), bound), None);
        for k in 37..=40u64 {
            p.report("pc", "moments/cam0", 105, 2, ms(k * 1000 + 290));
            p.report(
                "pc",
                "capture/cam0",
                118 + 20 * (k - 36),
                1,
                ms(k * 1000 + 950),
            );
        }
        assert_eq!(
            p.stuck("pc", "moments/cam0", t0, ms(40_960), bound)
                .as_deref(),
            Some("capture/cam0 on pc")
        );
    }
}
