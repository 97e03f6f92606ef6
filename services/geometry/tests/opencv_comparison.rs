//! This library against OpenCV on the same input (`tests/data/`, made by
//! `examples/opencv_fixtures.rs`; OpenCV's answers in `opencv_reference.json`, made by
//! `benches/opencv_reference.py` — run `benches/compare-opencv.sh` to redo both).
//!
//! - calibration RMS within 2 % of `cv2.calibrateCamera`'s on the same correspondences;
//! - two-view triangulation no worse than `cv2.triangulatePoints` linearly, better refined.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use nalgebra::{
    Isometry3, Matrix3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use serde_json::Value;
use std::path::Path;
use stereoscope_geometry::calibrate::{DistortionModel, calibrate_camera};
use stereoscope_geometry::triangulate::{Observation, triangulate, triangulate_dlt};
use stereoscope_geometry::{Camera, Distortion, Intrinsics};

fn data(name: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data")
            .join(name),
    )
    .unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

#[test]
fn calibration_rms_matches_opencv_within_two_percent() {
    let reference: Value = serde_json::from_str(&data("opencv_reference.json")).unwrap();
    let mut views: Vec<(String, Vec<(Point3<f64>, Point2<f64>)>)> = Vec::new();
    for line in data("calibration_points.csv").lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        let n: Vec<f64> = c[1..].iter().map(|s| s.parse().unwrap()).collect();
        if views.last().is_none_or(|v| v.0 != c[0]) {
            views.push((c[0].to_string(), Vec::new()));
        }
        views
            .last_mut()
            .unwrap()
            .1
            .push((Point3::new(n[0], n[1], n[2]), Point2::new(n[3], n[4])));
    }
    let views: Vec<_> = views.into_iter().map(|v| v.1).collect();
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

fn camera(v: &Value) -> Camera {
    let k = &v["K"];
    let size = &v["size"];
    let intr = Intrinsics::new(
        f(&k[0][0]),
        f(&k[1][1]),
        f(&k[0][2]),
        f(&k[1][2]),
        size[0].as_u64().unwrap() as u32,
        size[1].as_u64().unwrap() as u32,
    )
    .unwrap();
    let d = &v["dist"];
    let dist = Distortion {
        k1: f(&d[0]),
        k2: f(&d[1]),
        p1: f(&d[2]),
        p2: f(&d[3]),
        k3: f(&d[4]),
    };
    let r = Matrix3::from_fn(|i, j| f(&v["R"][i][j]));
    let t = Vector3::new(f(&v["t"][0]), f(&v["t"][1]), f(&v["t"][2]));
    let pose = Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    );
    Camera::new(intr, dist, pose).unwrap()
}

#[test]
fn triangulation_is_no_worse_than_opencv_and_better_refined() {
    let reference: Value = serde_json::from_str(&data("opencv_reference.json")).unwrap();
    let tri: Value = serde_json::from_str(&data("triangulation.json")).unwrap();
    let cams: Vec<Camera> = tri["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(camera)
        .collect();
    let cv_err: Vec<f64> = reference["triangulation_two_view_errors_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(f)
        .collect();
    let (mut dlt2, mut ref2, mut ref4) = (Vec::new(), Vec::new(), Vec::new());
    for p in tri["points"].as_array().unwrap() {
        let truth = Point3::new(f(&p["truth"][0]), f(&p["truth"][1]), f(&p["truth"][2]));
        let obs: Vec<Observation> = (0..cams.len())
            .map(|c| Observation {
                camera: c,
                pixel: Point2::new(f(&p["pixels"][c][0]), f(&p["pixels"][c][1])),
            })
            .collect();
        dlt2.push((triangulate_dlt(&cams, &obs[..2]).unwrap() - truth).norm());
        ref2.push((triangulate(&cams, &obs[..2]).unwrap().point_world - truth).norm());
        ref4.push((triangulate(&cams, &obs).unwrap().point_world - truth).norm());
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64 * 1000.0;
    let (cv, d2, r2, r4) = (mean(&cv_err), mean(&dlt2), mean(&ref2), mean(&ref4));
    println!(
        "mean triangulation error over {} points (0.5 px noise): OpenCV triangulatePoints (2 views) {cv:.3} mm; ours DLT (2 views) {d2:.3} mm, refined (2 views) {r2:.3} mm, refined (4 views) {r4:.3} mm",
        cv_err.len()
    );
    assert!(d2 <= cv * 1.01, "linear: ours {d2} mm vs OpenCV {cv} mm");
    assert!(r2 < cv, "refined: ours {r2} mm vs OpenCV {cv} mm");
    assert!(r4 < r2);
}
