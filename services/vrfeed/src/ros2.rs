//! ROS 2 without a ROS install (`docs/lab-protocols.md`, "ROS 2"): the feed publishes through
//! Zenoh exactly as `rmw_zenoh` (ROS 2 Jazzy's Zenoh middleware) does, so ROS 2 nodes started
//! with `RMW_IMPLEMENTATION=rmw_zenoh_cpp` list and receive its topics. A re-implementation of
//! rmw_zenoh's mapping from its sources (`liveliness_utils.cpp`, the attachment it sends),
//! checked in the tests against independent implementations (rosbags' CDR and type hashes,
//! the `zenoh-ros2-sdk` subscriber); the maintained Rust library for it, `hiroz`, was measured
//! at 6 min 54 s of added build on this machine's two cores, over the CI budget.
//!
//! *Graph.* One node (`NN` liveliness token) and one publisher (`MP`) per topic, tokens
//! `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>
//! [/<topic>/<type>/<type hash>/<qos>]`, every `/` inside a part written `%`.
//!
//! *Data.* Key `<domain>/<topic without its leading slash>/<type>/<type hash>`; payload CDR
//! (little-endian, 4-byte encapsulation header); attachment: sequence number (i64), source
//! time (i64, ns), the publisher's 16-byte gid with its length (one byte, 16) — as rmw_zenoh
//! and hiroz serialise it with zenoh-ext.
//!
//! *Topics.* Per body `<namespace>/<body>/pose` (`geometry_msgs/msg/PoseStamped`) and
//! `<namespace>/<body>/twist` (`geometry_msgs/msg/TwistStamped`, linear and angular velocity in
//! the same frame), and every body on `/tf` (`tf2_msgs/msg/TFMessage`, parent `frame_id`, child
//! the body's name). Per kinematic model `<namespace>/<model>/joint_states`
//! (`sensor_msgs/msg/JointState`: names and positions of its determined joints, velocity and
//! effort empty), and on `/tf` each of its links whose joints from the root are all
//! determined, child `<model>/<link>`. `header.stamp` is the exposure; bodies held through an occlusion and joints
//! not determined are not published (a ROS pose is a measurement).

use crate::output::{Counts, Output, OutputFrame};
use nalgebra::{Point3, Vector3};
use stereoscope_rig::vr::Ros2Settings;
use zenoh::Wait;

/// `geometry_msgs/msg/PoseStamped`, Jazzy: its DDS name and RIHS01 type hash.
pub const POSE_STAMPED: (&str, &str) = (
    "geometry_msgs::msg::dds_::PoseStamped_",
    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
);
pub const TWIST_STAMPED: (&str, &str) = (
    "geometry_msgs::msg::dds_::TwistStamped_",
    "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
);
/// `sensor_msgs/msg/JointState`, Jazzy (the hash as rosbags 0.11.9 computes it).
pub const JOINT_STATE: (&str, &str) = (
    "sensor_msgs::msg::dds_::JointState_",
    "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
);
pub const TF_MESSAGE: (&str, &str) = (
    "tf2_msgs::msg::dds_::TFMessage_",
    "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
);
/// rmw_zenoh's QoS field for the default profile: reliable (1), volatile (2), keep last (1)
/// 10, no deadline, no lifespan, automatic liveliness (1) with the default lease.
pub const DEFAULT_QOS: &str = "1:2:1,10:0,0:0,0:1,0,0";

/// A CDR (XCDR1, little-endian) writer: the encapsulation header, then values aligned to
/// their size counted from the end of the header.
#[derive(Debug, Default)]
pub struct Cdr {
    buf: Vec<u8>,
}

impl Cdr {
    pub fn new() -> Cdr {
        Cdr {
            buf: vec![0, 1, 0, 0],
        }
    }
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// `std_msgs/Header`: `builtin_interfaces/Time` then `frame_id`.
    pub fn header(&mut self, stamp_ns: u64, frame_id: &str) {
        self.i32((stamp_ns / 1_000_000_000) as i32);
        self.u32((stamp_ns % 1_000_000_000) as u32);
        self.string(frame_id);
    }
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// A pose in the output frame: position (metres) and quaternion x, y, z, w.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RosPose {
    pub position: [f64; 3],
    pub quat_xyzw: [f64; 4],
}

