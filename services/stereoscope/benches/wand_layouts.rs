//! The wand calibration end to end through the real services, for rigs of 2, 4 and 8 cameras
//! in different layouts (`docs/performance.md`, "Wand calibration", issue 13): for each, a rig
//! of synthetic 320 × 240 cameras at their true poses renders a 250 mm two-marker wand
//! turning and nodding round a circle; `stereoscope run` records the moment workers'
//! observations (the rig's `[recorder]`); `stereoscope calibrate wand` solves from the
//! recording; each camera's pose relative to the first (the calibration's world) is compared
//! with the truth. Prints a Markdown table.
//!
//! Then the whole calibration for the four ceiling cameras, as a user does it: the wand
//! (recorded, solved), an L-frame on the floor (recorded, fused again with the wand's rig by
//! `replay --rig`, `calibrate floor`), and six markers standing at known places (recorded with
//! the true rig, fused again with the calibrated one): the calibrated cameras against the
//! truth in the floor's world, and the markers' triangulation error with each rig.
//!
//!   cargo bench -p stereoscope --bench wand_layouts [-- --seconds S]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use stereoscope_geometry::transform::camera_pose_error;
use stereoscope_rig::Rig;

const BIN: &str = env!("CARGO_BIN_EXE_stereoscope");

/// A camera at `at` (cm) looking at `look` with `up`.
struct Place {
    at: [f64; 3],
    look: [f64; 3],
    up: [f64; 3],
}

fn ring(n: usize, radius: f64, heights: &[f64], rolled: Option<usize>) -> Vec<Place> {
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
const WAND_SCENE: &str = "[[body]]\nname = \"wand\"\nmarkers = [[0.0, 0.0, 0.0], [25.0, 0.0, 0.0]]\n\n[synthetic]\nseed = 5\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"body\"\nbody = \"wand\"\nradius = 1.0\nmotion = { kind = \"head\", centre = [0.0, 0.0, 70.0], radius = 35.0, period_s = 7.0, turn_period_s = 3.0, nod_deg = 40.0 }\n";

/// An L-frame on the floor at the origin: arms of 800 mm along +x and 500 mm along +y,
/// markers of 20 mm radius.
const L_FRAME_SCENE: &str = "[[body]]\nname = \"lframe\"\nmarkers = [[0.0, 0.0, 0.0], [80.0, 0.0, 0.0], [0.0, 50.0, 0.0]]\n\n[synthetic]\nseed = 6\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"body\"\nbody = \"lframe\"\nradius = 2.0\nmotion = { kind = \"static\", position = [0.0, 0.0, 0.0] }\n";

/// Markers standing at known places (cm).
const KNOWN_M: [[f64; 3]; 6] = [
    [0.40, 0.30, 0.40],
    [-0.40, 0.30, 0.60],
    [-0.40, -0.30, 0.40],
    [0.40, -0.30, 0.80],
    [0.0, 0.10, 1.00],
    [0.15, -0.10, 1.30],
];

fn known_scene() -> String {
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

fn rig_text(name: &str, places: &[Place], fps: f64, dir: &std::path::Path, port: u16) -> String {
    scene_rig(name, places, fps, dir, port, WAND_SCENE)
}

fn scene_rig(
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
            "[[camera]]\nid = \"cam{i}\"\nimage_size = [320, 240]\nfocal_length_mm = 6.0\npixel_pitch_um = [15.0, 15.0]\npose = {{ position = {:?}, look_at = {:?}, up = {:?} }}\nsource = {{ kind = \"synthetic\", fps = {fps} }}\nmoments = {{ threshold = \"auto\", max_objects = 4 }}\n\n",
            p.at, p.look, p.up
        );
    }
    t += &format!(
        "[fusion]\nmax_skew_ms = 5.0\n\n[recorder]\nfolder = \"{}\"\n\n{scene}\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{port}\"]\niceoryx2_prefix = \"stsc_wb{}_\"\n",
        dir.join("rec").display(),
        std::process::id()
    );
    t
}

