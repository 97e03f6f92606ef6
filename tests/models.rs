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
