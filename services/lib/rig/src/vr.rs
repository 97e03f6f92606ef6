//! The rig's `[vr]` section resolved for the VR feed (`docs/vr.md`): each consumer's address
//! and frame (which world axis each of its axes is, its origin, its unit), each body's
//! smoothing and prediction. Checked when the rig loads, so the feed never meets a value it
//! cannot use.

use crate::error::{RigError, err};
use crate::schema::{FrameSpec, RigFile, Units};
use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};
use std::net::SocketAddr;
use stereoscope_bodies::filter::OneEuroConfig;

/// The VRPN port (IANA-registered), also the default of every VRPN client.
pub const VRPN_PORT: u16 = 3883;
/// VirtualMotionTracker's default OSC input port.
pub const VMT_PORT: u16 = 39570;
/// The VMC protocol's default performer port.
pub const VMC_PORT: u16 = 39539;
/// opentrack's "UDP over network" default port.
pub const OPENTRACK_PORT: u16 = 4242;
/// NatNet's command port, data port and multicast group (OptiTrack Motive's defaults).
pub const NATNET_COMMAND_PORT: u16 = 1510;
pub const NATNET_DATA_PORT: u16 = 1511;
pub const NATNET_MULTICAST: std::net::Ipv4Addr = std::net::Ipv4Addr::new(239, 255, 42, 99);
/// The Qualisys RT protocol's base port (QTM's default).
pub const QUALISYS_BASE_PORT: u16 = 22222;
/// Longest prediction a body may ask for, milliseconds.
pub const MAX_PREDICT_MS: f64 = 100.0;

/// Where a consumer's coordinates come from: `consumer = scale · axes · (world − origin)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConsumerFrame {
    /// Rows: the consumer's x, y, z as world vectors (a signed permutation).
    pub consumer_from_world: Matrix3<f64>,
    pub origin_world_m: Point3<f64>,
    /// Consumer units per metre.
    pub units_per_m: f64,
}

impl ConsumerFrame {
    pub fn identity() -> Self {
        ConsumerFrame {
            consumer_from_world: Matrix3::identity(),
            origin_world_m: Point3::origin(),
            units_per_m: 1.0,
        }
    }

    /// A y-up, right-handed frame: world x stays x, world z (up) is y, world y is −z. OpenVR's
    /// room space (VirtualMotionTracker) and opentrack's.
    pub fn y_up() -> Self {
        ConsumerFrame {
            consumer_from_world: Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0),
            ..Self::identity()
        }
    }

    /// Unity's y-up, left-handed frame (VMC): world x is x, world z (up) is y, world y is z. A
    /// mirror of the world: rotations turn the other way.
    pub fn unity() -> Self {
        ConsumerFrame {
            consumer_from_world: Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0),
            ..Self::identity()
        }
    }

    /// Whether the frame keeps handedness (a proper rotation; a mirror flips it).
    pub fn is_proper(&self) -> bool {
        self.consumer_from_world.determinant() > 0.0
    }

    pub fn position(&self, world_m: &Point3<f64>) -> Vector3<f64> {
        self.consumer_from_world * (world_m - self.origin_world_m) * self.units_per_m
    }

    /// A world rotation in consumer axes, as a quaternion. For a mirrored frame (determinant
    /// −1) the conjugated matrix `M R Mᵀ` is still a proper rotation, so it is well defined.
    pub fn rotation(&self, world: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        let m = self.consumer_from_world;
        let r = m * world.to_rotation_matrix().matrix() * m.transpose();
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r))
    }
}

/// Parses a signed axis name: `"x"`, `"-y"`, `"+z"`.
fn axis(name: &str) -> Option<Vector3<f64>> {
    let (sign, a) = match name.trim().strip_prefix('-') {
        Some(a) => (-1.0, a),
        None => (1.0, name.trim().trim_start_matches('+')),
    };
    let v = match a {
        "x" => Vector3::x(),
        "y" => Vector3::y(),
        "z" => Vector3::z(),
        _ => return None,
    };
    Some(v * sign)
}