pub fn pose_stamped(stamp_ns: u64, frame_id: &str, p: &RosPose) -> Vec<u8> {
    let mut c = Cdr::new();
    c.header(stamp_ns, frame_id);
    for v in p.position.iter().chain(&p.quat_xyzw) {
        c.f64(*v);
    }
    c.finish()
}

pub fn twist_stamped(
    stamp_ns: u64,
    frame_id: &str,
    linear: [f64; 3],
    angular: [f64; 3],
) -> Vec<u8> {
    let mut c = Cdr::new();
    c.header(stamp_ns, frame_id);
    for v in linear.iter().chain(&angular) {
        c.f64(*v);
    }
    c.finish()
}

/// `tf2_msgs/msg/TFMessage`: one `geometry_msgs/msg/TransformStamped` per (child, pose).
/// `sensor_msgs/msg/JointState`: the header, then the joints' names and positions (radians,
/// metres); velocity and effort empty (not measured).
pub fn joint_state(stamp_ns: u64, frame_id: &str, joints: &[(String, f64)]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.header(stamp_ns, frame_id);
    c.u32(joints.len() as u32);
    for (n, _) in joints {
        c.string(n);
    }
    c.u32(joints.len() as u32);
    for (_, v) in joints {
        c.f64(*v);
    }
    c.u32(0);
    c.u32(0);
    c.finish()
}

/// What the feed knows of a kinematic model's tree: its name, and for each link its name and
/// the joints from the root to it (a link's pose is published on `/tf` only when every one of
/// them is determined).
#[derive(Debug, Clone, PartialEq)]
pub struct ModelTree {
    pub name: String,
    pub links: Vec<(String, Vec<usize>)>,
}

impl ModelTree {
    pub fn of(m: &stereoscope_kinematics::Model) -> ModelTree {
        ModelTree {
            name: m.name.clone(),
            links: m
                .links
                .iter()
                .enumerate()
                .map(|(l, link)| (link.name.clone(), m.path(l).to_vec()))
                .collect(),
        }
    }
}

/// A model's joints as `JointState` lists them: each determined hinge or slide by its name,
/// a universal joint's two angles as `<joint>_0` and `<joint>_1`; ball joints (no URDF
/// equivalent) and undetermined joints left out.
pub fn joint_positions(m: &stereoscope_proto::messages::ModelPose) -> Vec<(String, f64)> {
    let mut out = Vec::new();
    for j in m.joints.iter().filter(|j| j.determined) {
        match j.values.as_slice() {
            [v] => out.push((j.name.clone(), *v)),
            [a, b] => {
                out.push((format!("{}_0", j.name), *a));
                out.push((format!("{}_1", j.name), *b));
            }
            _ => {}
        }
    }
    out
}

pub fn tf_message(stamp_ns: u64, frame_id: &str, transforms: &[(&str, RosPose)]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32(transforms.len() as u32);
    for (child, p) in transforms {
        c.header(stamp_ns, frame_id);
        c.string(child);
        for v in p.position.iter().chain(&p.quat_xyzw) {
            c.f64(*v);
        }
    }
    c.finish()
}

/// A name with each `/` written `%` (rmw_zenoh's `mangle_name`).
pub fn mangle(s: &str) -> String {
    s.replace('/', "%")
}

/// A Zenoh id as rmw_zenoh writes it: its bytes from the most significant, each in hex
/// without padding (`zid_to_str`).
pub fn zid_string(le_bytes: &[u8]) -> String {
    le_bytes.iter().rev().map(|b| format!("{b:x}")).collect()
}

/// The liveliness token of the node.
pub fn node_token(domain: u32, zid: &str, namespace: &str, node: &str) -> String {
    format!(
        "@ros2_lv/{domain}/{zid}/0/0/NN/%/{}/{}",
        mangle(namespace),
        mangle(node)
    )
}

