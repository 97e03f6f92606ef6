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
    demo_model_of(
        common::repo_root()
            .join(format!("deploy/rigs/{rig}.toml"))
            .to_str()
            .unwrap(),
    )
}

/// [`demo_model`] of the rig file at `path`.
fn demo_model_of(path: &str) -> (serde_json::Value, String) {
    let o = common::run_with_limit(
        &["demo", "--rig", path, "--seconds", "8", "--json"],
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
    // Measured (8 s, 3 runs): 98–99 % of the frames valid and whole, every joint 0.018–0.077°,
    // the tool 0.10–0.13 mm; the bounds leave room for a loaded machine.
    assert!(
        frames >= 150.0 && valid >= 0.9 * frames && whole >= 0.9 * frames,
        "{line}"
    );
    for j in arm["joints"].as_array().unwrap() {
        let Some(rms) = j["rms"].as_f64() else {
            // The tool's flange is fixed.
            assert_eq!(j["name"], "tool_flange", "{line}");
            continue;
        };
        assert!(rms < 0.15, "joint {}: {rms}° RMS\n{line}", j["name"]);
    }
    let tool = arm["tool_rms_m"].as_f64().unwrap();
    assert!(tool < 0.0003, "tool {tool} m RMS\n{line}");
}

/// The robot arm with its upper arm's markers all hidden for 1 s in every 4 s (the scene's
/// `hide`), through the services: while hidden, no joint is published as determined more
/// than 0.5° off the truth (the chain carries what it determines, the rest is flagged), and
/// none of the hidden markers is found; outside those seconds the demo's bounds hold.
#[test]
fn the_arms_upper_arm_hidden_for_a_second_through_the_services() {
    let dir = common::TempDir::new("arm-hidden");
    let root = common::repo_root();
    let urdf = root.join("deploy/models/arm6.urdf");
    let from = "motion = { kind = \"joints\", base =";
    let text = std::fs::read_to_string(root.join("deploy/rigs/robot-arm.toml")).unwrap();
    assert!(text.contains(from), "the arm's motion changed form");
    let text = text
        .replace(
            "urdf = \"../models/arm6.urdf\"",
            &format!("urdf = {:?}", urdf.to_str().unwrap()),
        )
        .replace(
            from,
            "motion = { kind = \"joints\", hide = { link = \"upper_arm\", every_s = 4.0, for_s = 1.0 }, base =",
        );
    let path = dir.file("arm-hidden.toml", &text);
    let rig = stereoscope_rig::Rig::load(std::path::Path::new(&path)).unwrap();
    let arm = &rig.models[0].model;
    let upper = arm
        .links
        .iter()
        .position(|l| l.name == "upper_arm")
        .unwrap();
    let on_upper = arm.markers.iter().filter(|m| m.link == upper).count();
    let (m, line) = demo_model_of(&path);
    let h = &m["hidden"];
    assert_eq!(h["link"], "upper_arm", "{line}");
    let frames = h["frames"].as_u64().unwrap();
    assert!(frames >= 30, "{frames} frames hidden\n{line}");
    let seen = h["markers_seen_max"].as_u64().unwrap() as usize;
    assert!(
        seen <= arm.markers.len() - on_upper,
        "{seen} markers found with {on_upper} of {} hidden\n{line}",
        arm.markers.len()
    );
    assert_eq!(h["guesses"], 0, "{line}");
    for j in h["joints"].as_array().unwrap() {
        if let Some(w) = j["worst"].as_f64() {
            assert!(w <= 0.5, "{}: {w}° while hidden\n{line}", j["name"]);
        }
    }
    eprintln!("hidden: {h}");
    let whole = m["whole"].as_f64().unwrap();
    assert!(whole >= 0.8 * m["frames"].as_f64().unwrap(), "{line}");
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

/// The robot-arm demo rig in `dir` with a `[recorder]`, run for `seconds` by `stereoscope
/// demo`: the rig file and the one session it recorded.
fn recorded_arm(dir: &common::TempDir, seconds: u32) -> (String, std::path::PathBuf) {
    let root = common::repo_root();
    let urdf = root.join("deploy/models/arm6.urdf");
    let text = std::fs::read_to_string(root.join("deploy/rigs/robot-arm.toml"))
        .unwrap()
        .replace(
            "urdf = \"../models/arm6.urdf\"",
            &format!("urdf = {:?}", urdf.to_str().unwrap()),
        );
    let rig_path = dir.file(
        "arm.toml",
        &format!("{text}\n[recorder]\nfolder = \"rec\"\n"),
    );
    let s = seconds.to_string();
    let o = common::run_with_limit(
        &["demo", "--rig", &rig_path, "--seconds", &s, "--quiet"],
        std::time::Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let sessions: Vec<_> = std::fs::read_dir(dir.0.join("rec"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sessions.len(), 1, "{sessions:?}");
    (rig_path, sessions[0].clone())
}

/// The robot arm recorded through the services and exported to C3D, read by py-c3d and
/// ezc3d: every marker of the rig's arm labelled `arm:<marker>` and every link's origin
/// `arm:<link>`, and the labels right — two markers of one link keep their distance within
/// 7 mm of its median in every frame both are in (each labelled point lies within
/// `MARKER_OUTLIER_M`, 3 mm, of its fitted marker; a point given another marker's label would
/// be tens of millimetres off); every marker labelled in a fifth of the frames or more (fusion
/// triangulates the wrist's markers in a third to a half), and 90 % of the measured points
/// labelled.
#[test]
fn the_arms_c3d_export_names_every_link_and_marker() {
    let dir = common::TempDir::new("arm-c3d");
    let root = common::repo_root();
    let (rig_path, session) = recorded_arm(&dir, 5);
    let sessions = [session];
    let c3d = dir.0.join("arm.c3d");
    let o = common::run_with_limit(
        &[
            "export",
            sessions[0].to_str().unwrap(),
            "--format",
            "c3d",
            "--out",
            c3d.to_str().unwrap(),
        ],
        std::time::Duration::from_secs(60),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let rig = stereoscope_rig::Rig::load(std::path::Path::new(&rig_path)).unwrap();
    let arm = &rig.models[0].model;
    let o = common::run_program_with_limit(
        &common::python_clients(),
        &[
            root.join("tests/clients/c3d_reader.py").to_str().unwrap(),
            c3d.to_str().unwrap(),
        ],
        std::time::Duration::from_secs(60),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let readers: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(readers.len(), 2, "{out}");
    for r in &readers {
        let labels: Vec<&str> = r["labels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| l.as_str().unwrap())
            .collect();
        let column = |name: &str| {
            labels
                .iter()
                .position(|l| *l == format!("arm:{name}"))
                .unwrap_or_else(|| panic!("{}: no arm:{name} in {labels:?}", r["reader"]))
        };
        for l in &arm.links {
            column(&l.name);
        }
        let frames = r["frames"].as_array().unwrap();
        let at = |f: &serde_json::Value, c: usize| -> Option<nalgebra::Point3<f64>> {
            let p = f[c].as_array()?;
            Some(nalgebra::Point3::new(
                p[0].as_f64()?,
                p[1].as_f64()?,
                p[2].as_f64()?,
            ))
        };
        let mut whole = 0;
        let mut worst = 0.0f64;
        for (li, l) in arm.links.iter().enumerate() {
            let cols: Vec<usize> = arm
                .markers
                .iter()
                .filter(|m| m.link == li)
                .map(|m| column(&m.name))
                .collect();
            for (i, &a) in cols.iter().enumerate() {
                for &b in &cols[i + 1..] {
                    let d: Vec<f64> = frames
                        .iter()
                        .filter_map(|f| Some((at(f, a)? - at(f, b)?).norm()))
                        .collect();
                    let mut sorted = d.clone();
                    sorted.sort_by(f64::total_cmp);
                    let median = sorted[sorted.len() / 2];
                    let off = d.iter().map(|v| (v - median).abs()).fold(0.0, f64::max);
                    worst = worst.max(off);
                    assert!(off < 7.0, "{}: link {}: {off} mm", r["reader"], l.name);
                }
            }
        }
        for f in frames {
            if arm.markers.iter().all(|m| at(f, column(&m.name)).is_some()) {
                whole += 1;
            }
        }
        // The marker labelled in the fewest frames.
        let (rarest, share) = arm
            .markers
            .iter()
            .map(|m| {
                let c = column(&m.name);
                let n = frames.iter().filter(|f| at(f, c).is_some()).count();
                (m.name.as_str(), n as f64 / frames.len() as f64)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        eprintln!(
            "{}: {} frames, {whole} with all {} arm markers, {rarest} in {:.0} %; worst change \
             of a link's marker distance {worst:.3} mm",
            r["reader"],
            frames.len(),
            arm.markers.len(),
            share * 100.0
        );
        assert!(share >= 0.2, "{rarest} labelled in {share} of the frames");
        // The scene holds only the arm: nearly every measured point is one of its markers.
        let loose: usize = labels
            .iter()
            .enumerate()
            .filter(|(_, l)| l.starts_with("obj"))
            .map(|(c, _)| frames.iter().filter(|f| at(f, c).is_some()).count())
            .sum();
        let labelled: usize = arm
            .markers
            .iter()
            .map(|m| {
                let c = column(&m.name);
                frames.iter().filter(|f| at(f, c).is_some()).count()
            })
            .sum();
        eprintln!("{}: {labelled} points labelled, {loose} not", r["reader"]);
        assert!(labelled >= 9 * loose, "{labelled} labelled, {loose} not");
    }
}

/// `body define --session`: the robot arm recorded through the services; the markers that moved
/// together are its links' (several groups — links whose joints barely moved in the take make
/// one — so the command lists them and asks for `--objects`); tried longest seen first, a group
/// that did not keep one shape is refused saying so, and the first that makes a body fits the
/// recording's frames that show it.
#[test]
fn a_body_is_defined_from_the_markers_that_moved_together_in_a_recording() {
    let dir = common::TempDir::new("body-session");
    let (rig_path, session) = recorded_arm(&dir, 6);
    let define = |extra: &[&str]| {
        let mut args = vec![
            "body",
            "define",
            "wand",
            "--rig",
            &rig_path,
            "--session",
            session.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        common::run_with_limit(&args, std::time::Duration::from_secs(60))
    };
    let o = define(&[]);
    let e = common::stderr(&o);
    // The ids in "[a, b, c]".
    let ids_in = |t: &str| -> Option<Vec<u32>> {
        let (_, rest) = t.split_once('[')?;
        let (ids, _) = rest.split_once(']')?;
        ids.split(',').map(|x| x.trim().parse().ok()).collect()
    };
    let mut refused = 0;
    let mut groups: Vec<(usize, Vec<u32>)> = Vec::new();
    let (chosen, table) = if o.status.success() {
        // One group only: taken as it is.
        let line = e
            .lines()
            .find(|l| l.contains("moved together: objects"))
            .unwrap();
        groups.push((0, ids_in(line).unwrap()));
        (
            groups[0].1.clone(),
            String::from_utf8_lossy(&o.stdout).to_string(),
        )
    } else {
        assert!(
            e.contains("several groups of markers moved together") && e.contains("--objects"),
            "{e}"
        );
        // The groups as listed: "[a, b, c] (N frames)"; tried longest seen first: a group that
        // did not keep one shape (an id fusion passed between markers, or two links joined)
        // is refused saying so, and the next is tried.
        groups = e
            .split('[')
            .skip(1)
            .filter_map(|g| {
                let (ids, rest) = g.split_once("] (")?;
                let frames = rest.split(' ').next()?.parse().ok()?;
                Some((frames, ids_in(&format!("[{ids}]"))?))
            })
            .collect();
        assert!(groups.len() >= 2, "{groups:?}\n{e}");
        groups.sort_by_key(|g| std::cmp::Reverse(g.0));
        groups
            .iter()
            .find_map(|(_, g)| {
                let ids: Vec<String> = g.iter().map(u32::to_string).collect();
                let o = define(&["--objects", &ids.join(",")]);
                if o.status.success() {
                    return Some((g.clone(), String::from_utf8_lossy(&o.stdout).to_string()));
                }
                // Refused only as not rigid.
                let e = common::stderr(&o);
                assert!(e.contains("did not keep one shape"), "{e}");
                eprintln!("refused: {}", e.lines().last().unwrap_or_default());
                refused += 1;
                None
            })
            .unwrap_or_else(|| panic!("no group of {groups:?} made a body"))
    };
    let body = stereoscope_rig::Rig::from_toml(&format!(
        "{}\n{table}",
        std::fs::read_to_string(&rig_path).unwrap()
    ))
    .map(|r| r.spec.bodies.last().cloned().unwrap())
    .unwrap_or_else(|e| panic!("{e}\n{table}"));
    // The body posed onto the recording's frames that show all its markers: it fits them
    // (the group kept its shape), within 1.5 mm RMS in 95 % of them.
    let rec = stereoscope_recorder::session::Session::read(&session).unwrap();
    let body_m: Vec<nalgebra::Point3<f64>> = body
        .markers
        .iter()
        .map(|m| nalgebra::Point3::new(m[0], m[1], m[2]) * 1e-3)
        .collect();
    let residuals: Vec<f64> = rec
        .poses
        .iter()
        .filter_map(|f| {
            let ps: Option<Vec<nalgebra::Point3<f64>>> = chosen
                .iter()
                .map(|id| {
                    f.poses
                        .iter()
                        .find(|p| p.object_id == *id)
                        .map(|p| nalgebra::Point3::from(p.position_m))
                })
                .collect();
            let ones = vec![1.0; body_m.len()];
            stereoscope_bodies::kabsch(&body_m, &ps?, &ones).map(|(_, r)| r)
        })
        .collect();
    let good = residuals.iter().filter(|r| **r < 0.0015).count();
    eprintln!(
        "{} groups moved together, {refused} refused as not rigid; {chosen:?} as a body fits \
         {good} of the {} frames showing it within 1.5 mm RMS",
        groups.len(),
        residuals.len()
    );
    assert!(residuals.len() >= 30, "{}", residuals.len());
    assert!(
        good * 20 >= residuals.len() * 19,
        "{good} of {}",
        residuals.len()
    );
}
