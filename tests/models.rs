//! Kinematic models against software the project did not write: the six-joint arm's URDF
//! (`deploy/models/arm6.urdf`) read by yourdfpy, and every link's pose at 50 joint
//! configurations compared with this project's forward kinematics of the same file
//! (urdf-rs reading it, `stereoscope-kinematics` moving it).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use nalgebra::{Isometry3, Matrix4};
use std::io::Write;
use std::process::{Command, Stdio};
use stereoscope_kinematics::JointValue;
use stereoscope_kinematics::synthetic::{arm6, arm6_values};

#[test]
fn the_arms_links_are_where_yourdfpy_puts_them() {
    let model = arm6().unwrap();
    let root = common::repo_root();
    let configs: Vec<Vec<JointValue>> = (0..50).map(|k| arm6_values(k as f64 * 1.37)).collect();
    let job = serde_json::json!({
        "urdf": root.join("deploy/models/arm6.urdf"),
        "links": model.links.iter().map(|l| l.name.clone()).collect::<Vec<_>>(),
        "configs": configs.iter().map(|values| {
            model.joints.iter().zip(values).filter_map(|(j, v)| match v {
                JointValue::Angle(a) => Some((j.name.clone(), serde_json::json!(a))),
                _ => None,
            }).collect::<serde_json::Map<_, _>>()
        }).collect::<Vec<_>>(),
    });
    let mut child = Command::new(common::python_clients())
        .arg(root.join("tests/clients/urdf_fk.py"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(job.to_string().as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let theirs: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(theirs["root"], model.links[0].name);
    let mut poses = Vec::new();
    let mut worst = 0.0f64;
    for (values, links) in configs.iter().zip(theirs["transforms"].as_array().unwrap()) {
        model.forward(&Isometry3::identity(), values, &mut poses);
        for (l, link) in model.links.iter().enumerate() {
            let rows = &links[&link.name];
            let m = Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap());
            let ours = poses[l].to_homogeneous();
            worst = worst.max((m - ours).abs().max());
        }
    }
    println!("worst element of any link's transform, yourdfpy − ours: {worst:e}");
    assert!(worst < 1e-12, "{worst}");
}

/// The robot-arm demo rig through the real services (four synthetic 640 × 480 cameras, moment
/// workers, fusion fitting the arm from its URDF): the fitted joint angles and the tool's
/// position against the renderer's truth. Bounds guard against regressions; the figures are
/// in docs/models.md (`cargo run --release -p stereoscope -- demo --rig
/// deploy/rigs/robot-arm.toml --seconds 30`).
/// `stereoscope demo --rig deploy/rigs/<rig>.toml --seconds 8 --json`: the first model's
/// summary (the whole summary line beside it, for messages).
fn demo_model(rig: &str) -> (serde_json::Value, String) {
    let o = common::run_with_limit(
        &[
            "demo",
            "--rig",
            common::repo_root()
                .join(format!("deploy/rigs/{rig}.toml"))
                .to_str()
                .unwrap(),
            "--seconds",
            "8",
            "--json",
        ],
        std::time::Duration::from_secs(120),
    );
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{out}\n{}", common::stderr(&o));
    let line = out
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .unwrap()
        .to_string();
    let s: serde_json::Value = serde_json::from_str(&line).unwrap();
    (s["models"][0].clone(), line)
}

#[test]
fn the_robot_arm_demo_measures_its_joints_through_the_services() {
    let (arm, line) = demo_model("robot-arm");
    assert_eq!(arm["name"], "arm", "{line}");
    let frames = arm["frames"].as_f64().unwrap();
    let valid = arm["valid"].as_f64().unwrap();
    let whole = arm["whole"].as_f64().unwrap();
    assert!(
        frames >= 150.0 && valid >= 0.7 * frames && whole >= 0.7 * frames,
        "{line}"
    );
    for (k, j) in arm["joints"].as_array().unwrap().iter().enumerate() {
        let Some(rms) = j["rms"].as_f64() else {
            // The tool's flange is fixed.
            assert_eq!(j["name"], "tool_flange", "{line}");
            continue;
        };
        let bound = if k < 3 { 0.3 } else { 1.0 };
        assert!(rms < bound, "joint {}: {rms}° RMS\n{line}", j["name"]);
    }
    let tool = arm["tool_rms_m"].as_f64().unwrap();
    assert!(tool < 0.001, "tool {tool} m RMS\n{line}");
}

/// The leg (`deploy/rigs/leg.toml`: hip ball joint, knee hinge, ankle universal, defined in
/// the rig) walking in place through the services: the knee within the 0.5° RMS, the
/// hip's rotation and the ankle's two angles within 1°, the foot within 1 mm.
#[test]
fn the_leg_demo_measures_its_knee_through_the_services() {
    let (leg, line) = demo_model("leg");
    assert_eq!(leg["name"], "leg", "{line}");
    let frames = leg["frames"].as_f64().unwrap();
    assert!(
        frames >= 150.0 && leg["whole"].as_f64().unwrap() >= 0.9 * frames,
        "{line}"
    );
    for j in leg["joints"].as_array().unwrap() {
        let rms = j["rms"].as_f64().unwrap();
        let bound = if j["name"] == "knee" { 0.5 } else { 1.0 };
        assert!(rms < bound, "joint {}: {rms}° RMS\n{line}", j["name"]);
    }
    let foot = leg["tool_rms_m"].as_f64().unwrap();
    assert!(foot < 0.001, "foot {foot} m RMS\n{line}");
}

/// The leg's joints on ROS 2 as `sensor_msgs/msg/JointState`: the demo runs the leg rig with a
/// ROS 2 feed into a Zenoh router that Zenoh's Python binding stands up (where `rmw_zenohd`
/// would be); rosbags decodes every sample's CDR with ROS 2 Jazzy's types and checks its key's
/// type hash, and the knee's angles lie in the scene's range (2–60°); each link's pose comes on
/// `/tf`.
#[test]
fn the_legs_joints_reach_ros2_as_joint_states() {
    let port = stereoscope_transport::net::free_loopback_port().unwrap();
    let dir = std::env::temp_dir().join(format!("stsc-models-ros2-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(common::repo_root().join("deploy/rigs/leg.toml")).unwrap();
    let rig = dir.join("leg-ros2.toml");
    std::fs::write(
        &rig,
        format!("{text}\n[vr]\nros2 = {{ router = \"tcp/127.0.0.1:{port}\", domain_id = 11 }}\n"),
    )
    .unwrap();
    // The router (and the decoders) first, listening for 20 s; the demo runs 8 s in them.
    let client = std::thread::spawn(move || {
        let python = common::python_clients();
        let script = common::repo_root().join("tests/clients/ros2_clients.py");
        let port_s = port.to_string();
        let o = common::run_program_with_limit(
            &python,
            &[script.to_str().unwrap(), &port_s, "11", "20"],
            std::time::Duration::from_secs(90),
        );
        assert!(o.status.success(), "{}", common::stderr(&o));
        String::from_utf8_lossy(&o.stdout).into_owned()
    });
    std::thread::sleep(std::time::Duration::from_secs(3));
    let o = common::run_with_limit(
        &[
            "demo",
            "--rig",
            rig.to_str().unwrap(),
            "--seconds",
            "8",
            "--quiet",
        ],
        std::time::Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let out = client.join().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let states: Vec<&serde_json::Value> = lines
        .iter()
        .filter(|v| v["kind"] == "sample" && v["topic"] == "/stereoscope/leg/joint_states")
        .collect();
    assert!(
        states.len() >= 100,
        "{} JointState samples:\n{out}",
        states.len()
    );
    for s in &states {
        assert_eq!(s["type_ok"], true, "{s}");
        let msg = &s["msg"];
        let names: Vec<&str> = msg["name"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n.as_str().unwrap())
            .collect();
        assert_eq!(names, ["knee", "ankle_0", "ankle_1"], "{s}");
        let knee = msg["position"][0].as_f64().unwrap().to_degrees();
        assert!((1.0..=61.0).contains(&knee), "knee {knee}°: {s}");
        assert!(msg["velocity"].as_array().unwrap().is_empty(), "{s}");
        assert!(
            msg["header"]["stamp"]["sec"].as_i64().unwrap() > 1_700_000_000,
            "{s}"
        );
    }
}
