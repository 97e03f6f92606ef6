//! `stereoscope status`: every service of a rig on every PC, as Zenoh sees it — liveliness
//! tokens (which services run), their health reports (rates, drops, rejects, thresholds,
//! tracked objects, last error), and the latest pose frame (which cameras see each object, and
//! its residual). A camera whose capture or worker has not reported a frame within the stall
//! time is flagged.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Detail, Health, Message, PoseFrame, now_ns};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_transport::inlet::{self, Admission};
use stereoscope_transport::net::{self, ZenohSpec};
use stereoscope_transport::{Refusal, TransportError};

#[derive(Debug, Clone)]
pub struct StatusConfig {
    pub rig: String,
    pub zenoh: ZenohSpec,
    /// How long to listen for health reports (they come every second).
    pub listen: Duration,
    /// A camera service with no processed frame for this long is stalled; so is fusion with
    /// no pose frame while the moment workers report observations.
    pub stall: Duration,
}

/// One service's line.
#[derive(Debug, Clone, PartialEq)]
pub struct ServiceStatus {
    pub host: String,
    pub service: String,
    pub alive: bool,
    pub health: Option<Health>,
    /// Seconds since its last health report.
    pub report_age_s: Option<f64>,
    pub stalled: bool,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Status {
    pub services: Vec<ServiceStatus>,
    pub poses: Option<PoseFrame>,
    /// Messages refused while listening (another rig's, or ones that do not decode), and
    /// the last refusal.
    pub refused: u64,
    pub last_refused: Option<String>,
}

#[derive(Default)]
struct Seen {
    health: BTreeMap<(String, String), (Health, Instant)>,
    poses: Option<PoseFrame>,
    refused: u64,
    last_refused: Option<String>,
}

impl Seen {
    fn refuse(&mut self, r: Refusal) {
        self.refused += 1;
        self.last_refused = Some(r.message);
    }
}

/// A connection that keeps listening, for `--watch`.
pub struct Monitor {
    session: zenoh::Session,
    seen: Arc<Mutex<Seen>>,
    cfg: StatusConfig,
    _subs: Vec<net::NetSubscriber>,
    /// When it began listening.
    started: Instant,
}

impl std::fmt::Debug for Monitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Monitor({})", self.cfg.rig)
    }
}

fn split_key(key: &str, prefix: &str) -> Option<(String, String)> {
    let rest = key.strip_prefix(prefix)?;
    let (host, service) = rest.split_once('/')?;
    Some((host.to_string(), service.to_string()))
}

impl Monitor {
    pub fn connect(cfg: StatusConfig) -> Result<Self, TransportError> {
        let session = match cfg.zenoh.mode {
            stereoscope_transport::ZenohMode::Client => net::open_client(&cfg.zenoh)?,
            _ => net::open(&cfg.zenoh)?,
        };
        let seen = Arc::new(Mutex::new(Seen::default()));
        let s1 = seen.clone();
        let health_prefix = format!("stereoscope/{}/health/", cfg.rig);
        let lock = |s: &Arc<Mutex<Seen>>| {
            let s = s.clone();
            move |r: Refusal| s.lock().unwrap_or_else(|e| e.into_inner()).refuse(r)
        };
        // A health report on another service's key is refused: the table is by key.
        let mut subs = inlet::listen(
            &session,
            &[keys::all_health(&cfg.rig)],
            Admission::<Health>::new(&cfg.rig, "health").expecting(move |k, h: &Health| {
                match split_key(k, &health_prefix) {
                    Some((host, service)) if host == h.host && service == h.service => Ok(()),
                    _ => {
                        Err(format!("of {}/{} on another service's key", h.host, h.service).into())
                    }
                }
            }),
            move |h, _| {
                let mut s = s1.lock().unwrap_or_else(|e| e.into_inner());
                let id = (h.host.clone(), h.service.clone());
                s.health.insert(id, (h, Instant::now()));
            },
            lock(&seen),
        )?;
        let s2 = seen.clone();
        subs.extend(inlet::listen(
            &session,
            &[keys::poses(&cfg.rig)],
            Admission::<PoseFrame>::new(&cfg.rig, "pose frame"),
            move |p, _| s2.lock().unwrap_or_else(|e| e.into_inner()).poses = Some(p),
            lock(&seen),
        )?);
        Ok(Monitor {
            session,
            seen,
            cfg,
            _subs: subs,
            started: Instant::now(),
        })
    }