/// Runs `rig_path` for `seconds` and returns the session folder it recorded.
fn record(rig_path: &std::path::Path, seconds: f64) -> std::path::PathBuf {
    let dir = rig_path.parent().unwrap();
    let mut run = Command::new(BIN)
        .args(["run", rig_path.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs_f64(seconds + 3.0));
    // SAFETY: signalling our own child.
    unsafe {
        libc::kill(run.id() as libc::pid_t, libc::SIGTERM);
    }
    let _ = run.wait();
    std::fs::read_dir(dir.join("rec"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .find(|p| p.join("observations.jsonl").exists())
        .expect("a recorded session")
}

/// `stereoscope ARGS`, which must succeed.
fn cli(args: &[&str]) -> String {
    let o = Command::new(BIN).args(args).output().unwrap();
    assert!(
        o.status.success(),
        "stereoscope {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).to_string()
}

/// Each known place's measured positions (within 5 cm of it) in a poses file.
fn near_known(poses_jsonl: &std::path::Path) -> Vec<Vec<[f64; 3]>> {
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

/// RMS (mm) of the markers' positions from their known places after the rigid motion that
/// fits them best (the error of the rig's geometry, its world's placement left out).
fn rms_after_fit(poses_jsonl: &std::path::Path) -> f64 {
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

/// RMS distance (mm) of each pose frame's markers from the nearest known place, and the
/// number of positions counted.
fn rms_from_known(poses_jsonl: &std::path::Path) -> (f64, usize) {
    let text = std::fs::read_to_string(poses_jsonl).unwrap();
    let (mut sq, mut n) = (0.0, 0usize);
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let f: serde_json::Value = serde_json::from_str(line).unwrap();
        for p in f["poses"].as_array().unwrap() {
            let x: Vec<f64> = p["position_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let d = KNOWN_M
                .iter()
                .map(|k| {
                    ((x[0] - k[0]).powi(2) + (x[1] - k[1]).powi(2) + (x[2] - k[2]).powi(2)).sqrt()
                })
                .fold(f64::MAX, f64::min);
            if d < 0.05 {
                sq += d * d;
                n += 1;
            }
        }
    }
    ((sq / n.max(1) as f64).sqrt() * 1e3, n)
}

/// The whole calibration of the four ceiling cameras (see the header).
fn end_to_end(places: &[Place], seconds: f64) {
    let root = std::env::temp_dir().join(format!("stereoscope-e2e-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let session = |tag: &str, scene: &str, secs: f64| {
        let dir = root.join(tag);
        std::fs::create_dir_all(&dir).unwrap();
        let port = stereoscope_transport::net::free_loopback_port().unwrap();
        let path = dir.join("rig.toml");
        std::fs::write(&path, scene_rig("e2e", places, 60.0, &dir, port, scene)).unwrap();
        (path.clone(), record(&path, secs))
    };
    let (wand_rig, wand_session) = session("wand", WAND_SCENE, seconds);
    let (_, floor_session) = session("floor", L_FRAME_SCENE, 8.0);
    let (_, known_session) = session("known", &known_scene(), 8.0);
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
        "250",
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
    cli(&[
        "calibrate",
        "floor",
        "--rig",
        &s(&cal),
        "--poses",
        &s(&floor_poses),
        "--l-frame",
        "800,500",
        "--units",
        "mm",
        "--out",
        &s(&fin),
    ]);
    let truth = Rig::load(&wand_rig).unwrap();
    let got = Rig::load(&fin).unwrap();
    let (mut worst_d, mut worst_a) = (0.0f64, 0.0f64);
    for (g, t) in got.cameras.iter().zip(&truth.cameras) {
        let (d, a) = camera_pose_error(&g.camera.cam_from_world, &t.camera.cam_from_world);
        worst_d = worst_d.max(d);
        worst_a = worst_a.max(a);
    }
    let refused = root.join("known-calibrated.jsonl");
    cli(&[
        "replay",
        &s(&known_session),
        "--rig",
        &s(&fin),
        "--out",
        &s(&refused),
    ]);
    let (rms_true, n_true) = rms_from_known(&known_session.join("poses.jsonl"));
    let (rms_cal, n_cal) = rms_from_known(&refused);
    let counts: Vec<usize> = near_known(&refused).iter().map(Vec::len).collect();
    println!("positions per known place (calibrated rig): {counts:?}");
    println!(
        "\nWhole calibration, four ceiling cameras (wand {seconds} s, L-frame 8 s, six known markers 8 s):\n"
    );
    println!(
        "| cameras in the floor's world against the truth | worst position {:.2} mm, worst rotation {:.4}° |",
        worst_d * 1e3,
        worst_a
    );
    println!("|---|---|");
    println!("| six known markers, true rig | {rms_true:.3} mm RMS over {n_true} positions |");
    println!(
        "| six known markers, calibrated rig | {rms_cal:.3} mm RMS over {n_cal} positions ({:+.1} %) |",
        100.0 * (rms_cal / rms_true - 1.0)
    );
    let (fit_true, fit_cal) = (
        rms_after_fit(&known_session.join("poses.jsonl")),
        rms_after_fit(&refused),
    );
    println!(
        "| the same after the best rigid fit to the known places (the world's placement left out) | true rig {fit_true:.3} mm, calibrated rig {fit_cal:.3} mm ({:+.1} %) |",
        100.0 * (fit_cal / fit_true - 1.0)
    );
    if std::env::var_os("KEEP").is_none() {
        let _ = std::fs::remove_dir_all(&root);
    } else {
        println!("kept {}", root.display());
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seconds: f64 = args
        .iter()
        .position(|a| a == "--seconds")
        .and_then(|i| args.get(i + 1))
        .and_then(|s| s.parse().ok())
        .unwrap_or(40.0);
    let layouts: Vec<(&str, Vec<Place>, f64)> = vec![
        (
            "2, facing across a ring",
            ring(2, 200.0, &[160.0], None),
            60.0,
        ),
        (
            "4, ceiling corners",
            vec![
                Place {
                    at: [-130.0, -130.0, 260.0],
                    look: [0.0, 0.0, 70.0],
                    up: [0.0, 0.0, 1.0],
                },
                Place {
                    at: [130.0, -130.0, 260.0],
                    look: [0.0, 0.0, 70.0],
                    up: [0.0, 0.0, 1.0],
                },
                Place {
                    at: [130.0, 130.0, 260.0],
                    look: [0.0, 0.0, 70.0],
                    up: [0.0, 0.0, 1.0],
                },
                Place {
                    at: [-130.0, 130.0, 260.0],
                    look: [0.0, 0.0, 70.0],
                    up: [0.0, 0.0, 1.0],
                },
            ],
            60.0,
        ),
        (
            "8, ring at mixed heights, one rolled 90°",
            ring(8, 220.0, &[90.0, 240.0], Some(3)),
            30.0,
        ),
    ];
    println!(
        "| layout | frames | reprojection RMS px | worst position mm | worst rotation ° | wand SD mm | solve s |"
    );
    println!("|---|---|---|---|---|---|---|");
    let ceiling: Vec<Place> = [
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
    .collect();
    if args.iter().any(|a| a == "--end-to-end-only") {
        end_to_end(&ceiling, seconds);
        return;
    }
    for (k, (name, places, fps)) in layouts.into_iter().enumerate() {
        let dir =
            std::env::temp_dir().join(format!("stereoscope-wandbench-{}-{k}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let port = stereoscope_transport::net::free_loopback_port().unwrap();
        let rig_path = dir.join("rig.toml");
        std::fs::write(
            &rig_path,
            rig_text(&format!("wandbench{k}"), &places, fps, &dir, port),
        )
        .unwrap();
        let session = record(&rig_path, seconds);
        let out_rig = dir.join("calibrated.toml");
        let t0 = Instant::now();
        let o = Command::new(BIN)
            .args([
                "calibrate",
                "wand",
                "--rig",
                rig_path.to_str().unwrap(),
                "--observations",
                session.join("observations.jsonl").to_str().unwrap(),
                "--wand",
                "250",
                "--units",
                "mm",
                "--json",
                "--out",
                out_rig.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        let solve_s = t0.elapsed().as_secs_f64();
        if !o.status.success() {
            println!(
                "| {name} | — | failed: {} | | | | |",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            continue;
        }
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let truth = Rig::load(&rig_path).unwrap();
        let got = Rig::load(&out_rig).unwrap();
        let world_from_cam0 = truth.cameras[0].camera.cam_from_world.inverse();
        let (mut worst_d, mut worst_a) = (0.0f64, 0.0f64);
        for (g, t) in got.cameras.iter().zip(&truth.cameras) {
            let want = t.camera.cam_from_world * world_from_cam0;
            let (d, a) = camera_pose_error(&g.camera.cam_from_world, &want);
            worst_d = worst_d.max(d);
            worst_a = worst_a.max(a);
        }
        let rms: Vec<f64> = report["cameras"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["reprojection_rms_px"].as_f64().unwrap())
            .collect();
        let (lo, hi) = rms
            .iter()
            .fold((f64::MAX, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
        println!(
            "| {name} | {} | {lo:.3}–{hi:.3} | {:.2} | {:.4} | {:.3} | {solve_s:.2} |",
            report["frames_used"],
            worst_d * 1e3,
            worst_a,
            report["wand_length_sd_mm"].as_f64().unwrap_or(f64::NAN),
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
    end_to_end(&ceiling, seconds);
}
