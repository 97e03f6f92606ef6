//! The lab protocols the rig's `[vr]` asks for (NatNet, Qualisys RT, ROS 2, LSL), each behind
//! [`crate::output::Output`]: opened with the feed's bodies, and opened again (once a second)
//! while it cannot be.

use crate::{bodies, lsl, natnet, output, qualisys, ros2};
use std::net::SocketAddr;
use std::time::Duration;
use stereoscope_proto::messages::Detail;
use stereoscope_rig::vr::VrSettings;

/// A lab protocol's server, once open, and what opens it.
type Opened = Box<dyn output::Output + Send>;
type Opener = Box<dyn Fn(&Defs) -> std::io::Result<Opened> + Send>;

/// A lab protocol the rig asks for: its server once it could bind, and until then when to try
/// again (once a second, the reason in health meanwhile).
pub(crate) struct Lab {
    pub(crate) name: &'static str,
    /// Where it listens, or (ROS 2) the router it connects to.
    pub(crate) addr: String,
    pub(crate) state_key: Detail,
    pub(crate) clients_key: Option<Detail>,
    /// The state health reports once it is up (`listening`, `publishing`).
    pub(crate) up: &'static str,
    /// Opens it with the feed's body table and the rig's kinematic models.
    pub(crate) open: Opener,
    /// Whether it sends the kinematic models (opened again when they change).
    pub(crate) carries_models: bool,
    pub(crate) server: Option<Box<dyn output::Output + Send>>,
    pub(crate) next_bind: std::time::Instant,
}

impl Lab {
    /// Binds if it is not bound and a try is due; says what happened in `counters`.
    pub(crate) fn bind(&mut self, counters: &mut stereoscope_transport::Counters, defs: &Defs) {
        if self.server.is_some() || std::time::Instant::now() < self.next_bind {
            return;
        }
        self.next_bind = std::time::Instant::now() + Duration::from_secs(1);
        match (self.open)(defs) {
            Ok(s) => {
                tracing::info!("{} {} on {}", self.name, self.up, self.addr);
                counters.set(self.state_key, self.up);
                self.server = Some(s);
            }
            Err(e) => {
                let m = format!(
                    "{} ({}) is not up: {e}; trying again every second",
                    self.name, self.addr
                );
                if counters.last_error() != Some(&m) {
                    tracing::warn!("{m}");
                }
                counters.set_error(&m);
                let state = if e.kind() == std::io::ErrorKind::AddrInUse {
                    "port in use"
                } else {
                    "unavailable"
                };
                counters.set(self.state_key, state);
            }
        }
    }
}

/// The rig's nominal frame rate: its first camera's that states one (0 when none does).
pub(crate) fn nominal_fps(spec: &stereoscope_rig::schema::RigFile) -> f64 {
    use stereoscope_rig::schema::SourceSpec;
    spec.cameras
        .iter()
        .filter_map(|c| match c.source.as_ref()? {
            SourceSpec::Synthetic { fps, .. } | SourceSpec::Images { fps, .. } => Some(*fps),
            SourceSpec::V4l { fps, .. } | SourceSpec::Genicam { fps, .. } => *fps,
            SourceSpec::Y4m { .. } => None,
        })
        .next()
        .unwrap_or(0.0)
}

/// What the lab protocols are opened with: the feed's body table and the rig's models.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct Defs {
    pub(crate) bodies: bodies::BodyTable,
    pub(crate) model_trees: Vec<ros2::ModelTree>,
}

/// The lab protocols of `settings`, not yet bound.
pub(crate) fn labs(settings: &VrSettings, fps: f64, rig: &str) -> Vec<Lab> {
    let mut out = Vec::new();
    if let Some(n) = &settings.natnet {
        let cfg = natnet::NatNetConfig {
            command: n.command,
            data_port: n.data_port,
            multicast: n.multicast,
            frame: n.frame,
        };
        out.push(Lab {
            name: "NatNet",
            addr: n.command.to_string(),
            state_key: Detail::Natnet,
            clients_key: Some(Detail::NatnetClients),
            up: "listening",
            open: Box::new(move |d: &Defs| {
                natnet::NatNetServer::bind(cfg.clone(), d.bodies.defs().to_vec())
                    .map(|s| Box::new(s) as Box<dyn output::Output + Send>)
            }),
            carries_models: false,
            server: None,
            next_bind: std::time::Instant::now(),
        });
    }
    if let Some(q) = &settings.qualisys {
        let cfg = qualisys::QualisysConfig {
            base: q.base,
            frame: q.frame,
            frequency_hz: fps,
        };
        let port = if q.base.port() == 0 {
            0
        } else {
            q.base.port() + 1
        };
        out.push(Lab {
            name: "Qualisys RT",
            addr: SocketAddr::new(q.base.ip(), port).to_string(),
            state_key: Detail::Qualisys,
            clients_key: Some(Detail::QualisysClients),
            up: "listening",
            open: Box::new(move |d: &Defs| {
                qualisys::QualisysServer::bind(cfg.clone(), d.bodies.defs().to_vec())
                    .map(|s| Box::new(s) as Box<dyn output::Output + Send>)
            }),
            carries_models: false,
            server: None,
            next_bind: std::time::Instant::now(),
        });
    }
    if let Some(r) = &settings.ros2 {
        let cfg = r.clone();
        out.push(Lab {
            name: "ROS 2",
            addr: r.router.clone(),
            state_key: Detail::Ros2,
            clients_key: None,
            up: "publishing",
            open: Box::new(move |d: &Defs| {
                ros2::Ros2Output::open(cfg.clone(), d.bodies.names(), d.model_trees.clone())
                    .map(|s| Box::new(s) as Box<dyn output::Output + Send>)
            }),
            carries_models: true,
            server: None,
            next_bind: std::time::Instant::now(),
        });
    }
    if let Some(l) = &settings.lsl {
        let cfg = l.clone();
        let rig = rig.to_string();
        out.push(Lab {
            name: "LSL",
            addr: l
                .source_id
                .clone()
                .unwrap_or_else(|| format!("stereoscope/{rig}")),
            state_key: Detail::Lsl,
            clients_key: Some(Detail::LslConsumers),
            up: "streaming",
            open: Box::new(move |d: &Defs| {
                lsl::LslOutlet::open(&cfg, &rig, &d.bodies.names(), fps)
                    .map(|s| Box::new(s) as Box<dyn output::Output + Send>)
            }),
            carries_models: false,
            server: None,
            next_bind: std::time::Instant::now(),
        });
    }
    out
}