    /// What is known now.
    pub fn snapshot(&self) -> Result<Status, TransportError> {
        let alive_prefix = format!("stereoscope/{}/alive/", self.cfg.rig);
        let alive: Vec<(String, String)> = net::alive(
            &self.session,
            &keys::all_alive(&self.cfg.rig),
            Duration::from_millis(500),
        )?
        .iter()
        .filter_map(|k| split_key(k, &alive_prefix))
        .collect();
        let seen = self.seen.lock().unwrap_or_else(|e| e.into_inner());
        let mut ids: Vec<(String, String)> = alive.clone();
        ids.extend(seen.health.keys().cloned());
        ids.sort();
        ids.dedup();
        let stall = self.cfg.stall.as_secs_f64();
        // Observations are flowing when a moment worker reports a rate: fusion must then
        // make pose frames.
        let observations_flow = seen
            .health
            .iter()
            .any(|((_, service), (h, _))| service.starts_with("moments/") && h.rate_hz > 0.0);
        let services = ids
            .into_iter()
            .map(|id| {
                let h = seen.health.get(&id);
                let age = h.map(|(_, t)| t.elapsed().as_secs_f64());
                let camera_service = id.1.starts_with("capture/") || id.1.starts_with("moments/");
                // Fusion is judged against its inputs: alive and reporting, but making no pose
                // frames while observations arrive, it is stalled too.
                let fusion = id.1 == "fusion";
                // Stalled: no report for the stall time, or reports that handled nothing.
                let stalled = (camera_service || (fusion && observations_flow))
                    && match h {
                        // No report yet: stalled only once a report had time to come (the
                        // first seconds of listening, or of a service, are not a stall).
                        None => self.started.elapsed().as_secs_f64() > stall,
                        Some((h, t)) => {
                            t.elapsed().as_secs_f64() > stall
                                || (h.rate_hz == 0.0
                                    && now_ns().saturating_sub(h.started_ns) as f64 / 1e9 > stall)
                        }
                    };
                ServiceStatus {
                    alive: alive.contains(&id),
                    health: h.map(|(h, _)| h.clone()),
                    report_age_s: age,
                    stalled,
                    host: id.0,
                    service: id.1,
                }
            })
            .collect();
        Ok(Status {
            services,
            poses: seen.poses.clone(),
            refused: seen.refused,
            last_refused: seen.last_refused.clone(),
        })
    }

    pub fn listen(&self) -> Duration {
        self.cfg.listen
    }
}

/// Connects, listens for `cfg.listen`, and reports.
pub fn status(cfg: StatusConfig) -> Result<Status, TransportError> {
    let listen = cfg.listen;
    let m = Monitor::connect(cfg)?;
    std::thread::sleep(listen);
    m.snapshot()
}

fn detail(h: &Health, key: Detail) -> String {
    h.detail(key).unwrap_or("-").to_string()
}

/// The status as text tables.
pub fn to_text(s: &Status) -> String {
    let mut o = String::new();
    o.push_str(
        "host        service            alive  rate/s   processed  dropped  rejected  detail\n",
    );
    for x in &s.services {
        let (rate, processed, dropped, rejected, det) = match &x.health {
            Some(h) => {
                let det = match x.service.split('/').next() {
                    Some("capture") => detail(h, Detail::Source),
                    Some("moments") => format!(
                        "threshold {} tracked {}",
                        detail(h, Detail::Threshold),
                        detail(h, Detail::Tracked)
                    ),
                    Some("fusion") => format!(
                        "cameras {} objects {}",
                        detail(h, Detail::CamerasLive),
                        detail(h, Detail::Objects)
                    ),
                    Some("serial") => format!("port {}", detail(h, Detail::Port)),
                    _ => String::new(),
                };
                (
                    format!("{:.1}", h.rate_hz),
                    h.processed.to_string(),
                    h.dropped.to_string(),
                    h.rejected.to_string(),
                    det,
                )
            }
            None => (
                "-".into(),
                "-".into(),
                "-".into(),
                "-".into(),
                "no report".into(),
            ),
        };
        o.push_str(&format!(
            "{:<11} {:<18} {:<6} {:>6} {:>11} {:>8} {:>9}  {}{}\n",
            x.host,
            x.service,
            if x.alive { "yes" } else { "NO" },
            rate,
            processed,
            dropped,
            rejected,
            det,
            if x.stalled { "  STALLED" } else { "" }
        ));
        if let Some(e) = x.health.as_ref().and_then(|h| h.last_error.as_ref()) {
            o.push_str(&format!("            last error: {e}\n"));
        }
    }
    if let Some(r) = &s.last_refused {
        o.push_str(&format!(
            "{} messages refused while listening; the last: {r}\n",
            s.refused
        ));
    }
    if let Some(p) = &s.poses {
        o.push_str(&format!(
            "\nlatest pose frame {} from {}:\nobject  method           cameras        residual px\n",
            p.sequence,
            p.cameras.join(",")
        ));
        for pose in &p.poses {
            o.push_str(&format!(
                "{:>6}  {:<15}  {:<13}  {:>10.3}\n",
                pose.object_id,
                format!("{:?}", pose.method).to_lowercase(),
                pose.cameras.join(","),
                pose.residual_px
            ));
        }
    }
    o
}

/// The status as one JSON object.
pub fn to_json(s: &Status) -> String {
    let services: Vec<String> = s
        .services
        .iter()
        .map(|x| {
            format!(
                "{{\"host\":{:?},\"service\":{:?},\"alive\":{},\"stalled\":{},\"report_age_s\":{},\"health\":{}}}",
                x.host,
                x.service,
                x.alive,
                x.stalled,
                x.report_age_s.map(|a| format!("{a:.3}")).unwrap_or("null".into()),
                x.health
                    .as_ref()
                    .map(|h| String::from_utf8_lossy(&h.to_json()).into_owned())
                    .unwrap_or("null".into())
            )
        })
        .collect();
    format!(
        "{{\"services\":[{}],\"poses\":{}}}",
        services.join(","),
        s.poses
            .as_ref()
            .map(|p| String::from_utf8_lossy(&p.to_json()).into_owned())
            .unwrap_or("null".into())
    )
}
