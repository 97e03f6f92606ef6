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

#[path = "../../../tests/chain/mod.rs"]
mod chain;

use chain::{BIN, ChainWand, Place, ceiling, end_to_end, record, rig_text, ring};
use std::process::Command;
use std::time::Instant;
use stereoscope_geometry::transform::camera_pose_error;
use stereoscope_rig::Rig;

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
        ("4, ceiling corners", ceiling(), 60.0),
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
    let ceiling = ceiling();
    if args.iter().any(|a| a == "--end-to-end-only") {
        print_chain(&ceiling, seconds);
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
    print_chain(&ceiling, seconds);
}

/// The whole calibration of the four ceiling cameras, as a table.
fn print_chain(places: &[Place], seconds: f64) {
    let r = end_to_end(places, ChainWand::Two, seconds, 8.0, 60.0);
    println!(
        "\nWhole calibration, four ceiling cameras (wand {seconds} s, L-frame 8 s, six known markers 8 s):\n"
    );
    println!(
        "| cameras in the floor's world against the truth | worst position {:.2} mm, worst rotation {:.4}° |",
        r.worst_position_m * 1e3,
        r.worst_rotation_deg
    );
    println!("|---|---|");
    println!(
        "| known markers, true rig | {:.3} mm RMS over {} positions ({} places of 6 seen) |",
        r.rms_true_mm, r.positions, r.places_seen
    );
    println!(
        "| known markers, calibrated rig | {:.3} mm RMS ({:+.1} %) |",
        r.rms_calibrated_mm,
        100.0 * (r.rms_calibrated_mm / r.rms_true_mm - 1.0)
    );
    println!(
        "| the same after the best rigid fit to the known places (the world's placement left out) | true rig {:.3} mm, calibrated rig {:.3} mm ({:+.1} %) |",
        r.fit_true_mm,
        r.fit_calibrated_mm,
        100.0 * (r.fit_calibrated_mm / r.fit_true_mm - 1.0)
    );
}