/// The frame a `[vr.*] frame` table asks for, over `default`; `key` names it in errors.
pub fn consumer_frame(
    spec: Option<&FrameSpec>,
    default: ConsumerFrame,
    file_units: Units,
    key: &str,
) -> Result<ConsumerFrame, RigError> {
    let Some(f) = spec else {
        return Ok(default);
    };
    let mut out = default;
    if let Some(axes) = &f.axes {
        let mut m = Matrix3::zeros();
        for (i, name) in axes.iter().enumerate() {
            let v = axis(name).ok_or_else(|| {
                err(
                    format!("{key}.axes[{i}]"),
                    format!("{name:?} is not one of x, y, z, -x, -y, -z"),
                )
            })?;
            m.set_row(i, &v.transpose());
        }
        if m.determinant().abs() < 0.5 {
            return Err(err(
                format!("{key}.axes"),
                format!("{axes:?} names one world axis twice; each must appear once"),
            ));
        }
        out.consumer_from_world = m;
    }
    if let Some(o) = f.origin {
        if o.iter().any(|v| !v.is_finite()) {
            return Err(err(format!("{key}.origin"), format!("{o:?} is not finite")));
        }
        let s = file_units.metres();
        out.origin_world_m = Point3::new(o[0] * s, o[1] * s, o[2] * s);
    }
    if let Some(u) = f.units {
        out.units_per_m = 1.0 / u.metres();
    }
    Ok(out)
}

/// An address from the rig (`"127.0.0.1:3883"`), or `default`.
pub fn address(v: Option<&String>, default: SocketAddr, key: &str) -> Result<SocketAddr, RigError> {
    match v {
        None => Ok(default),
        Some(s) => s.parse().map_err(|_| {
            err(
                key.to_string(),
                format!(
                    "{s:?} is not an IP address and port, like \"127.0.0.1:{}\"",
                    default.port()
                ),
            )
        }),
    }
}

/// A body's One Euro settings (none: not smoothed) and prediction, seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyOutput {
    pub smoothing: Option<OneEuroConfig>,
    pub predict_s: f64,
}

/// Each body's smoothing and prediction, in rig order.
pub fn body_outputs(file: &RigFile) -> Result<Vec<BodyOutput>, RigError> {
    file.bodies
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let key = format!("body[{i}]");
            let smoothing = match &b.smoothing {
                None => None,
                Some(s) => {
                    let d = OneEuroConfig::default();
                    let c = OneEuroConfig {
                        min_cutoff_hz: s.min_cutoff_hz.unwrap_or(d.min_cutoff_hz),
                        beta: s.beta.unwrap_or(d.beta),
                        d_cutoff_hz: s.d_cutoff_hz.unwrap_or(d.d_cutoff_hz),
                    };
                    for (k, v, lo, hi) in [
                        ("min_cutoff_hz", c.min_cutoff_hz, 0.001, 1000.0),
                        ("beta", c.beta, 0.0, 1000.0),
                        ("d_cutoff_hz", c.d_cutoff_hz, 0.001, 1000.0),
                    ] {
                        if !(v.is_finite() && (lo..=hi).contains(&v)) {
                            return Err(err(
                                format!("{key}.smoothing.{k}"),
                                format!("{v:?} must be between {lo} and {hi}"),
                            ));
                        }
                    }
                    Some(c)
                }
            };
            let ms = b.predict_ms.unwrap_or(0.0);
            if !(ms.is_finite() && (0.0..=MAX_PREDICT_MS).contains(&ms)) {
                return Err(err(
                    format!("{key}.predict_ms"),
                    format!("{ms:?} must be between 0 and {MAX_PREDICT_MS} milliseconds"),
                ));
            }
            Ok(BodyOutput {
                smoothing,
                predict_s: ms * 1e-3,
            })
        })
        .collect()
}

/// Loopback at `port`.
pub fn loopback(port: u16) -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], port))
}

