//! System test of the VR feed: the real `stereoscope` binary runs a rig whose helmet body stands
//! still at a known pose, and clients the project did not write receive it — libmotioncapture's
//! C++ VRPN client, python-osc for VirtualMotionTracker and VMC, and opentrack's packet decoded
//! as opentrack reads it. Each must get the known pose in its own frame and unit
//! (`docs/vr.md`). Hostile VRPN peers (garbage, a message cut off mid-way) are dropped and
//! counted while the real client keeps receiving. Own iceoryx2 prefix, own loopback ports,
//! every wait bounded, every child reaped.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::{Proc, TempDir, repo_root};
use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};
use stereoscope_proto::messages::{Health, Message, PoseFrame};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_transport::net::{self, ZenohSpec};

fn free_port() -> u16 {
    net::free_loopback_port().unwrap()
}

/// The helmet's known pose: at (−0.10, 0.30, 0.60) m, turned 30° about world +z.
const AT: [f64; 3] = [-0.10, 0.30, 0.60];
const HEADING_DEG: f64 = 30.0;

/// The demo rig with its moving targets replaced by the helmet standing still, and the VR feed
/// on this test's ports.
fn rig(dir: &TempDir, router: u16, vrpn: u16, vmt: u16, vmc: u16, opentrack: u16) -> String {
    let demo = std::fs::read_to_string(repo_root().join("deploy/rigs/demo.toml")).unwrap();
    let scene = demo.split("[[synthetic.target]]").next().unwrap();
    let scene = scene.replace(
        "[vr]\nvrpn = {}\nvmt = {}\nopentrack = {}\n",
        &format!(
            "[vr]\nvrpn = {{ listen = \"127.0.0.1:{vrpn}\" }}\nvmt = {{ send_to = \"127.0.0.1:{vmt}\" }}\nvmc = {{ send_to = \"127.0.0.1:{vmc}\" }}\nopentrack = {{ send_to = \"127.0.0.1:{opentrack}\" }}\n"
        ),
    );
    assert!(
        scene.contains(&format!(":{vrpn}")),
        "the demo rig's [vr] section changed"
    );
    let text = format!(
        "{scene}[[synthetic.target]]\nshape = \"body\"\nbody = \"head\"\nradius = 1.0\nmotion = {{ kind = \"static\", position = [{}, {}, {}], heading_deg = {HEADING_DEG} }}\n\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{router}\"]\niceoryx2_prefix = \"stsc_v{}_\"\n",
        AT[0] * 100.0,
        AT[1] * 100.0,
        AT[2] * 100.0,
        std::process::id()
    );
    dir.file("rig.toml", &text)
}

