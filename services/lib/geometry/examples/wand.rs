//! The wand calibration timed and checked against truth: four 640 × 480 cameras about 3 m
//! from the volume (`synthetic::wand_rig_cameras`), a two-marker wand of 500 mm, Gaussian
//! pixel noise.
//!
//!   cargo run --release -p stereoscope-geometry --example wand -- [--frames 2000] [--noise 0.2] [--runs 3] [--export FILE.json]
//!
//! `--export` writes the same detections labelled by marker, the cameras' intrinsics, their
//! true poses, the adjustment's starting estimate and this solution (all relative to camera
//! 0), and the solve's time, for a peer to adjust from the same start
//! (`services/lib/geometry/examples/wand_aniposelib.py`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::Isometry3;
use std::time::Instant;
use stereoscope_geometry::synthetic::{wand_frames, wand_frames_in_order, wand_rig_cameras};
use stereoscope_geometry::transform::camera_pose_error;
use stereoscope_geometry::wand::{Wand, WandConfig, WandFrame, calibrate_wand};

fn arg(args: &[String], name: &str, default: f64) -> f64 {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map_or(default, |s| s.parse().unwrap())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let count = arg(&args, "--frames", 2000.0) as usize;
    let noise = arg(&args, "--noise", 0.2);
    let runs = arg(&args, "--runs", 3.0) as usize;
    let truth = wand_rig_cameras();
    let wand = Wand::two(0.5).unwrap();
    let frames: Vec<WandFrame> = wand_frames(&truth, &wand.offsets_m, count, noise, 5)
        .into_iter()
        .enumerate()
        .map(|(k, pixels)| WandFrame {
            frame: k as u64,
            pixels,
        })
        .collect();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let t = Instant::now();
        let sol = calibrate_wand(&truth, &frames, &wand, &WandConfig::default()).unwrap();
        times.push(t.elapsed().as_secs_f64());
        last = Some(sol);
    }
    let sol = last.unwrap();
    times.sort_by(f64::total_cmp);
    let ref_from_world = truth[0].cam_from_world;
    let (mut worst_mm, mut worst_deg) = (0.0f64, 0.0f64);
    for (c, cam) in truth.iter().enumerate() {
        let want = cam.cam_from_world * ref_from_world.inverse();
        let (d, a) = camera_pose_error(&sol.cam_from_ref[c], &want);
        println!(
            "camera {c}: {:.3} mm, {a:.4}° from truth; reprojection RMS {:.3} px over {} marker images",
            d * 1e3,
            sol.per_camera[c].0,
            sol.per_camera[c].1
        );
        worst_mm = worst_mm.max(d * 1e3);
        worst_deg = worst_deg.max(a);
    }
    if let Some(path) = args
        .iter()
        .position(|a| a == "--export")
        .and_then(|i| args.get(i + 1))
    {
        let pose = |p: &Isometry3<f64>| {
            let r = p.rotation.scaled_axis();
            let t = p.translation.vector;
            serde_json::json!({"rvec": [r.x, r.y, r.z], "tvec": [t.x, t.y, t.z]})
        };
        let labelled = wand_frames_in_order(&truth, &wand.offsets_m, count, noise, 5, false);
        let markers = wand.markers();
        let cameras: Vec<serde_json::Value> = truth
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let k = &cam.intrinsics;
                let d = &cam.distortion;
                serde_json::json!({
                    "size": [k.width, k.height],
                    "matrix": [[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]],
                    "dist": [d.k1, d.k2, d.p1, d.p2, d.k3],
                    "truth": pose(&(cam.cam_from_world * ref_from_world.inverse())),
                    "initial": pose(&sol.initial_cam_from_ref[c]),
                    "ours": pose(&sol.cam_from_ref[c]),
                    // Each frame's two markers in order, null where the view lacks one.
                    "points": labelled
                        .iter()
                        .flat_map(|views| {
                            let v = &views[c];
                            (0..markers)
                                .map(move |m| (v.len() == markers).then(|| [v[m].x, v[m].y]))
                        })
                        .collect::<Vec<_>>(),
                })
            })
            .collect();
        let out = serde_json::json!({
            "wand_m": wand.length_m(),
            "noise_px": noise,
            "cameras": cameras,
            "ours_solve_s": times[times.len() / 2],
            "ours_rms_px": sol.per_camera.iter().map(|p| p.0).collect::<Vec<_>>(),
        });
        std::fs::write(path, out.to_string()).unwrap();
    }
    println!(
        "{count} frames, {noise} px: worst camera {worst_mm:.3} mm and {worst_deg:.4}°; wand {:.3} ± {:.3} mm (free triangulation); {} frames used, {} outliers; solve median {:.3} s (min {:.3}, max {:.3}) over {runs} runs",
        sol.length_mean_m.unwrap_or(f64::NAN) * 1e3,
        sol.length_sd_m.unwrap_or(f64::NAN) * 1e3,
        sol.frames_used,
        sol.frames_outliers,
        times[times.len() / 2],
        times[0],
        times[times.len() - 1]
    );
}