/// The liveliness token of publisher `id` on `topic`.
pub fn publisher_token(
    domain: u32,
    zid: &str,
    id: u32,
    namespace: &str,
    node: &str,
    topic: &str,
    (dds_type, hash): (&str, &str),
) -> String {
    format!(
        "@ros2_lv/{domain}/{zid}/0/{id}/MP/%/{}/{}/{}/{}/{hash}/{DEFAULT_QOS}",
        mangle(namespace),
        mangle(node),
        mangle(topic),
        mangle(dds_type)
    )
}

/// The data key of `topic`.
pub fn data_key(domain: u32, topic: &str, (dds_type, hash): (&str, &str)) -> String {
    format!(
        "{domain}/{}/{dds_type}/{hash}",
        topic.trim_start_matches('/')
    )
}

/// The attachment every sample carries: sequence number, source time (ns), gid.
pub fn attachment(sequence: i64, source_ns: i64, gid: &[u8; 16]) -> Vec<u8> {
    let mut a = Vec::with_capacity(33);
    a.extend_from_slice(&sequence.to_le_bytes());
    a.extend_from_slice(&source_ns.to_le_bytes());
    a.push(16);
    a.extend_from_slice(gid);
    a
}

struct Topic {
    publisher: zenoh::pubsub::Publisher<'static>,
    gid: [u8; 16],
    sequence: i64,
    _token: zenoh::liveliness::LivelinessToken,
}

impl Topic {
    fn put(&mut self, payload: Vec<u8>, counts: &mut Counts, name: &str) {
        self.sequence += 1;
        let now = stereoscope_proto::messages::now_ns() as i64;
        let a = attachment(self.sequence, now, &self.gid);
        if let Err(e) = self.publisher.put(payload).attachment(a).wait() {
            counts.send_error(format!("ROS 2 {name}: {e}"));
        }
    }
}

/// The ROS 2 output: its own Zenoh session (a peer that connects to the ROS user's router),
/// the node's token, and the publishers.
pub struct Ros2Output {
    cfg: Ros2Settings,
    names: Vec<String>,
    /// Per body: pose and twist topics.
    bodies: Vec<(Topic, Topic)>,
    /// Per kinematic model: its tree and `joint_states` topic.
    models: Vec<(ModelTree, Topic)>,
    tf: Topic,
    counts: Counts,
    _node: zenoh::liveliness::LivelinessToken,
    // Last: dropping it undeclares the rest.
    _session: zenoh::Session,
}

impl std::fmt::Debug for Ros2Output {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Ros2Output({})", self.cfg.router)
    }
}

fn zerr(what: &str, e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(format!("{what}: {e}"))
}