/// The `[vr]` section resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct VrSettings {
    pub vrpn: Option<(SocketAddr, ConsumerFrame)>,
    /// Address, frame, and the bodies (indices into the rig's) in tracker-index order.
    pub vmt: Option<(SocketAddr, ConsumerFrame, Vec<usize>)>,
    pub vmc: Option<(SocketAddr, ConsumerFrame)>,
    /// Address, frame, the body sent.
    pub opentrack: Option<(SocketAddr, ConsumerFrame, usize)>,
    pub natnet: Option<NatNetSettings>,
    pub qualisys: Option<QualisysSettings>,
    pub ros2: Option<Ros2Settings>,
    pub lsl: Option<LslSettings>,
    pub bodies: Vec<BodyOutput>,
}

/// `[vr] lsl` resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct LslSettings {
    pub library: Option<String>,
    pub source_id: Option<String>,
    pub frame: ConsumerFrame,
}

/// `[vr] ros2` resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct Ros2Settings {
    pub router: String,
    pub domain_id: u32,
    pub namespace: String,
    pub node: String,
    pub frame_id: String,
    pub frame: ConsumerFrame,
}

/// A ROS name token: a letter, then letters, digits and underscores.
fn ros_token(s: &str) -> bool {
    let mut c = s.chars();
    c.next().is_some_and(|f| f.is_ascii_alphabetic())
        && c.all(|x| x.is_ascii_alphanumeric() || x == '_')
}

/// `[vr] natnet` resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct NatNetSettings {
    pub command: SocketAddr,
    pub data_port: u16,
    /// `None`: unicast.
    pub multicast: Option<std::net::Ipv4Addr>,
    pub frame: ConsumerFrame,
}

/// `[vr] qualisys` resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct QualisysSettings {
    pub base: SocketAddr,
    pub frame: ConsumerFrame,
}

