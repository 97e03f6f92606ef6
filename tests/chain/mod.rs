//! The whole calibration chain through the real services, shared by the system test
//! (`tests/calibration.rs`) and the benchmark (`benches/wand_layouts.rs`): rigs of synthetic
//! cameras at true poses, scenes to record (a wand, an L-frame, markers at known places),
//! `stereoscope run` recording them, and the command line solving (`docs/calibration.md`).
#![allow(dead_code)]

use std::process::{Command, Stdio};
use std::time::Duration;
use stereoscope_geometry::transform::camera_pose_error;
use stereoscope_rig::Rig;

pub const BIN: &str = env!("CARGO_BIN_EXE_stereoscope");

/// A camera at `at` (cm) looking at `look` with `up`.
pub struct Place {
    pub at: [f64; 3],
    pub look: [f64; 3],
    pub up: [f64; 3],
}

pub fn ring(n: usize, radius: f64, heights: &[f64], rolled: Option<usize>) -> Vec<Place> {
    (0..n)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / n as f64;
            let (x, y) = (radius * a.cos(), radius * a.sin());
            // A camera rolled 90° about its axis: its image's up is the ring's tangent.
            let up = if rolled == Some(i) {
                [-a.sin(), a.cos(), 0.0]
            } else {
                [0.0, 0.0, 1.0]
            };
            Place {
                at: [x, y, heights[i % heights.len()]],
                look: [0.0, 0.0, 70.0],
                up,
            }
        })
        .collect()
}

/// The wand: two markers 250 mm apart, turning and nodding round a circle.
pub const WAND_SCENE: &str = "[[body]]\nname = \"wand\"\nmarkers = [[0.0, 0.0, 0.0], [25.0, 0.0, 0.0]]\n\n[synthetic]\nseed = 5\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"body\"\nbody = \"wand\"\nradius = 1.0\nmotion = { kind = \"head\", centre = [0.0, 0.0, 70.0], radius = 35.0, period_s = 7.0, turn_period_s = 3.0, nod_deg = 40.0 }\n";

/// A one-marker wand: a single 10 mm ball wandering through a 0.9 × 0.9 × 0.7 m volume about
/// (0, 0, 0.7) m.
pub const ONE_MARKER_WAND_SCENE: &str = "[synthetic]\nseed = 5\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"sphere\"\nradius = 1.0\nmotion = { kind = \"wander\", centre = [0.0, 0.0, 70.0], extent = [45.0, 45.0, 35.0], seed = 3 }\n";

/// Which wand the chain waves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ChainWand {
    /// Two markers 250 mm apart: the scale from the wand.
    Two,
    /// One marker: the scale from the floor's L-frame (`calibrate floor --scale`).
    One,
}

/// An L-frame on the floor at the origin: arms of 800 mm along +x and 500 mm along +y,
/// markers of 20 mm radius.
pub const L_FRAME_SCENE: &str = "[[body]]\nname = \"lframe\"\nmarkers = [[0.0, 0.0, 0.0], [80.0, 0.0, 0.0], [0.0, 50.0, 0.0]]\n\n[synthetic]\nseed = 6\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"body\"\nbody = \"lframe\"\nradius = 2.0\nmotion = { kind = \"static\", position = [0.0, 0.0, 0.0] }\n";

/// Markers standing at known places (metres), 0.3–1.35 m up.
pub const KNOWN_M: [[f64; 3]; 6] = [
    [0.40, 0.30, 0.40],
    [-0.35, 0.25, 0.65],
    [-0.25, -0.40, 0.30],
    [0.30, -0.20, 0.85],
    [0.05, 0.10, 1.05],
    [0.15, -0.05, 1.35],
];

pub fn known_scene() -> String {
    let mut t =
        "[synthetic]\nseed = 7\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n"
            .to_string();
    for p in KNOWN_M {
        t += &format!(
            "[[synthetic.target]]\nshape = \"sphere\"\nradius = 1.0\nmotion = {{ kind = \"static\", position = [{}, {}, {}] }}\n\n",
            p[0] * 100.0,
            p[1] * 100.0,
            p[2] * 100.0
        );
    }
    t
}

pub fn rig_text(
    name: &str,
    places: &[Place],
    fps: f64,
    dir: &std::path::Path,
    port: u16,
) -> String {
    scene_rig(name, places, fps, dir, port, WAND_SCENE)
}