impl Ros2Output {
    /// Opens the session (it connects in the background, retrying, so an absent router delays
    /// nothing) and declares the node and its publishers.
    pub fn open(
        cfg: Ros2Settings,
        names: Vec<String>,
        model_trees: Vec<ModelTree>,
    ) -> std::io::Result<Ros2Output> {
        let mut z = zenoh::Config::default();
        let endpoints = serde_json_list(&[cfg.router.as_str()]);
        for (k, v) in [
            ("mode", "\"peer\""),
            ("scouting/multicast/enabled", "false"),
            // As rmw_zenoh's nodes: listen on loopback, where the other nodes of this PC connect
            // once the router's gossip tells them (data goes peer to peer, not through it).
            ("listen/endpoints", "[\"tcp/127.0.0.1:0\"]"),
            ("connect/endpoints", endpoints.as_str()),
            // Open returns at once and the session keeps trying the router in the background
            // (a ROS user may start rmw_zenohd after the rig).
            ("connect/timeout_ms", "-1"),
            ("connect/exit_on_failure", "false"),
            (
                "connect/retry",
                "{ period_init_ms: 250, period_max_ms: 2000, period_increase_factor: 2 }",
            ),
        ] {
            z.insert_json5(k, v).map_err(|e| zerr(k, e))?;
        }
        let session = zenoh::open(z)
            .wait()
            .map_err(|e| zerr("zenoh session", e))?;
        let zid_bytes = session.zid().to_le_bytes();
        let zid = zid_string(&zid_bytes);
        let d = cfg.domain_id;
        let node = session
            .liveliness()
            .declare_token(node_token(d, &zid, "/", &cfg.node))
            .wait()
            .map_err(|e| zerr("node token", e))?;
        let mut next_id = 0u32;
        let mut topic = |name: &str, ty: (&str, &str)| -> std::io::Result<Topic> {
            next_id += 1;
            let publisher = session
                .declare_publisher(data_key(d, name, ty))
                .wait()
                .map_err(|e| zerr(name, e))?;
            let token = session
                .liveliness()
                .declare_token(publisher_token(d, &zid, next_id, "/", &cfg.node, name, ty))
                .wait()
                .map_err(|e| zerr(name, e))?;
            let mut gid = [0u8; 16];
            gid.copy_from_slice(&zid_bytes[..16]);
            gid[12..16].copy_from_slice(&next_id.to_le_bytes());
            Ok(Topic {
                publisher,
                gid,
                sequence: 0,
                _token: token,
            })
        };
        let ns = cfg.namespace.trim_end_matches('/').to_string();
        let mut bodies = Vec::new();
        for n in &names {
            bodies.push((
                topic(&format!("{ns}/{n}/pose"), POSE_STAMPED)?,
                topic(&format!("{ns}/{n}/twist"), TWIST_STAMPED)?,
            ));
        }
        let mut models = Vec::new();
        for m in model_trees {
            let t = topic(&format!("{ns}/{}/joint_states", m.name), JOINT_STATE)?;
            models.push((m, t));
        }
        let tf = topic("/tf", TF_MESSAGE)?;
        Ok(Ros2Output {
            cfg,
            names,
            bodies,
            models,
            tf,
            counts: Counts::default(),
            _node: node,
            _session: session,
        })
    }
}

fn serde_json_list(items: &[&str]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("{s:?}")).collect();
    format!("[{}]", quoted.join(","))
}

