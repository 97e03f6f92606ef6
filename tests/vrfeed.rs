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

/// The demo rig with its moving targets replaced by the helmet standing still, its `[vr]`
/// section `vr` (this test's ports), its router on `router`, its iceoryx2 names under `tag`.
fn rig(dir: &TempDir, router: u16, vr: &str, tag: &str) -> String {
    let demo = std::fs::read_to_string(repo_root().join("deploy/rigs/demo.toml")).unwrap();
    let scene = demo.split("[[synthetic.target]]").next().unwrap();
    assert!(
        scene.contains(common::DEMO_VR),
        "the demo rig's [vr] section changed"
    );
    let scene = scene.replace(common::DEMO_VR, vr);
    let text = format!(
        "{scene}[[synthetic.target]]\nshape = \"body\"\nbody = \"head\"\nradius = 1.0\nmotion = {{ kind = \"static\", position = [{}, {}, {}], heading_deg = {HEADING_DEG} }}\n\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{router}\"]\niceoryx2_prefix = \"stsc_{tag}{}_\"\n",
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
    let path = rig(
        &dir,
        router,
        &format!(
            "[vr]\nvrpn = {{ listen = \"127.0.0.1:{vrpn}\" }}\nvmt = {{ send_to = \"127.0.0.1:{vmt}\" }}\nvmc = {{ send_to = \"127.0.0.1:{vmc}\" }}\nopentrack = {{ send_to = \"127.0.0.1:{opentrack}\" }}\n"
        ),
        "v",
    );
    // Another program holds the VRPN port when the feed starts.
    let squatter = std::net::TcpListener::bind(("127.0.0.1", vrpn)).unwrap();
    let run = Running::start(&dir, &path, router);
    let (tx, rx) = std::sync::mpsc::sync_channel::<PoseFrame>(1024);
    let _poses = net::subscribe(&run.session, &keys::poses("demo"), move |_, b| {
        if let Ok(p) = PoseFrame::from_json(b) {
            let _ = tx.try_send(p);
        }
    })
    .unwrap();
    let health = run.health.clone();
    // The body is found: measured (not held) with all four markers.
    let end = Instant::now() + Duration::from_secs(40);
    let body = loop {
        assert!(
            Instant::now() < end,
            "no body in 40 s:\n{}",
            run.launcher.output()
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

    // Hostile VRPN peers first: a thousand connections at once (the feed takes 32 and refuses
    // the rest, then sees them go), garbage, and a message cut off mid-way.
    assert_eq!(connection_burst(([127, 0, 0, 1], vrpn).into(), 1000), 1000);
    run.health_until(
        "refusing the VRPN burst, then seeing the 32 it took go",
        |h| {
            let n = |k: &str| {
                h.detail
                    .get(k)
                    .and_then(|v| v.parse::<u32>().ok())
                    .unwrap_or(0)
            };
            // Every connection it took has gone (closed, reset, or silent past the cookie wait).
            let refused = n("rejected.too_many_clients");
            refused > 0
                && n("rejected.closed") + n("rejected.io") + n("rejected.no_cookie")
                    >= 1000 - refused
        },
    );
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
    let mut launcher = run.launcher;
    launcher.stop();
    let log = launcher.output();
    assert!(!log.contains("restarted vrfeed"), "{log}");
}

/// The rig running, with what a test watches: the feed's trace (every frame it sent) and its
/// last health.
struct Running {
    launcher: Proc,
    trace: std::path::PathBuf,
    health: std::sync::Arc<std::sync::Mutex<Option<Health>>>,
    session: zenoh::Session,
    _subscriber: net::NetSubscriber,
}

/// One body pose the feed sent, from its trace: exposure (ns), measured in that frame,
/// position (m) and quaternion (x, y, z, w) in the world frame.
struct Sent {
    exposure_ns: u64,
    measured: bool,
    position: Vec<f64>,
    quat: Vec<f64>,
}

impl Running {
    fn start(dir: &TempDir, path: &str, router: u16) -> Running {
        let r = Running::launch(dir, path, router);
        let end = Instant::now() + Duration::from_secs(40);
        while r.sent().iter().filter(|s| s.measured).count() < 5 {
            assert!(
                Instant::now() < end,
                "no measured body sent in 40 s:\n{}",
                r.launcher.output()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        r
    }

    /// The rig started, its router open to the test; nothing waited for.
    fn launch(dir: &TempDir, path: &str, router: u16) -> Running {
        let trace = dir.0.join("trace.jsonl");
        let launcher = Proc::start_program(
            std::path::Path::new(env!("CARGO_BIN_EXE_stereoscope")),
            &["run", path],
            &[("STEREOSCOPE_VR_TRACE", trace.to_str().unwrap())],
        );
        let spec = ZenohSpec::client_of(&format!("tcp/127.0.0.1:{router}"));
        let end = Instant::now() + Duration::from_secs(20);
        let session = loop {
            match net::open(&spec) {
                Ok(s) => break s,
                Err(e) if Instant::now() > end => panic!("no router: {e}"),
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        };
        let health = std::sync::Arc::new(std::sync::Mutex::new(None::<Health>));
        let h = health.clone();
        let subscriber = net::subscribe(&session, &keys::all_health("demo"), move |_, b| {
            if let Ok(x) = Health::from_json(b)
                && x.service == "vrfeed"
            {
                *h.lock().unwrap() = Some(x);
            }
        })
        .unwrap();
        Running {
            launcher,
            trace,
            health,
            session,
            _subscriber: subscriber,
        }
    }

    /// Every body pose the feed has sent so far (whole lines of its trace).
    fn sent(&self) -> Vec<Sent> {
        Running::sent_in(&self.trace)
    }

    fn sent_in(trace: &std::path::Path) -> Vec<Sent> {
        let text = std::fs::read_to_string(trace).unwrap_or_default();
        let mut out = Vec::new();
        for line in text.lines() {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
                continue;
            };
            let exposure_ns = v["exposure_ns"].as_u64().unwrap();
            for b in v["bodies"].as_array().into_iter().flatten() {
                let b = b.as_array().unwrap();
                let n: Vec<f64> = b[2..].iter().map(|x| x.as_f64().unwrap()).collect();
                out.push(Sent {
                    exposure_ns,
                    measured: b[1] == true,
                    position: n[..3].to_vec(),
                    quat: n[3..].to_vec(),
                });
            }
        }
        out
    }

    /// Waits (bounded) until the feed's health satisfies `pred`.
    fn health_until(&self, what: &str, pred: impl Fn(&Health) -> bool) -> Health {
        let end = Instant::now() + Duration::from_secs(10);
        loop {
            let h = self.health.lock().unwrap().clone();
            if let Some(h) = h.as_ref().filter(|h| pred(h)) {
                return h.clone();
            }
            assert!(Instant::now() < end, "vrfeed health never {what}: {h:?}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

/// The liblsl that pylsl's wheel carries (in the test clients' environment).
fn pylsl_library() -> String {
    let venv = common::python_clients()
        .parent()
        .and_then(|b| b.parent())
        .unwrap()
        .to_path_buf();
    let lib = venv.join("lib");
    for e in std::fs::read_dir(&lib).unwrap().flatten() {
        let p = e.path().join("site-packages/pylsl/lib/liblsl.so");
        if p.exists() {
            return p.to_string_lossy().into_owned();
        }
    }
    panic!("no pylsl/lib/liblsl.so under {}", lib.display());
}

/// A quaternion (x, y, z, w) from a rotation matrix given column by column.
fn quat_of_columns(m: &[f64]) -> [f64; 4] {
    let r = nalgebra::Matrix3::from_column_slice(m);
    let q = nalgebra::UnitQuaternion::from_matrix(&r);
    [q.i, q.j, q.k, q.w]
}

/// How many of `poses` (world frame, metres) are, within 0.1 mm and 0.01°, one of `reference`:
/// the same frame, sent by another protocol.
fn matched(reference: &[(Vec<f64>, Vec<f64>)], poses: &[(Vec<f64>, [f64; 4])]) -> usize {
    poses
        .iter()
        .filter(|(p, q)| {
            reference.iter().any(|(vp, vq)| {
                let d = (0..3).map(|i| (p[i] - vp[i]).powi(2)).sum::<f64>().sqrt();
                // The angle between the rotations from the chord between the quaternions (either
                // sign): well conditioned near zero, where 2·acos(q·q') is not.
                let chord = |sign: f64| {
                    (0..4)
                        .map(|i| (q[i] - sign * vq[i]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                };
                let c = chord(1.0).min(chord(-1.0));
                let angle = (4.0 * (c / 2.0).min(1.0).asin()).to_degrees();
                d <= 1e-4 && angle <= 0.01
            })
        })
        .count()
}

/// Opens `n` TCP connections to `addr` at once, then closes them; returns how many the server
/// took before closing any (refused ones read end-of-file at once).
fn connection_burst(addr: std::net::SocketAddr, n: usize) -> usize {
    // SAFETY: raising this process's own descriptor limit to its hard limit.
    unsafe {
        let mut l = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut l) == 0 && l.rlim_cur < l.rlim_max {
            l.rlim_cur = l.rlim_max.min(65536);
            libc::setrlimit(libc::RLIMIT_NOFILE, &l);
        }
    }
    let mut open = Vec::new();
    for _ in 0..n {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            Ok(s) => open.push(s),
            Err(e) => panic!("connection {} of {n}: {e}", open.len()),
        }
    }
    open.len()
}

/// NatNet (OptiTrack), and Qualisys RT read by clients the project did not write, against the
/// VRPN feed's poses: libmotioncapture's `optitrack` backend and OptiTrack's own Python client
/// (`natnetsdk`) over multicast, Qualisys's `qtm-rt` SDK and libmotioncapture's `qualisys`
/// backend (Qualisys's C++ SDK). Each must receive the body at the rig's rate, in its
/// protocol's frame and unit, every pose one the VRPN client also received (within 0.1 mm and
/// 0.01°), stamped with the exposure fusion published. Hostile peers come first and stay
/// during the run: NatNet garbage, 1,000 Qualisys connections, garbage, a header claiming a
/// gigabyte, a half-sent header, a client that streams and never reads.
#[test]
fn lab_clients_read_the_pose_the_vrpn_feed_sends() {
    let dir = TempDir::new("labfeeds");
    let liblsl = pylsl_library();
    let source_id = format!("stereoscope-test-{}", std::process::id());
    let (router, vrpn, natnet, data, qualisys, ros) = (
        free_port(),
        free_port(),
        free_port(),
        free_port(),
        free_port() - 1,
        free_port(),
    );
    let path = rig(
        &dir,
        router,
        &format!(
            "[vr]\nvrpn = {{ listen = \"127.0.0.1:{vrpn}\" }}\nnatnet = {{ command = \"127.0.0.1:{natnet}\", data_port = {data} }}\nqualisys = {{ base = \"127.0.0.1:{qualisys}\" }}\nros2 = {{ router = \"tcp/127.0.0.1:{ros}\", domain_id = 7 }}\nlsl = {{ library = {liblsl:?}, source_id = {source_id:?} }}\n"
        ),
        "l",
    );
    let run = Running::start(&dir, &path, router);
    run.health_until("listening on NatNet and Qualisys RT", |h| {
        h.detail.get("natnet").is_some_and(|v| v == "listening")
            && h.detail.get("qualisys").is_some_and(|v| v == "listening")
    });
    let rt: std::net::SocketAddr = ([127, 0, 0, 1], qualisys + 1).into();
    // The feed's resident memory before the hostile peers and the clients.
    let feed_pid = run.health.lock().unwrap().as_ref().unwrap().pid;
    let rss_kib = |pid: u32| -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .unwrap()
    };
    let rss_before = rss_kib(feed_pid);

    // NatNet garbage: under a header, a length that lies, an unknown id, an oversized datagram.
    let udp = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let big = vec![7u8; 60_000];
    for d in [&[1u8][..], &[0, 0, 200, 0, 1], &[55, 0, 0, 0], &big] {
        udp.send_to(d, ("127.0.0.1", natnet)).unwrap();
    }
    // Qualisys: a thousand connections at once, then closed; the server sees them go.
    assert_eq!(connection_burst(rt, 1000), 1000);
    run.health_until("refusing the burst and then free", |h| {
        h.detail.contains_key("rejected.too_many_clients")
            && h.detail.get("qualisys_clients").is_some_and(|n| n == "0")
    });
    let mut garbage = TcpStream::connect(rt).unwrap();
    garbage.write_all(b"GET / HTTP/1.0\r\n\r\n").unwrap();
    let mut huge = TcpStream::connect(rt).unwrap();
    huge.write_all(&(1u32 << 30).to_le_bytes()).unwrap();
    huge.write_all(&1u32.to_le_bytes()).unwrap();
    let mut half = TcpStream::connect(rt).unwrap();
    half.write_all(&[20, 0]).unwrap();
    let mut deaf = TcpStream::connect(rt).unwrap();
    for cmd in ["Version 1.25", "StreamFrames AllFrames 3D 6D 6DEuler"] {
        let mut p = ((8 + cmd.len() + 1) as u32).to_le_bytes().to_vec();
        p.extend_from_slice(&1u32.to_le_bytes());
        p.extend_from_slice(cmd.as_bytes());
        p.push(0);
        deaf.write_all(&p).unwrap();
    }

    // Every client at once.
    let seconds = 4.0;
    let s = seconds.to_string();
    let spawn = |script: &'static str, args: Vec<String>| {
        std::thread::spawn(move || {
            let a: Vec<&str> = args.iter().map(String::as_str).collect();
            python(script, &a, Duration::from_secs(90))
        })
    };
    // The VRPN client first, for longer: every frame the others get is in its window.
    let vrpn_client = spawn(
        "vrpn_client.py",
        vec![format!("127.0.0.1:{vrpn}"), (seconds + 6.0).to_string()],
    );
    std::thread::sleep(Duration::from_secs(2));
    let clients = [
        vrpn_client,
        spawn(
            "natnet_clients.py",
            vec![
                "libmotioncapture".into(),
                natnet.to_string(),
                data.to_string(),
                s.clone(),
            ],
        ),
        spawn(
            "natnet_clients.py",
            vec![
                "natnetsdk".into(),
                natnet.to_string(),
                data.to_string(),
                s.clone(),
            ],
        ),
        spawn(
            "qualisys_clients.py",
            vec!["qtm-rt".into(), (qualisys + 1).to_string(), s.clone()],
        ),
        spawn(
            "qualisys_clients.py",
            vec!["libmotioncapture".into(), qualisys.to_string(), s.clone()],
        ),
        spawn(
            "ros2_clients.py",
            vec![ros.to_string(), "7".into(), s.clone()],
        ),
        spawn("lsl_client.py", vec![source_id.clone(), s.clone()]),
    ];
    let [vrpn_out, lmc_nat, sdk_nat, qtm, lmc_q, ros2, lsl] = clients.map(|c| c.join().unwrap());
    let vrpn_poses: Vec<(Vec<f64>, Vec<f64>)> = vrpn_out
        .iter()
        .filter(|v| v["name"] == "head")
        .map(|v| (f(&v["position"]), f(&v["quat_xyzw"])))
        .collect();
    assert!(vrpn_poses.len() > 60, "{} VRPN poses", vrpn_poses.len());
    // The hostile peers were counted; the silent ones are the only clients left.
    let h = run.health_until("counting the hostile peers", |h| {
        h.detail.contains_key("rejected.garbage")
            && h.detail.contains_key("rejected.too_many_clients")
            && h.detail
                .get("qualisys_clients")
                .and_then(|v| v.parse::<u32>().ok())
                .is_some_and(|n| n <= 2)
    });
    let garbage: u32 = h.detail["rejected.garbage"].parse().unwrap();
    // Four NatNet datagrams, the HTTP request and the gigabyte header.
    assert!(garbage >= 6, "{h:?}");
    drop((garbage, huge, half, deaf));
    // Memory: what the peers and clients could hold is bounded (32 Qualisys clients of at most
    // 4 MiB backlog each, one datagram per NatNet peer); here far less.
    let grown_mib = (rss_kib(feed_pid) as f64 - rss_before as f64) / 1024.0;
    eprintln!(
        "feed resident memory: {:.1} MiB, grew {grown_mib:.1} MiB",
        rss_before as f64 / 1024.0
    );
    assert!(
        grown_mib < 32.0,
        "the feed grew {grown_mib:.1} MiB over the hostile peers and the clients"
    );
    // Stopped, the feed has written its whole trace.
    let mut launcher = run.launcher;
    launcher.stop();
    let log = launcher.output();
    assert!(!log.contains("restarted vrfeed"), "{log}");
    let sent = Running::sent_in(&run.trace);
    // What the feed sent, as its trace tells: the VRPN client got those poses (it polls, so
    // not every frame), and every other client must get them too.
    let published: Vec<(Vec<f64>, Vec<f64>)> = sent
        .iter()
        .map(|s| (s.position.clone(), s.quat.clone()))
        .collect();
    let vrpn_as_q: Vec<(Vec<f64>, [f64; 4])> = vrpn_poses
        .iter()
        .map(|(p, q)| (p.clone(), [q[0], q[1], q[2], q[3]]))
        .collect();
    assert_eq!(
        matched(&published, &vrpn_as_q),
        vrpn_as_q.len(),
        "VRPN poses that are not the trace's (first: {:?})",
        vrpn_as_q.first()
    );
    let us: std::collections::BTreeSet<u64> = sent
        .iter()
        .filter(|s| s.measured)
        .map(|s| s.exposure_ns / 1000)
        .collect();
    let done = |out: &[serde_json::Value]| -> serde_json::Value {
        out.iter()
            .find(|v| v["done"] == true)
            .cloned()
            .unwrap_or_else(|| {
                panic!(
                    "no summary line in {} lines; the last: {:?}",
                    out.len(),
                    out.last()
                )
            })
    };
    fn poses(out: &[serde_json::Value]) -> Vec<&serde_json::Value> {
        out.iter().filter(|v| v.get("position").is_some()).collect()
    }
    // At 30 frames a second for 4 s: at least 80 frames to each client.
    let rate_ok = |n: usize, what: &str| {
        assert!(n >= 80, "{what}: {n} frames in {seconds} s at 30 Hz");
    };
    let check = |what: &str, got: Vec<(Vec<f64>, [f64; 4])>| {
        let n = matched(&published, &got);
        let same_as_vrpn = matched(&vrpn_poses, &got);
        assert!(
            n == got.len() && same_as_vrpn > 0,
            "{what}: {n} of {} poses are ones the feed sent, {same_as_vrpn} the VRPN client's too (first: {:?}; VRPN first: {:?})",
            got.len(),
            got.first(),
            vrpn_poses.first()
        );
    };

    // libmotioncapture, NatNet: Motive's y-up frame in metres → world (x, −z, y).
    let p = poses(&lmc_nat);
    rate_ok(p.len(), "libmotioncapture NatNet");
    assert!(p.iter().all(|v| v["name"] == "head"), "{p:?}");
    let from_y_up = |v: &serde_json::Value| {
        let (p, q) = (f(&v["position"]), f(&v["quat_xyzw"]));
        (vec![p[0], -p[2], p[1]], [q[0], -q[2], q[1], q[3]])
    };
    check(
        "libmotioncapture NatNet",
        p.iter().map(|v| from_y_up(v)).collect(),
    );
    // OptiTrack's client: every frame decoded to its last byte; id 1 is "head" with its four
    // markers; NatNet 4.1; tracking valid; the mid-exposure stamp is the set's exposure.
    let d = done(&sdk_nat);
    assert_eq!(d["server_version"], serde_json::json!([4, 1, 0, 0]), "{d}");
    assert_eq!(d["frames"], d["whole"], "{d}");
    rate_ok(d["frames"].as_u64().unwrap() as usize, "natnetsdk");
    assert_eq!(
        d["models"],
        serde_json::json!([{"name": "head", "id": 1, "markers": 4}]),
        "{d}"
    );
    let st = f(&d["last_stamps"]);
    assert!(
        st[0] <= st[1] && st[1] <= st[2],
        "stamps out of order: {st:?}"
    );
    let p = poses(&sdk_nat);
    assert!(p.iter().all(|v| v["id"] == 1), "{p:?}");
    // Tracking valid exactly when the feed's trace has the body measured in that frame set (a
    // loaded machine may drop the helmet from a set: the feed then holds it, flagged).
    let measured_at: std::collections::BTreeMap<u64, bool> = sent
        .iter()
        .map(|s| (s.exposure_ns / 1000, s.measured))
        .collect();
    for v in &p {
        let at = v["timestamp_us"].as_u64().unwrap();
        if let Some(&m) = measured_at.get(&at) {
            assert_eq!(v["tracking_valid"], m, "NatNet frame at {at} µs: {v}");
        }
    }
    let held = p.iter().filter(|v| v["tracking_valid"] != true).count();
    assert!(held <= 2, "{held} of {} NatNet frames held: {p:?}", p.len());
    let stamped = p
        .iter()
        .filter(|v| us.contains(&v["timestamp_us"].as_u64().unwrap()))
        .count();
    assert!(
        stamped + 2 >= p.len(),
        "{stamped} of {} stamps are exposures",
        p.len()
    );
    check("natnetsdk", p.iter().map(|v| from_y_up(v)).collect());

    // qtm-rt: QTM's frame (the world, z up) in millimetres, the rotation matrix by columns.
    let d = done(&qtm);
    assert_eq!(d["bodies"], serde_json::json!(["head"]), "{d}");
    assert_eq!(
        d["labels"],
        serde_json::json!(["head_1", "head_2", "head_3", "head_4"]),
        "{d}"
    );
    assert_eq!(d["frequency"], "30", "{d}");
    assert_eq!(d["state"], "EventConnected", "{d}");
    assert_eq!(d["current_bodies"], 1, "{d}");
    assert!(
        d["refused"].as_str().unwrap_or("").contains("takecontrol"),
        "{d}"
    );
    rate_ok(d["all"].as_u64().unwrap() as usize, "qtm-rt");
    // Frequency:10 from 30 Hz: every third frame, 100 ms apart.
    let gaps = f(&d["rate_gaps_us"]);
    assert!(gaps.len() >= 15, "{d}");
    assert!(
        gaps.iter().all(|g| (90_000.0..=110_000.0).contains(g)),
        "{gaps:?}"
    );
    let p = poses(&qtm);
    let stamped = p
        .iter()
        .filter(|v| us.contains(&v["timestamp_us"].as_u64().unwrap()))
        .count();
    assert!(
        stamped + 2 >= p.len(),
        "{stamped} of {} stamps are exposures",
        p.len()
    );
    check(
        "qtm-rt",
        p.iter()
            .map(|v| {
                let m: Vec<f64> = f(&v["position"]).iter().map(|x| x / 1000.0).collect();
                (m, quat_of_columns(&f(&v["rotation"])))
            })
            .collect(),
    );
    // The four labelled markers of the body, all seen.
    assert!(
        p.iter()
            .all(|v| v["markers"].as_array().unwrap().len() == 4),
        "{:?}",
        p.first()
    );

    // libmotioncapture, Qualisys: metres, the quaternion it builds from 6DEuler.
    let p = poses(&lmc_q);
    rate_ok(p.len(), "libmotioncapture Qualisys");
    let got: Vec<(Vec<f64>, [f64; 4])> = p
        .iter()
        .map(|v| {
            let q = f(&v["quat_xyzw"]);
            (f(&v["position"]), [q[0], q[1], q[2], q[3]])
        })
        .collect();
    check("libmotioncapture Qualisys", got);

    // ROS 2: every sample decoded by rosbags with its key's type hash rosbags' own, the
    // attachment rmw_zenoh's (33 bytes, sequence rising by topic), the pose and /tf the feed's,
    // stamped with a measured exposure; zenoh-ros2-sdk's subscriber got the poses too.
    let samples: Vec<&serde_json::Value> = ros2.iter().filter(|v| v["kind"] == "sample").collect();
    let mut last_sequence = std::collections::BTreeMap::new();
    for v in &samples {
        assert_eq!(v["type_ok"], true, "{v}");
        assert_eq!(v["domain"], "7", "{v}");
        let seq = v["attachment"]["sequence"]
            .as_i64()
            .unwrap_or_else(|| panic!("no rmw_zenoh attachment: {v}"));
        let topic = v["topic"].as_str().unwrap().to_string();
        if let Some(prev) = last_sequence.insert(topic, seq) {
            assert!(seq > prev, "sequence {seq} after {prev}: {v}");
        }
    }
    let of_topic = |t: &str| samples.iter().filter(|v| v["topic"] == t).count();
    for t in ["/stereoscope/head/pose", "/stereoscope/head/twist", "/tf"] {
        rate_ok(of_topic(t), t);
    }
    let ros_pose = |m: &serde_json::Value| {
        let p = &m["position"];
        let q = &m["orientation"];
        let n = |x: &serde_json::Value| x.as_f64().unwrap();
        (
            vec![n(&p["x"]), n(&p["y"]), n(&p["z"])],
            [n(&q["x"]), n(&q["y"]), n(&q["z"]), n(&q["w"])],
        )
    };
    let stamp_us = |h: &serde_json::Value| {
        (h["stamp"]["sec"].as_u64().unwrap() * 1_000_000_000
            + h["stamp"]["nanosec"].as_u64().unwrap())
            / 1000
    };
    let poses_of = |t: &str| -> Vec<(Vec<f64>, [f64; 4])> {
        samples
            .iter()
            .filter(|v| v["topic"] == t)
            .map(|v| {
                let m = &v["msg"];
                assert_eq!(m["header"]["frame_id"], "world", "{v}");
                assert!(us.contains(&stamp_us(&m["header"])), "not an exposure: {v}");
                ros_pose(&m["pose"])
            })
            .collect()
    };
    check("ROS 2 PoseStamped", poses_of("/stereoscope/head/pose"));
    let tf: Vec<(Vec<f64>, [f64; 4])> = samples
        .iter()
        .filter(|v| v["topic"] == "/tf")
        .map(|v| {
            let t = &v["msg"]["transforms"][0];
            assert_eq!(t["child_frame_id"], "head", "{v}");
            assert_eq!(t["header"]["frame_id"], "world", "{v}");
            let tr = &t["transform"];
            let n = |x: &serde_json::Value| x.as_f64().unwrap();
            (
                vec![
                    n(&tr["translation"]["x"]),
                    n(&tr["translation"]["y"]),
                    n(&tr["translation"]["z"]),
                ],
                [
                    n(&tr["rotation"]["x"]),
                    n(&tr["rotation"]["y"]),
                    n(&tr["rotation"]["z"]),
                    n(&tr["rotation"]["w"]),
                ],
            )
        })
        .collect();
    check("ROS 2 /tf", tf);
    // The helmet stands still: its twist is noise around zero.
    for v in samples
        .iter()
        .filter(|v| v["topic"] == "/stereoscope/head/twist")
    {
        let l = &v["msg"]["twist"]["linear"];
        let speed = ["x", "y", "z"]
            .iter()
            .map(|k| l[k].as_f64().unwrap().powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(speed < 0.05, "{v}");
    }
    let sdk: Vec<(Vec<f64>, [f64; 4])> = ros2
        .iter()
        .filter(|v| v["kind"] == "sdk")
        .map(|v| ros_pose(&v["msg"]["pose"]))
        .collect();
    rate_ok(sdk.len(), "zenoh-ros2-sdk");
    check("zenoh-ros2-sdk", sdk);
    // The graph as rmw_zenoh's liveliness_utils.cpp writes it, field by field.
    let d = done(&ros2);
    let tokens: Vec<&str> = d["tokens"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|t| t.as_str())
        .filter(|t| t.contains("/stereoscope"))
        .collect();
    let node: Vec<&str> = tokens
        .iter()
        .copied()
        .filter(|t| t.contains("/NN/"))
        .collect();
    assert_eq!(node.len(), 1, "{tokens:?}");
    let n: Vec<&str> = node[0].split('/').collect();
    assert_eq!(n.len(), 9, "{node:?}");
    assert_eq!(
        (n[0], n[1], n[3], n[4], n[5], n[6], n[7], n[8]),
        ("@ros2_lv", "7", "0", "0", "NN", "%", "%", "stereoscope")
    );
    assert!(
        !n[2].is_empty() && n[2].chars().all(|c| c.is_ascii_hexdigit()),
        "{node:?}"
    );
    let mut published = Vec::new();
    for t in tokens.iter().filter(|t| t.contains("/MP/")) {
        let p: Vec<&str> = t.split('/').collect();
        assert_eq!(p.len(), 13, "{t}");
        assert_eq!(
            (p[0], p[1], p[2], p[3], p[5], p[6], p[7], p[8]),
            ("@ros2_lv", "7", n[2], "0", "MP", "%", "%", "stereoscope"),
            "{t}"
        );
        // QoS: reliability:durability:history,depth:deadline:lifespan:liveliness.
        let q: Vec<&str> = p[12].split(':').collect();
        assert_eq!(q.len(), 6, "{t}");
        // The type hash rosbags computes for the type.
        assert_eq!(d["hashes"][p[10]], p[11], "{t}");
        published.push((p[9].to_string(), p[10].to_string()));
    }
    published.sort();
    assert_eq!(
        published,
        vec![
            (
                "%stereoscope%head%pose".to_string(),
                "geometry_msgs::msg::dds_::PoseStamped_".to_string()
            ),
            (
                "%stereoscope%head%twist".to_string(),
                "geometry_msgs::msg::dds_::TwistStamped_".to_string()
            ),
            (
                "%tf".to_string(),
                "tf2_msgs::msg::dds_::TFMessage_".to_string()
            ),
        ],
        "{tokens:?}"
    );

    // LSL: pylsl resolves the stream by source id and type; seven channels a body, described;
    // every frame the feed sent within the inlet's window arrives (≥ 99 %), each stamped, after
    // LSL's own clock correction, within 1 ms of its exposure, with the pose of that frame.
    let d = done(&lsl);
    let info = &d["info"];
    assert_eq!(
        (&info["type"], &info["channel_count"], &info["source_id"]),
        (
            &serde_json::json!("MoCap"),
            &serde_json::json!(7),
            &serde_json::json!(source_id)
        ),
        "{d}"
    );
    assert_eq!(info["nominal_srate"], 30.0, "{d}");
    assert_eq!(
        info["labels"][0],
        serde_json::json!(["head_X", "PositionX", "metres"]),
        "{d}"
    );
    assert_eq!(
        info["labels"][6],
        serde_json::json!(["head_QW", "OrientationW", "quaternion"]),
        "{d}"
    );
    let samples: Vec<(f64, Vec<f64>)> = lsl
        .iter()
        .filter(|v| v.get("unix").is_some())
        .map(|v| (v["unix"].as_f64().unwrap(), f(&v["values"])))
        .collect();
    rate_ok(samples.len(), "LSL");
    let frames: std::collections::BTreeMap<u64, &Sent> =
        sent.iter().map(|s| (s.exposure_ns, s)).collect();
    let (first, last) = (samples[0].0, samples[samples.len() - 1].0);
    let window = frames
        .keys()
        .filter(|&&e| (e as f64 * 1e-9) >= first - 0.001 && (e as f64 * 1e-9) <= last + 0.001)
        .count();
    assert!(
        samples.len() * 100 >= window * 99,
        "LSL: {} samples of {window} frames sent in the window",
        samples.len()
    );
    let mut worst_ms = 0.0f64;
    for (t, values) in &samples {
        let ns = (t * 1e9) as u64;
        let near = frames
            .range(ns.saturating_sub(5_000_000)..ns + 5_000_000)
            .min_by_key(|(e, _)| e.abs_diff(ns))
            .unwrap_or_else(|| panic!("LSL sample at {t} is no frame's"));
        let off_ms = (*near.0 as f64 * 1e-9 - t).abs() * 1e3;
        worst_ms = worst_ms.max(off_ms);
        let s = near.1;
        if s.measured {
            for (k, v) in s.position.iter().chain(&s.quat).enumerate() {
                assert!(
                    (values[k] - v).abs() < 1e-9,
                    "LSL sample {values:?} vs sent {:?} {:?}",
                    s.position,
                    s.quat
                );
            }
        } else {
            assert!(values.iter().all(|v| v.is_nan()), "{values:?}");
        }
    }
    assert!(
        worst_ms < 1.0,
        "LSL timestamps up to {worst_ms:.3} ms from the exposure"
    );
}

/// A rig with an output and no body yet (docs/bodies.md, "Changing bodies while the rig
/// runs"): the feed starts, warns and listens; a VRPN client (libmotioncapture's, the C++ VRPN
/// library) and a NatNet client (libmotioncapture's `optitrack`) connect while there is nothing
/// to send; the helmet's `[[body]]` is then written into the rig file, and both clients receive
/// the new body at its true pose without reconnecting — the VRPN client by name, from the
/// tracker the feed described to it on the open connection; the NatNet client by id (it read
/// the model definitions when it connected, when there were none). Nothing restarts.
#[test]
fn an_output_with_no_body_starts_and_sends_the_first_body_defined() {
    let dir = TempDir::new("firstbody");
    let (router, vrpn, natnet, data) = (free_port(), free_port(), free_port(), free_port());
    let with_body = rig(
        &dir,
        router,
        &format!(
            "[vr]\nvrpn = {{ listen = \"127.0.0.1:{vrpn}\" }}\nnatnet = {{ command = \"127.0.0.1:{natnet}\", data_port = {data} }}\n"
        ),
        "f",
    );
    let text = std::fs::read_to_string(&with_body).unwrap();
    // The helmet rendered as four loose spheres where its markers are: the scene is the same,
    // the rig knows no body.
    let body_block = "[[body]]\nname = \"head\"\nmarkers = [[0.0, 0.0, 0.0], [18.0, 0.0, 0.0], [0.0, 11.0, 0.0], [6.0, 6.0, 8.0]]\ntolerance = 1.0\n";
    assert!(text.contains(body_block), "the demo's helmet changed");
    let (s, c) = HEADING_DEG.to_radians().sin_cos();
    let spheres: String = [[0.0, 0.0, 0.0], [18.0, 0.0, 0.0], [0.0, 11.0, 0.0], [6.0, 6.0, 8.0]]
        .iter()
        .map(|m: &[f64; 3]| {
            let p = [
                AT[0] * 100.0 + c * m[0] - s * m[1],
                AT[1] * 100.0 + s * m[0] + c * m[1],
                AT[2] * 100.0 + m[2],
            ];
            format!(
                "[[synthetic.target]]\nshape = \"sphere\"\nradius = 1.0\nmotion = {{ kind = \"static\", position = [{}, {}, {}] }}\n\n",
                p[0], p[1], p[2]
            )
        })
        .collect();
    let target_start = text.find("[[synthetic.target]]").unwrap();
    let target_end = text[target_start..].find("[[host]]").unwrap() + target_start;
    let bodiless = format!(
        "{}{spheres}{}",
        text[..target_start].replace(body_block, ""),
        &text[target_end..]
    );
    std::fs::write(&with_body, &bodiless).unwrap();
    let run = Running::launch(&dir, &with_body, router);
    run.health_until("listening with no body", |h| {
        h.detail.get("natnet").is_some_and(|v| v == "listening")
            && h.detail.get("vrpn").is_some_and(|v| v == "listening")
    });
    // Clients while there is no body, for long enough to see the body come.
    let spawn = |script: &'static str, args: Vec<String>| {
        std::thread::spawn(move || {
            let a: Vec<&str> = args.iter().map(String::as_str).collect();
            python(script, &a, Duration::from_secs(90))
        })
    };
    let seconds = 14.0;
    let vrpn_client = spawn(
        "vrpn_client.py",
        vec![format!("127.0.0.1:{vrpn}"), seconds.to_string()],
    );
    let natnet_client = spawn(
        "natnet_clients.py",
        vec![
            "libmotioncapture".into(),
            natnet.to_string(),
            data.to_string(),
            seconds.to_string(),
        ],
    );
    std::thread::sleep(Duration::from_secs(4));
    assert!(run.sent().is_empty(), "a body sent before one was defined");
    // The body, as a user adds it: the file written beside and renamed.
    let tmp = format!("{with_body}.new");
    std::fs::write(
        &tmp,
        bodiless.replacen(
            "[[synthetic.target]]",
            &format!("{body_block}\n[[synthetic.target]]"),
            1,
        ),
    )
    .unwrap();
    std::fs::rename(&tmp, &with_body).unwrap();
    let h = run.health_until("the body applied", |h| {
        h.detail.get("bodies").is_some_and(|v| v == "head")
            && h.detail.get("rig_reloads").is_some_and(|v| v == "1")
    });
    eprintln!("{h:?}");
    let vrpn_out = vrpn_client.join().unwrap();
    let natnet_out = natnet_client.join().unwrap();
    let sent: Vec<Sent> = run.sent().into_iter().filter(|s| s.measured).collect();
    assert!(sent.len() > 30, "{} measured poses sent", sent.len());
    let at = |p: &[f64]| {
        let d = ((p[0] - AT[0]).powi(2) + (p[1] - AT[1]).powi(2) + (p[2] - AT[2]).powi(2)).sqrt();
        d < 0.005
    };
    assert!(
        sent.iter().all(|s| at(&s.position)),
        "not at the helmet's place"
    );
    let heads: Vec<&serde_json::Value> = vrpn_out.iter().filter(|v| v["name"] == "head").collect();
    assert!(
        heads.len() > 30,
        "the VRPN client connected before the body got {} poses of it: {:?}",
        heads.len(),
        vrpn_out.last()
    );
    assert!(
        heads.iter().all(|v| at(&f(&v["position"]))),
        "{:?}",
        heads[0]
    );
    // libmotioncapture reads the model definitions once, when it connects, and does not ask
    // again when a frame says the models changed: it gets the new body's poses by its id, with
    // no name (a client reconnecting, or one that asks again, gets the name).
    let natnet_poses: Vec<Vec<f64>> = natnet_out
        .iter()
        .filter(|v| v.get("position").is_some())
        .map(|v| {
            let p = f(&v["position"]);
            vec![p[0], -p[2], p[1]]
        })
        .collect();
    assert!(
        natnet_poses.len() > 30 && natnet_poses.iter().all(|p| at(p)),
        "the NatNet client got {} poses of the new body; its last lines: {:?}",
        natnet_poses.len(),
        &natnet_out[natnet_out.len().saturating_sub(3)..]
    );
    let mut launcher = run.launcher;
    launcher.stop();
    let log = launcher.output();
    assert!(log.contains("no [[body]] or [[model]] yet"), "{log}");
    assert!(
        !log.contains("restarted vrfeed") && !log.contains("restarted fusion"),
        "{log}"
    );
}