/// Resolves (and so checks) the rig's `[vr]` section; `None` when it has none.
pub fn settings(file: &RigFile) -> Result<Option<VrSettings>, RigError> {
    let Some(vr) = &file.vr else {
        return Ok(None);
    };
    let u = file.units;
    let body_index = |key: String, name: &str| {
        file.bodies
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| {
                err(
                    key,
                    format!(
                        "{name:?} is not a [[body]] of this rig (bodies: {:?})",
                        file.bodies.iter().map(|b| &b.name).collect::<Vec<_>>()
                    ),
                )
            })
    };
    let vrpn = match &vr.vrpn {
        None => None,
        Some(s) => Some((
            address(s.listen.as_ref(), loopback(VRPN_PORT), "vr.vrpn.listen")?,
            consumer_frame(
                s.frame.as_ref(),
                ConsumerFrame::identity(),
                u,
                "vr.vrpn.frame",
            )?,
        )),
    };
    let vmt = match &vr.vmt {
        None => None,
        Some(s) => {
            let bodies = if s.bodies.is_empty() {
                (0..file.bodies.len()).collect()
            } else {
                s.bodies
                    .iter()
                    .enumerate()
                    .map(|(i, n)| body_index(format!("vr.vmt.bodies[{i}]"), n))
                    .collect::<Result<Vec<_>, _>>()?
            };
            Some((
                address(s.send_to.as_ref(), loopback(VMT_PORT), "vr.vmt.send_to")?,
                consumer_frame(s.frame.as_ref(), ConsumerFrame::y_up(), u, "vr.vmt.frame")?,
                bodies,
            ))
        }
    };
    let vmc = match &vr.vmc {
        None => None,
        Some(s) => Some((
            address(s.send_to.as_ref(), loopback(VMC_PORT), "vr.vmc.send_to")?,
            consumer_frame(s.frame.as_ref(), ConsumerFrame::unity(), u, "vr.vmc.frame")?,
        )),
    };
    let opentrack = match &vr.opentrack {
        None => None,
        Some(s) => {
            let body = match &s.body {
                Some(n) => body_index("vr.opentrack.body".into(), n)?,
                None => 0,
            };
            let cm = ConsumerFrame {
                units_per_m: 100.0,
                ..ConsumerFrame::y_up()
            };
            Some((
                address(
                    s.send_to.as_ref(),
                    loopback(OPENTRACK_PORT),
                    "vr.opentrack.send_to",
                )?,
                consumer_frame(s.frame.as_ref(), cm, u, "vr.opentrack.frame")?,
                body,
            ))
        }
    };
    let natnet = match &vr.natnet {
        None => None,
        Some(s) => {
            let command = address(
                s.command.as_ref(),
                loopback(NATNET_COMMAND_PORT),
                "vr.natnet.command",
            )?;
            if !command.is_ipv4() {
                return Err(err(
                    "vr.natnet.command",
                    format!("{command} is IPv6; NatNet is IPv4 only"),
                ));
            }
            let multicast = match s.multicast.as_deref() {
                None => Some(NATNET_MULTICAST),
                Some("unicast") => None,
                Some(g) => match g.parse::<std::net::Ipv4Addr>() {
                    Ok(ip) if ip.is_multicast() => Some(ip),
                    _ => {
                        return Err(err(
                            "vr.natnet.multicast",
                            format!(
                                "{g:?} is neither a multicast group (224.0.0.0 to 239.255.255.255) nor \"unicast\""
                            ),
                        ));
                    }
                },
            };
            let data_port = s.data_port.unwrap_or(NATNET_DATA_PORT);
            if data_port == 0 {
                return Err(err("vr.natnet.data_port", "0 is not a port"));
            }
            Some(NatNetSettings {
                command,
                data_port,
                multicast,
                frame: consumer_frame(
                    s.frame.as_ref(),
                    ConsumerFrame::y_up(),
                    u,
                    "vr.natnet.frame",
                )?,
            })
        }
    };
    let qualisys = match &vr.qualisys {
        None => None,
        Some(s) => {
            let base = address(
                s.base.as_ref(),
                loopback(QUALISYS_BASE_PORT),
                "vr.qualisys.base",
            )?;
            if base.port() == u16::MAX {
                return Err(err(
                    "vr.qualisys.base",
                    format!("{base}: clients connect to the port after the base; 65535 has none"),
                ));
            }
            let mm = ConsumerFrame {
                units_per_m: 1000.0,
                ..ConsumerFrame::identity()
            };
            Some(QualisysSettings {
                base,
                frame: consumer_frame(s.frame.as_ref(), mm, u, "vr.qualisys.frame")?,
            })
        }
    };
    let ros2 = match &vr.ros2 {
        None => None,
        Some(s) => {
            let router = s
                .router
                .clone()
                .unwrap_or_else(|| "tcp/127.0.0.1:7447".to_string());
            let ok = router.split_once('/').is_some_and(|(proto, addr)| {
                ["tcp", "udp", "tls", "quic"].contains(&proto) && addr.contains(':')
            });
            if !ok {
                return Err(err(
                    "vr.ros2.router",
                    format!("{router:?} is not a Zenoh endpoint like \"tcp/127.0.0.1:7447\""),
                ));
            }
            let domain_id = s.domain_id.unwrap_or(0);
            if domain_id > 232 {
                return Err(err(
                    "vr.ros2.domain_id",
                    format!("{domain_id} is over 232, the largest ROS domain id"),
                ));
            }
            let namespace = s
                .namespace
                .clone()
                .unwrap_or_else(|| "/stereoscope".to_string());
            let parts: Vec<&str> = namespace.trim_end_matches('/').split('/').skip(1).collect();
            if !namespace.starts_with('/') || !parts.iter().all(|p| ros_token(p)) {
                return Err(err(
                    "vr.ros2.namespace",
                    format!(
                        "{namespace:?} is not a ROS namespace (\"/\" then names of letters, digits and _, each starting with a letter)"
                    ),
                ));
            }
            let node = s.node.clone().unwrap_or_else(|| "stereoscope".to_string());
            if !ros_token(&node) {
                return Err(err(
                    "vr.ros2.node",
                    format!(
                        "{node:?} is not a ROS node name (letters, digits and _, from a letter)"
                    ),
                ));
            }
            let frame_id = s.frame_id.clone().unwrap_or_else(|| "world".to_string());
            if frame_id.is_empty()
                || frame_id
                    .chars()
                    .any(|c| c.is_whitespace() || c.is_control())
            {
                return Err(err(
                    "vr.ros2.frame_id",
                    format!("{frame_id:?} must be a non-empty name without spaces"),
                ));
            }
            if let Some((i, b)) = file
                .bodies
                .iter()
                .enumerate()
                .find(|(_, b)| !ros_token(&b.name))
            {
                return Err(err(
                    format!("body[{i}].name"),
                    format!(
                        "{:?} cannot name ROS 2 topics ([vr] ros2): use letters, digits and _, from a letter",
                        b.name
                    ),
                ));
            }
            Some(Ros2Settings {
                router,
                domain_id,
                namespace: namespace.trim_end_matches('/').to_string(),
                node,
                frame_id,
                frame: consumer_frame(
                    s.frame.as_ref(),
                    ConsumerFrame::identity(),
                    u,
                    "vr.ros2.frame",
                )?,
            })
        }
    };
    let lsl = match &vr.lsl {
        None => None,
        Some(s) => {
            for (key, v) in [
                ("vr.lsl.library", &s.library),
                ("vr.lsl.source_id", &s.source_id),
            ] {
                if let Some(v) = v
                    && (v.is_empty() || v.contains('\0'))
                {
                    return Err(err(
                        key,
                        format!("{v:?} must be a non-empty text without NUL"),
                    ));
                }
            }
            Some(LslSettings {
                library: s.library.clone(),
                source_id: s.source_id.clone(),
                frame: consumer_frame(
                    s.frame.as_ref(),
                    ConsumerFrame::identity(),
                    u,
                    "vr.lsl.frame",
                )?,
            })
        }
    };
    Ok(Some(VrSettings {
        vrpn,
        vmt,
        vmc,
        opentrack,
        natnet,
        qualisys,
        ros2,
        lsl,
        bodies: body_outputs(file)?,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_map_axes_origin_and_units() {
        let f = consumer_frame(
            Some(&FrameSpec {
                axes: Some(["x".into(), "z".into(), "-y".into()]),
                origin: Some([100.0, 0.0, 0.0]),
                units: Some(Units::Centimetres),
            }),
            ConsumerFrame::identity(),
            Units::Millimetres,
            "vr.vrpn.frame",
        )
        .unwrap();
        // World (0.3, 0.2, 0.1) m, origin at x = 0.1 m: consumer (20, 10, −20) cm.
        let p = f.position(&Point3::new(0.3, 0.2, 0.1));
        assert!((p - Vector3::new(20.0, 10.0, -20.0)).norm() < 1e-9, "{p}");
        assert!(f.is_proper());
        // A turn about world z is a turn about the consumer's y (world z is its y).
        let q = f.rotation(&UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5));
        let axis = q.axis().unwrap();
        assert!((axis.y - 1.0).abs() < 1e-9 && (q.angle() - 0.5).abs() < 1e-9);
        let bad = |axes: [&str; 3]| {
            consumer_frame(
                Some(&FrameSpec {
                    axes: Some(axes.map(String::from)),
                    ..FrameSpec::default()
                }),
                ConsumerFrame::identity(),
                Units::Metres,
                "vr.vmt.frame",
            )
            .unwrap_err()
        };
        assert_eq!(bad(["x", "x", "z"]).key, "vr.vmt.frame.axes");
        let e = bad(["x", "w", "z"]);
        assert_eq!(e.key, "vr.vmt.frame.axes[1]");
        assert!(e.to_string().contains("\"w\""), "{e}");
    }

    #[test]
    fn a_mirrored_frame_still_gives_a_proper_rotation() {
        let f = ConsumerFrame::unity();
        assert!(!f.is_proper());
        assert!(ConsumerFrame::y_up().is_proper());
        let world = UnitQuaternion::from_euler_angles(0.2, -0.4, 1.1);
        let q = f.rotation(&world);
        // Conjugating by the mirror keeps a rotation matrix (det +1, orthonormal).
        let m = q.to_rotation_matrix();
        assert!((m.matrix().determinant() - 1.0).abs() < 1e-9);
        // And it acts on consumer vectors as the world rotation acts on world vectors.
        let v = Vector3::new(0.3, -0.1, 0.7);
        let lhs = q * (f.consumer_from_world * v);
        let rhs = f.consumer_from_world * (world * v);
        assert!((lhs - rhs).norm() < 1e-9);
    }

    /// The demo rig's `[vr]` and `[fusion] volume` load; mistakes in them are refused at load
    /// with the key and the value.
    #[test]
    fn the_vr_section_is_checked_at_load() {
        let demo = include_str!("../../../../deploy/rigs/demo.toml");
        let r = crate::Rig::from_toml(demo).unwrap();
        let v = settings(&r.spec).unwrap().unwrap();
        assert_eq!(v.vrpn.unwrap().0, loopback(VRPN_PORT));
        assert_eq!(v.vmt.as_ref().unwrap().2, vec![0]);
        assert_eq!(v.opentrack.unwrap().2, 0);
        let bad = |from: &str, to: &str| {
            assert!(demo.contains(from), "{from}");
            crate::Rig::from_toml(&demo.replacen(from, to, 1)).unwrap_err()
        };
        let e = bad("vmt = {}", "vmt = { bodies = [\"hat\"] }");
        assert_eq!(e.key, "vr.vmt.bodies[0]");
        assert!(e.message.contains("\"hat\""), "{e}");
        let e = bad("vrpn = {}", "vrpn = { listen = \"localhost\" }");
        assert_eq!(e.key, "vr.vrpn.listen");
        let e = bad(
            "opentrack = {}",
            "opentrack = { frame = { axes = [\"x\", \"y\", \"y\"] } }",
        );
        assert_eq!(e.key, "vr.opentrack.frame.axes");
        let e = bad("tolerance = 1.0", "tolerance = 1.0\npredict_ms = 500");
        assert_eq!(e.key, "body[0].predict_ms");
        let e = bad("min = [-80.0, -80.0, -10.0]", "min = [-80.0, 90.0, -10.0]");
        assert_eq!(e.key, "fusion.volume");
        let n = v.natnet.unwrap();
        assert_eq!(n.command, loopback(NATNET_COMMAND_PORT));
        assert_eq!(
            (n.data_port, n.multicast),
            (NATNET_DATA_PORT, Some(NATNET_MULTICAST))
        );
        assert_eq!(v.qualisys.unwrap().frame.units_per_m, 1000.0);
        let e = bad("natnet = {}", "natnet = { multicast = \"10.0.0.1\" }");
        assert_eq!(e.key, "vr.natnet.multicast");
        assert!(e.message.contains("10.0.0.1"), "{e}");
        let e = bad("natnet = {}", "natnet = { command = \"[::1]:1510\" }");
        assert_eq!(e.key, "vr.natnet.command");
        let e = bad("qualisys = {}", "qualisys = { base = \"127.0.0.1:65535\" }");
        assert_eq!(e.key, "vr.qualisys.base");
        let e = bad("ros2 = {}", "ros2 = { namespace = \"stereo\" }");
        assert_eq!(e.key, "vr.ros2.namespace");
        let e = bad("ros2 = {}", "ros2 = { router = \"localhost\" }");
        assert_eq!(e.key, "vr.ros2.router");
        let e = bad("name = \"head\"", "name = \"my head\"");
        assert!(
            e.key == "body[0].name" || e.message.contains("my head"),
            "{e}"
        );
        let unicast = crate::Rig::from_toml(&demo.replacen(
            "natnet = {}",
            "natnet = { multicast = \"unicast\" }",
            1,
        ))
        .unwrap();
        assert_eq!(
            settings(&unicast.spec)
                .unwrap()
                .unwrap()
                .natnet
                .unwrap()
                .multicast,
            None
        );
        // No bodies, but a VR feed: refused.
        let no_body = demo.replacen("[[body]]", "[[bodyx]]", 1);
        assert!(crate::Rig::from_toml(&no_body).is_err());
    }
}
