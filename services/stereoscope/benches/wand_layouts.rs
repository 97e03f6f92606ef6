//! The wand calibration end to end through the real services, for rigs of 2, 4 and 8 cameras
//! in different layouts (`docs/performance.md`, "Wand calibration", issue 13): for each, a rig
//! of synthetic 320 × 240 cameras at their true poses renders a 250 mm two-marker wand
//! turning and nodding round a circle; `stereoscope run` records the moment workers'
//! observations (the rig's `[recorder]`); `stereoscope calibrate wand` solves from the
//! recording; each camera's pose relative to the first (the calibration's world) is compared
//! with the truth. Prints a Markdown table.
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

fn rig_text(name: &str, places: &[Place], fps: f64, dir: &std::path::Path, port: u16) -> String {
    let mut t = format!("name = \"{name}\"\nunits = \"cm\"\n\n");
    for (i, p) in places.iter().enumerate() {
        t += &format!(
            "[[camera]]\nid = \"cam{i}\"\nimage_size = [320, 240]\nfocal_length_mm = 6.0\npixel_pitch_um = [15.0, 15.0]\npose = {{ position = {:?}, look_at = {:?}, up = {:?} }}\nsource = {{ kind = \"synthetic\", fps = {fps} }}\nmoments = {{ threshold = \"auto\", max_objects = 4 }}\n\n",
            p.at, p.look, p.up
        );
    }
    t += &format!(
        "[fusion]\nmax_skew_ms = 5.0\n\n[[body]]\nname = \"wand\"\nmarkers = [[0.0, 0.0, 0.0], [25.0, 0.0, 0.0]]\n\n[recorder]\nfolder = \"{}\"\n\n[synthetic]\nseed = 5\nnoise_sigma = 2.0\nblur_sigma_px = 0.6\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"body\"\nbody = \"wand\"\nradius = 1.0\nmotion = {{ kind = \"head\", centre = [0.0, 0.0, 70.0], radius = 35.0, period_s = 7.0, turn_period_s = 3.0, nod_deg = 40.0 }}\n\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{port}\"]\niceoryx2_prefix = \"stsc_wb{}_\"\n",
        dir.join("rec").display(),
        std::process::id()
    );
    t
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
        let session = std::fs::read_dir(dir.join("rec"))
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .find(|p| p.join("observations.jsonl").exists())
            .expect("a recorded session");
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
}