/// Numbers the iceoryx2 prefixes of one process's rigs.
static NEXT_PREFIX: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// One whole chain at a time in a process: two rigs of four cameras at 60 fps at once are
/// more than two cores render and track, each camera then drops a quarter of its frames on
/// its own, and the L-frame's marker that only two cameras see is fused in too few frames for
/// `calibrate floor` (docs/reliability.md). What the tests check is the calibration, not an
/// overloaded machine.
static ONE_CHAIN_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

pub fn scene_rig(
    name: &str,
    places: &[Place],
    fps: f64,
    dir: &std::path::Path,
    port: u16,
    scene: &str,
) -> String {
    let mut t = format!("name = \"{name}\"\nunits = \"cm\"\n\n");
    for (i, p) in places.iter().enumerate() {
        t += &format!(
            "[[camera]]\nid = \"cam{i}\"\nimage_size = [320, 240]\nfocal_length_mm = 6.0\npixel_pitch_um = [15.0, 15.0]\npose = {{ position = {:?}, look_at = {:?}, up = {:?} }}\nsource = {{ kind = \"synthetic\", fps = {fps} }}\nmoments = {{ threshold = \"auto\", max_objects = 8 }}\n\n",
            p.at, p.look, p.up
        );
    }
    t += &format!(
        "[fusion]\nmax_skew_ms = 5.0\n\n[recorder]\nfolder = \"{}\"\n\n{scene}\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{port}\"]\niceoryx2_prefix = \"stsc_wb{}_{}_\"\n",
        dir.join("rec").display(),
        std::process::id(),
        // Each rig of this process its own prefix: tests run in parallel.
        NEXT_PREFIX.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    );
    t
}