fn python(script: &str, args: &[&str], limit: Duration) -> Vec<serde_json::Value> {
    let python = common::python_clients();
    let path = repo_root().join("tests/clients").join(script);
    let mut all = vec![path.to_str().unwrap()];
    all.extend_from_slice(args);
    let o = common::run_program_with_limit(&python, &all, limit);
    assert!(o.status.success(), "{script}: {}", common::stderr(&o));
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn f(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .filter_map(|x| x.as_f64())
        .collect()
}

fn close(got: &[f64], want: &[f64], tol: f64, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: {got:?}");
    for (g, w) in got.iter().zip(want) {
        assert!(
            (g - w).abs() <= tol,
            "{what}: got {got:?}, want {want:?} (±{tol})"
        );
    }
}

/// A quaternion equal to `want` up to sign, within `deg` degrees.
fn same_rotation(q: &[f64], want: [f64; 4], deg: f64, what: &str) {
    let dot: f64 = q.iter().zip(want).map(|(a, b)| a * b).sum();
    let angle = (2.0 * dot.abs().min(1.0).acos()).to_degrees();
    assert!(angle <= deg, "{what}: {q:?} is {angle:.2}° from {want:?}");
}

#[test]
fn every_protocol_gets_the_known_body_pose_in_its_own_frame() {
    let dir = TempDir::new("vrfeed");
    let (router, vrpn, vmt, vmc, opentrack) = (
        free_port(),
        free_port(),
        free_port(),
        free_port(),
        free_port(),
    );
    let path = rig(&dir, router, vrpn, vmt, vmc, opentrack);
    // Another program holds the VRPN port when the feed starts.
    let squatter = std::net::TcpListener::bind(("127.0.0.1", vrpn)).unwrap();
    let mut launcher = Proc::start(&["run", &path]);
    let session = {
        let spec = ZenohSpec::client_of(&format!("tcp/127.0.0.1:{router}"));
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            match net::open(&spec) {
                Ok(s) => break s,
                Err(e) if Instant::now() > end => panic!("no router: {e}"),
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    };
    let (tx, rx) = std::sync::mpsc::sync_channel::<PoseFrame>(1024);
    let _poses = net::subscribe(&session, &keys::poses("demo"), move |_, b| {
        if let Ok(p) = PoseFrame::from_json(b) {
            let _ = tx.try_send(p);
        }
    })
    .unwrap();
    let health = std::sync::Arc::new(std::sync::Mutex::new(None::<Health>));
    let sink = health.clone();
    let _health = net::subscribe(&session, &keys::all_health("demo"), move |_, b| {
        if let Ok(h) = Health::from_json(b)
            && h.service == "vrfeed"
        {
            *sink.lock().unwrap() = Some(h);
        }
    })
    .unwrap();
    // The body is found: measured (not held) with all four markers.
    let end = Instant::now() + Duration::from_secs(40);
    let body = loop {
        assert!(
            Instant::now() < end,
            "no body in 40 s:\n{}",
            launcher.output()
        );
        if let Ok(p) = rx.recv_timeout(Duration::from_millis(200))
            && let Some(b) = p.bodies.iter().find(|b| b.name == "head" && !b.held)
            && b.markers_seen == 4
        {
            break b.clone();
        }
    };
    close(&body.position_m, &AT, 0.01, "Zenoh body position");
    let h = (HEADING_DEG / 2.0).to_radians();
    let (s, c) = (h.sin(), h.cos());
    same_rotation(
        &body.orientation_xyzw,
        [0.0, 0.0, s, c],
        3.0,
        "Zenoh body rotation",
    );

    // The port in use was reported, not fatal; freed, the feed listens within seconds.
    let vrpn_state = |want: &str| {
        let end = Instant::now() + Duration::from_secs(8);
        loop {
            let h = health.lock().unwrap().clone();
            if h.as_ref()
                .and_then(|h| h.detail.get("vrpn"))
                .is_some_and(|v| v == want)
            {
                return h;
            }
            assert!(Instant::now() < end, "vrfeed's vrpn never {want:?}: {h:?}");
            std::thread::sleep(Duration::from_millis(100));
        }
    };
    let h = vrpn_state("port in use").unwrap();
    assert!(
        h.last_error
            .as_deref()
            .unwrap_or("")
            .contains(&format!(":{vrpn}")),
        "{h:?}"
    );
    drop(squatter);
    vrpn_state("listening");

    // Hostile VRPN peers first: garbage, and a message cut off mid-way.
    let mut garbage = TcpStream::connect(("127.0.0.1", vrpn)).unwrap();
    garbage.write_all(b"GET / HTTP/1.0\r\n\r\n").unwrap();
    let mut cut = TcpStream::connect(("127.0.0.1", vrpn)).unwrap();
    let mut cookie = b"vrpn: ver. 07.38  0".to_vec();
    cookie.resize(24, 0);
    cut.write_all(&cookie).unwrap();
    cut.write_all(&[0, 0, 0, 200, 0, 0, 0, 1]).unwrap();
    drop(cut);

    // The receivers and the VRPN client at once, for 4 s.
    let receivers = std::thread::spawn(move || {
        python(
            "udp_receivers.py",
            &[
                &vmt.to_string(),
                &vmc.to_string(),
                &opentrack.to_string(),
                "4",
            ],
            Duration::from_secs(60),
        )
    });
    let vrpn_poses = python(
        "vrpn_client.py",
        &[&format!("127.0.0.1:{vrpn}"), "4"],
        Duration::from_secs(60),
    );
    let udp = receivers.join().unwrap();

    // VRPN: the rig's frame, metres; the tracker named after the body.
    let last = vrpn_poses
        .iter()
        .rev()
        .find(|v| v["name"] == "head")
        .unwrap_or_else(|| panic!("no VRPN pose of \"head\": {vrpn_poses:?}"));
    assert!(
        vrpn_poses.len() > 20,
        "{} VRPN poses in 4 s",
        vrpn_poses.len()
    );
    close(&f(&last["position"]), &AT, 0.01, "VRPN position");
    same_rotation(
        &f(&last["quat_xyzw"]),
        [0.0, 0.0, s, c],
        3.0,
        "VRPN rotation",
    );

    let of = |feed: &str| -> Vec<f64> {
        let all: Vec<&serde_json::Value> = udp.iter().filter(|v| v["feed"] == feed).collect();
        assert!(
            all.len() > 20,
            "{} {feed} messages in 4 s: {udp:?}",
            all.len()
        );
        f(&all[all.len() - 1]["values"])
    };
    // VMT: index 0, enabled, no time offset, OpenVR's room (x, z, −y), metres; the turn about
    // world +z is a turn about its +y.
    let v = of("vmt");
    close(
        &v[..3],
        &[0.0, 1.0, 0.0],
        1e-9,
        "VMT index, enable, time offset",
    );
    close(&v[3..6], &[AT[0], AT[2], -AT[1]], 0.01, "VMT position");
    same_rotation(&v[6..10], [0.0, s, 0.0, c], 3.0, "VMT rotation");
    // VMC: Unity's left-handed frame (x, z, y): the same turn is the other way about +y.
    let v = of("vmc");
    close(&v[..3], &[AT[0], AT[2], AT[1]], 0.01, "VMC position");
    same_rotation(&v[3..7], [0.0, -s, 0.0, c], 3.0, "VMC rotation");
    // opentrack: centimetres in the y-up frame, then yaw, pitch, roll in degrees.
    let v = of("opentrack");
    close(
        &v[..3],
        &[AT[0] * 100.0, AT[2] * 100.0, -AT[1] * 100.0],
        1.0,
        "opentrack position",
    );
    close(
        &v[3..6],
        &[HEADING_DEG, 0.0, 0.0],
        3.0,
        "opentrack yaw, pitch, roll",
    );

    // The hostile peers were dropped and counted; the feed is alive.
    let end = Instant::now() + Duration::from_secs(5);
    loop {
        let h = health.lock().unwrap().clone();
        if let Some(h) = &h
            && h.detail.contains_key("rejected.bad_cookie")
            && h.detail.contains_key("rejected.closed")
        {
            break;
        }
        assert!(Instant::now() < end, "vrfeed health: {h:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
    launcher.stop();
    let log = launcher.output();
    assert!(!log.contains("restarted vrfeed"), "{log}");
}
