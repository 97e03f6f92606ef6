//! This library against OpenCV on the same input (`tests/data/`, made by
//! `examples/opencv_fixtures.rs`; OpenCV's answers in `opencv_reference.json`, made by
//! `benches/opencv_reference.py` — run `benches/compare-opencv.sh` to redo both).
//!
//! - calibration RMS within 2 % of `cv2.calibrateCamera`'s on the same correspondences, with
//!   OpenCV's default model and with k3 fixed (`CALIB_FIX_K3`);
//! - two-view triangulation no worse than `cv2.triangulatePoints` linearly, better refined.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod fixtures;

use serde_json::Value;
use stereoscope_geometry::calibrate::{DistortionModel, calibrate_camera};
use stereoscope_geometry::triangulate::{Observation, triangulate, triangulate_dlt};

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// k1 k2 p1 p2 with k3 fixed against `cv2.calibrateCamera(..., flags=CALIB_FIX_K3)`: the same
/// RMS within 2 %, the same four terms, and k3 left at 0 by both.
#[test]
fn tangential_model_matches_opencv_with_k3_fixed() {
    let reference: Value = serde_json::from_str(&fixtures::read("opencv_reference.json")).unwrap();
    let views = fixtures::calibration_views();
    let cal = calibrate_camera(640, 480, &views, DistortionModel::Tangential).unwrap();
    let cv = &reference["calibration_fix_k3"];
    let (ours, theirs) = (cal.rms_px, f(&cv["rms_px"]));
    let d = cal.cameras[0].distortion;
    let dist: Vec<f64> = cv["dist"].as_array().unwrap().iter().map(f).collect();
    println!(
        "calibration RMS with k3 fixed: ours {ours:.5} px, OpenCV {theirs:.5} px; k1 k2 p1 p2 ours {:.5} {:.5} {:.6} {:.6}, OpenCV {:.5} {:.5} {:.6} {:.6}",
        d.k1, d.k2, d.p1, d.p2, dist[0], dist[1], dist[2], dist[3]
    );
    assert!(
        (ours - theirs).abs() / theirs <= 0.02,
        "ours {ours} vs OpenCV {theirs}"
    );
    assert_eq!((d.k3, dist[4]), (0.0, 0.0));
    assert!(
        (d.k1 - dist[0]).abs() < 2e-3 && (d.k2 - dist[1]).abs() < 1e-2,
        "{d:?} {dist:?}"
    );
    assert!(
        (d.p1 - dist[2]).abs() < 5e-5 && (d.p2 - dist[3]).abs() < 5e-5,
        "{d:?} {dist:?}"
    );
}

#[test]
fn calibration_rms_matches_opencv_within_two_percent() {
    let reference: Value = serde_json::from_str(&fixtures::read("opencv_reference.json")).unwrap();
    let views = fixtures::calibration_views();
    let cal = calibrate_camera(640, 480, &views, DistortionModel::Full).unwrap();
    let cv = &reference["calibration"];
    let (ours, theirs) = (cal.rms_px, f(&cv["rms_px"]));
    let c = &cal.cameras[0].intrinsics;
    println!(
        "calibration RMS: ours {ours:.5} px, OpenCV {} {theirs:.5} px ({:+.3} %); fx {:.3} vs {:.3}, fy {:.3} vs {:.3} (truth 812, 798)",
        reference["opencv_version"],
        100.0 * (ours - theirs) / theirs,
        c.fx,
        f(&cv["fx"]),
        c.fy,
        f(&cv["fy"])
    );
    assert!(
        (ours - theirs).abs() / theirs <= 0.02,
        "ours {ours} vs OpenCV {theirs}"
    );
}

#[test]
fn triangulation_is_no_worse_than_opencv_and_better_refined() {
    let reference: Value = serde_json::from_str(&fixtures::read("opencv_reference.json")).unwrap();
    let (cams, points) = fixtures::triangulation();
    let cv_err: Vec<f64> = reference["triangulation_two_view_errors_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(f)
        .collect();
    let (mut dlt2, mut ref2, mut ref4) = (Vec::new(), Vec::new(), Vec::new());
    for (truth, px) in &points {
        let obs: Vec<Observation> = px
            .iter()
            .enumerate()
            .map(|(c, &pixel)| Observation { camera: c, pixel })
            .collect();
        dlt2.push((triangulate_dlt(&cams, &obs[..2]).unwrap() - truth).norm());
        ref2.push((triangulate(&cams, &obs[..2]).unwrap().point_world - truth).norm());
        ref4.push((triangulate(&cams, &obs).unwrap().point_world - truth).norm());
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64 * 1000.0;
    let (cv, d2, r2, r4) = (mean(&cv_err), mean(&dlt2), mean(&ref2), mean(&ref4));
    println!(
        "mean triangulation error over {} points (0.5 px noise): OpenCV triangulatePoints (2 views) {cv:.4} mm; ours DLT (2 views) {d2:.4} mm, refined (2 views) {r2:.4} mm, refined (4 views) {r4:.4} mm",
        cv_err.len()
    );
    assert!(d2 <= cv * 1.01, "linear: ours {d2} mm vs OpenCV {cv} mm");
    assert!(r2 < cv, "refined: ours {r2} mm vs OpenCV {cv} mm");
    assert!(r4 < r2);
}