/// Runs `rig_path`, waits (up to a minute) until its recorder has written observations, lets
/// it record `seconds` more, stops it, and returns the session folder it recorded.
pub fn record(rig_path: &std::path::Path, seconds: f64) -> std::path::PathBuf {
    let dir = rig_path.parent().unwrap();
    // The launcher's lines, kept beside the recording: its restarts are said below.
    let log_path = dir.join("launcher.log");
    let log = std::fs::File::create(&log_path).unwrap();
    let mut run = Command::new(BIN)
        .args(["run", rig_path.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap();
    let session = || {
        std::fs::read_dir(dir.join("rec"))
            .ok()?
            .flatten()
            .map(|e| e.path())
            .find(|p| std::fs::metadata(p.join("observations.jsonl")).is_ok_and(|m| m.len() > 0))
    };
    let stop = |run: &mut std::process::Child, signal: libc::c_int| {
        // SAFETY: signalling our own child.
        unsafe {
            libc::kill(run.id() as libc::pid_t, signal);
        }
    };
    let end = std::time::Instant::now() + Duration::from_secs(60);
    let found = loop {
        if let Some(s) = session() {
            break Some(s);
        }
        if std::time::Instant::now() > end || run.try_wait().ok().flatten().is_some() {
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    if found.is_some() {
        std::thread::sleep(Duration::from_secs_f64(seconds));
    }
    stop(&mut run, libc::SIGTERM);
    let end = std::time::Instant::now() + Duration::from_secs(30);
    let mut exited = false;
    while !exited && std::time::Instant::now() < end {
        exited = run.try_wait().ok().flatten().is_some();
        std::thread::sleep(Duration::from_millis(50));
    }
    if !exited {
        stop(&mut run, libc::SIGKILL);
    }
    let _ = run.wait();
    // A service killed or restarted while the chain recorded is named in the test's output
    // (shown when a bound of the test fails).
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    for line in log
        .lines()
        .filter(|l| l.contains("restarting in") || l.contains("killing it"))
    {
        eprintln!("while recording: {line}");
    }
    found.expect("the recorder wrote no observations within a minute of `stereoscope run`")
}

/// `stereoscope ARGS`, which must succeed.
pub fn cli(args: &[&str]) -> String {
    let o = Command::new(BIN).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "stereoscope {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Each known place's measured positions (within 5 cm of it) in a poses file.
pub fn near_known(poses_jsonl: &std::path::Path) -> Vec<Vec<[f64; 3]>> {
    let text = std::fs::read_to_string(poses_jsonl).unwrap();
    let mut out = vec![Vec::new(); KNOWN_M.len()];
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let f: serde_json::Value = serde_json::from_str(line).unwrap();
        for p in f["poses"].as_array().unwrap() {
            let x: Vec<f64> = p["position_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let d = |k: &[f64; 3]| {
                ((x[0] - k[0]).powi(2) + (x[1] - k[1]).powi(2) + (x[2] - k[2]).powi(2)).sqrt()
            };
            if let Some(i) = (0..KNOWN_M.len()).find(|&i| d(&KNOWN_M[i]) < 0.05) {
                out[i].push([x[0], x[1], x[2]]);
            }
        }
    }
    out
}

/// The known places' RMS distance from their centroid, metres: a rig wrong in scale by `s`
/// misplaces them, after a rigid fit, by about `s` times this.
pub fn known_rms_radius_m() -> f64 {
    let n = KNOWN_M.len() as f64;
    let c: Vec<f64> = (0..3)
        .map(|k| KNOWN_M.iter().map(|p| p[k]).sum::<f64>() / n)
        .collect();
    let sq: f64 = KNOWN_M
        .iter()
        .map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>())
        .sum();
    (sq / n).sqrt()
}

/// RMS (mm) of the markers' positions from their known places after the rigid motion that
/// fits them best (the error of the rig's geometry, its world's placement left out).
pub fn rms_after_fit(poses_jsonl: &std::path::Path) -> f64 {
    use nalgebra::Point3;
    let seen = near_known(poses_jsonl);
    let mean: Vec<Point3<f64>> = seen
        .iter()
        .map(|v| {
            let n = v.len().max(1) as f64;
            Point3::new(
                v.iter().map(|p| p[0]).sum::<f64>() / n,
                v.iter().map(|p| p[1]).sum::<f64>() / n,
                v.iter().map(|p| p[2]).sum::<f64>() / n,
            )
        })
        .collect();
    let known: Vec<Point3<f64>> = KNOWN_M
        .iter()
        .map(|k| Point3::new(k[0], k[1], k[2]))
        .collect();
    // Places never measured weigh nothing.
    let weights: Vec<f64> = seen.iter().map(|v| (!v.is_empty()) as u8 as f64).collect();
    let (known_from_measured, _) = stereoscope_bodies::kabsch(&mean, &known, &weights).unwrap();
    let (mut sq, mut n) = (0.0, 0usize);
    for (i, v) in seen.iter().enumerate() {
        for p in v {
            let q = known_from_measured * Point3::new(p[0], p[1], p[2]);
            sq += (q - known[i]).norm_squared();
            n += 1;
        }
    }
    (sq / n.max(1) as f64).sqrt() * 1e3
}

/// RMS distance (mm) of each pose frame's markers from their known place, and the number of
/// positions counted.
pub fn rms_from_known(poses_jsonl: &std::path::Path) -> (f64, usize) {
    let (mut sq, mut n) = (0.0, 0usize);
    for (v, k) in near_known(poses_jsonl).iter().zip(KNOWN_M) {
        for p in v {
            sq += (0..3).map(|i| (p[i] - k[i]).powi(2)).sum::<f64>();
            n += 1;
        }
    }
    ((sq / n.max(1) as f64).sqrt() * 1e3, n)
}

/// The four ceiling cameras: corners of a 2.6 × 2.6 m square, 2.6 m up, looking at the
/// volume's middle.
pub fn ceiling() -> Vec<Place> {
    [
        [-130.0, -130.0],
        [130.0, -130.0],
        [130.0, 130.0],
        [-130.0, 130.0],
    ]
    .iter()
    .map(|&[x, y]| Place {
        at: [x, y, 260.0],
        look: [0.0, 0.0, 70.0],
        up: [0.0, 0.0, 1.0],
    })
    .collect()
}

/// What the whole calibration achieved.
#[derive(Debug, Clone)]
pub struct ChainResult {
    /// The calibrated cameras in the floor's world against the truth: worst position (m) and
    /// rotation (degrees).
    pub worst_position_m: f64,
    pub worst_rotation_deg: f64,
    /// The calibrated rig's size against the truth's (its cameras' distances), minus 1.
    pub scale_error: f64,
    /// The known markers' RMS error (mm) fused with the true rig and with the calibrated one,
    /// and the positions counted.
    pub rms_true_mm: f64,
    pub rms_calibrated_mm: f64,
    pub positions: usize,
    /// The same after each set's best rigid fit to the known places.
    pub fit_true_mm: f64,
    pub fit_calibrated_mm: f64,
    /// Known places measured at least once (of six).
    pub places_seen: usize,
}

/// The whole calibration, as a user does it: the wand recorded for `wand_s` and solved; an
/// L-frame on the floor recorded for `still_s`, fused again with the wand's rig (`replay
/// --rig`) and `calibrate floor`; six markers at known places recorded for `still_s` with the
/// true rig and fused again with the calibrated one.
pub fn end_to_end(
    places: &[Place],
    wand: ChainWand,
    wand_s: f64,
    still_s: f64,
    fps: f64,
) -> ChainResult {
    let _alone = ONE_CHAIN_AT_A_TIME
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    let root = std::env::temp_dir().join(format!(
        "stereoscope-chain-{}-{}-{wand:?}",
        std::process::id(),
        places.len()
    ));
    let _ = std::fs::remove_dir_all(&root);
    let session = |tag: &str, scene: &str, secs: f64| {
        let dir = root.join(tag);
        std::fs::create_dir_all(&dir).unwrap();
        let port = stereoscope_transport::net::free_loopback_port().unwrap();
        let path = dir.join("rig.toml");
        std::fs::write(&path, scene_rig("chain", places, fps, &dir, port, scene)).unwrap();
        (path.clone(), record(&path, secs))
    };
    let (scene, wand_arg) = match wand {
        ChainWand::Two => (WAND_SCENE, "250"),
        ChainWand::One => (ONE_MARKER_WAND_SCENE, "0"),
    };
    let (wand_rig, wand_session) = session("wand", scene, wand_s);
    let (_, floor_session) = session("floor", L_FRAME_SCENE, still_s);
    let (_, known_session) = session("known", &known_scene(), still_s);
    let s = |p: &std::path::Path| p.to_str().unwrap().to_string();
    let cal = root.join("wand-calibrated.toml");
    cli(&[
        "calibrate",
        "wand",
        "--rig",
        &s(&wand_rig),
        "--observations",
        &s(&wand_session.join("observations.jsonl")),
        "--wand",
        wand_arg,
        "--units",
        "mm",
        "--out",
        &s(&cal),
    ]);
    let floor_poses = root.join("floor-poses.jsonl");
    cli(&[
        "replay",
        &s(&floor_session),
        "--rig",
        &s(&cal),
        "--out",
        &s(&floor_poses),
    ]);
    let fin = root.join("calibrated.toml");
    let (cal_s, floor_s, fin_s) = (s(&cal), s(&floor_poses), s(&fin));
    let mut floor = vec![
        "calibrate",
        "floor",
        "--rig",
        &cal_s,
        "--poses",
        &floor_s,
        "--l-frame",
        "800,500",
        "--units",
        "mm",
        "--out",
        &fin_s,
    ];
    if wand == ChainWand::One {
        floor.push("--scale");
    }
    cli(&floor);
    let truth = Rig::load(&wand_rig).unwrap();
    let got = Rig::load(&fin).unwrap();
    let (mut worst_d, mut worst_a) = (0.0f64, 0.0f64);
    for (g, t) in got.cameras.iter().zip(&truth.cameras) {
        let (d, a) = camera_pose_error(&g.camera.cam_from_world, &t.camera.cam_from_world);
        worst_d = worst_d.max(d);
        worst_a = worst_a.max(a);
    }
    // The rig's scale: the cameras' distances from each other against the truth's.
    let spread = |r: &Rig| {
        let at: Vec<_> = r
            .cameras
            .iter()
            .map(|c| c.camera.position_world())
            .collect();
        let mut sum = 0.0;
        for i in 0..at.len() {
            for j in i + 1..at.len() {
                sum += (at[i] - at[j]).norm();
            }
        }
        sum
    };
    let scale_error = spread(&got) / spread(&truth) - 1.0;
    let refused = root.join("known-calibrated.jsonl");
    cli(&[
        "replay",
        &s(&known_session),
        "--rig",
        &s(&fin),
        "--out",
        &s(&refused),
    ]);
    let recorded = known_session.join("poses.jsonl");
    let (rms_true_mm, positions) = rms_from_known(&recorded);
    let (rms_calibrated_mm, _) = rms_from_known(&refused);
    let result = ChainResult {
        scale_error,
        worst_position_m: worst_d,
        worst_rotation_deg: worst_a,
        rms_true_mm,
        rms_calibrated_mm,
        positions,
        fit_true_mm: rms_after_fit(&recorded),
        fit_calibrated_mm: rms_after_fit(&refused),
        places_seen: near_known(&refused)
            .iter()
            .filter(|v| !v.is_empty())
            .count(),
    };
    let _ = std::fs::remove_dir_all(&root);
    result
}