impl Output for Ros2Output {
    fn name(&self) -> &'static str {
        "ros2"
    }

    fn poll(&mut self) {}

    fn send(&mut self, f: &OutputFrame) {
        let frame = self.cfg.frame;
        let mut transforms: Vec<(usize, RosPose)> = Vec::new();
        for o in f.bodies.iter().filter(|o| o.tracked) {
            let Some((pose_topic, twist_topic)) = self.bodies.get_mut(o.index) else {
                continue;
            };
            let p = frame.position(&Point3::from(o.world_from_body.translation.vector));
            let q = frame.rotation(&o.world_from_body.rotation);
            let pose = RosPose {
                position: [p.x, p.y, p.z],
                quat_xyzw: [q.i, q.j, q.k, q.w],
            };
            let id = &self.cfg.frame_id;
            pose_topic.put(
                pose_stamped(f.exposure_ns, id, &pose),
                &mut self.counts,
                "pose",
            );
            let v: Vector3<f64> =
                frame.consumer_from_world * Vector3::from(o.velocity_m_per_s) * frame.units_per_m;
            // Angular velocity is a rate about an axis: the axes turn, the unit does not apply.
            let w: Vector3<f64> = frame.consumer_from_world
                * Vector3::from(o.angular_velocity_rad_per_s)
                * frame.consumer_from_world.determinant().signum();
            twist_topic.put(
                twist_stamped(f.exposure_ns, id, [v.x, v.y, v.z], [w.x, w.y, w.z]),
                &mut self.counts,
                "twist",
            );
            transforms.push((o.index, pose));
        }
        // Each valid model's determined joints: a joint angle is a measurement, never a
        // held guess.
        let mut link_transforms: Vec<(String, RosPose)> = Vec::new();
        for m in f.models.iter().filter(|m| m.valid) {
            let Some((tree, topic)) = self.models.iter_mut().find(|(t, _)| t.name == m.name) else {
                continue;
            };
            // Each link whose every joint from the root is determined, as `<model>/<link>`.
            for ((name, path), pose) in tree.links.iter().zip(&m.links) {
                if path
                    .iter()
                    .all(|j| m.joints.get(*j).is_some_and(|j| j.determined))
                {
                    let p = frame.position(&Point3::from(pose.position_m));
                    let [x, y, z, w] = pose.orientation_xyzw;
                    let q = frame.rotation(&nalgebra::UnitQuaternion::from_quaternion(
                        nalgebra::Quaternion::new(w, x, y, z),
                    ));
                    link_transforms.push((
                        format!("{}/{name}", m.name),
                        RosPose {
                            position: [p.x, p.y, p.z],
                            quat_xyzw: [q.i, q.j, q.k, q.w],
                        },
                    ));
                }
            }
            let joints = joint_positions(m);
            if !joints.is_empty() {
                topic.put(
                    joint_state(f.exposure_ns, &self.cfg.frame_id, &joints),
                    &mut self.counts,
                    "joint_states",
                );
            }
        }
        if !transforms.is_empty() || !link_transforms.is_empty() {
            let named: Vec<(&str, RosPose)> = transforms
                .iter()
                .map(|(i, p)| (self.names[*i].as_str(), *p))
                .chain(link_transforms.iter().map(|(n, p)| (n.as_str(), *p)))
                .collect();
            let m = tf_message(f.exposure_ns, &self.cfg.frame_id, &named);
            self.tf.put(m, &mut self.counts, "tf");
        }
        self.counts.frames += 1;
    }

    fn counts(&mut self) -> &mut Counts {
        &mut self.counts
    }

    fn clients(&self) -> Option<usize> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_stamped_is_84_bytes_with_world() {
        let p = RosPose {
            position: [1.0, 2.0, 3.0],
            quat_xyzw: [0.0, 0.0, 0.0, 1.0],
        };
        let b = pose_stamped(1_500_000_000_250_000_000, "world", &p);
        assert_eq!(b.len(), 84);
        assert_eq!(&b[..4], &[0, 1, 0, 0]);
        assert_eq!(
            i32::from_le_bytes(b[4..8].try_into().unwrap()),
            1_500_000_000
        );
        assert_eq!(
            u32::from_le_bytes(b[8..12].try_into().unwrap()),
            250_000_000
        );
        assert_eq!(u32::from_le_bytes(b[12..16].try_into().unwrap()), 6);
        assert_eq!(&b[16..22], b"world\0");
        // Padding to 8 from the header's end: position.x at 24 after it.
        assert_eq!(f64::from_le_bytes(b[28..36].try_into().unwrap()), 1.0);
        assert_eq!(f64::from_le_bytes(b[76..84].try_into().unwrap()), 1.0);
    }

    #[test]
    fn tokens_and_keys_have_rmw_zenohs_fields() {
        let t = publisher_token(
            0,
            "1a2b",
            3,
            "/",
            "stereoscope",
            "/stereoscope/head/pose",
            POSE_STAMPED,
        );
        let parts: Vec<&str> = t.split('/').collect();
        assert_eq!(parts.len(), 13, "{t}");
        assert_eq!(
            &parts[..10],
            &[
                "@ros2_lv",
                "0",
                "1a2b",
                "0",
                "3",
                "MP",
                "%",
                "%",
                "stereoscope",
                "%stereoscope%head%pose"
            ]
        );
        assert_eq!(parts[10], POSE_STAMPED.0);
        assert_eq!(parts[12], DEFAULT_QOS);
        assert_eq!(
            data_key(0, "/tf", TF_MESSAGE),
            format!("0/tf/{}/{}", TF_MESSAGE.0, TF_MESSAGE.1)
        );
        assert_eq!(zid_string(&[0x0f, 0x10, 0x00, 0xab]), "ab010f");
        assert_eq!(attachment(7, 9, &[1; 16]).len(), 33);
    }
}
