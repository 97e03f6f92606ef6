//! Writes the inputs that `benches/opencv_reference.py` runs OpenCV on and
//! `tests/opencv_comparison.rs` runs this library on (deterministic; committed under
//! `tests/data/`): `cargo run -p stereoscope-geometry --example opencv_fixtures`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::write_with_newline)]

use nalgebra::Point3;
use std::fmt::Write as _;
use stereoscope_geometry::synthetic::{
    ViewSpread, calibration_views, example_camera, grid, ring_cameras,
};
use stereoscope_numeric::SplitMix64;

fn main() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    std::fs::create_dir_all(&dir).unwrap();

    // Calibration: 20 views of a 10 × 10 grid, 5 cm spacing, 0.2 px noise, 640 × 480.
    let spread = ViewSpread {
        lateral_m: 0.5,
        distance_m: (0.7, 1.0),
        aim_jitter_m: 0.0,
        roll: 0.3,
    };
    let views = calibration_views(
        &example_camera(),
        &grid(10, 10, 0.05),
        20,
        &spread,
        0.2,
        2026,
    );
    let mut csv = String::from("view,X,Y,Z,u,v\n");
    for (v, view) in views.iter().enumerate() {
        for (p, px) in view {
            writeln!(csv, "{v},{},{},0,{:.6},{:.6}", p.x, p.y, px.x, px.y).unwrap();
        }
    }
    std::fs::write(dir.join("calibration_points.csv"), csv).unwrap();

    // Triangulation: 4 cameras around a 1 m volume, 300 points, 0.5 px noise.
    let mut rng = SplitMix64::new(2026);
    let cams = ring_cameras(4);
    let mut json = String::from("{\n\"cameras\": [\n");
    for (i, c) in cams.iter().enumerate() {
        let r = c.cam_from_world.rotation.to_rotation_matrix();
        let m = r.matrix();
        let t = c.cam_from_world.translation.vector;
        let d = c.distortion;
        write!(
            json,
            "{{\"size\": [{}, {}], \"K\": [[{}, 0, {}], [0, {}, {}], [0, 0, 1]], \"dist\": [{}, {}, {}, {}, {}], \"R\": [[{}, {}, {}], [{}, {}, {}], [{}, {}, {}]], \"t\": [{}, {}, {}]}}{}\n",
            c.intrinsics.width, c.intrinsics.height, c.intrinsics.fx, c.intrinsics.cx, c.intrinsics.fy, c.intrinsics.cy,
            d.k1, d.k2, d.p1, d.p2, d.k3,
            m[(0, 0)], m[(0, 1)], m[(0, 2)], m[(1, 0)], m[(1, 1)], m[(1, 2)], m[(2, 0)], m[(2, 1)], m[(2, 2)],
            t.x, t.y, t.z,
            if i + 1 < cams.len() { "," } else { "" }
        )
        .unwrap();
    }
    json.push_str("],\n\"points\": [\n");
    for k in 0..300 {
        let p = Point3::new(
            rng.range(-0.5, 0.5),
            rng.range(-0.5, 0.5),
            rng.range(0.0, 0.9),
        );
        let px: Vec<String> = cams
            .iter()
            .map(|c| {
                let q = c.project(&p).unwrap();
                format!(
                    "[{:.6}, {:.6}]",
                    q.x + 0.5 * rng.normal(),
                    q.y + 0.5 * rng.normal()
                )
            })
            .collect();
        write!(
            json,
            "{{\"truth\": [{}, {}, {}], \"pixels\": [{}]}}{}\n",
            p.x,
            p.y,
            p.z,
            px.join(", "),
            if k + 1 < 300 { "," } else { "" }
        )
        .unwrap();
    }
    json.push_str("]\n}\n");
    std::fs::write(dir.join("triangulation.json"), json).unwrap();
    println!("wrote {}", dir.display());
}
