//! System tests of `stereoscope calibrate`, `fit-depth` and `triangulate`: the real binary on
//! files made here from known cameras. Every child is waited for with a bound; every test
//! works in its own temporary folder.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers may fail loudly

use nalgebra::{Isometry3, Point2, Point3, Vector3};
use std::fmt::Write as _;
use stereoscope_geometry::dotgrid::{DotGrid, render};
use stereoscope_geometry::synthetic::{
    ViewSpread, calibration_views, example_camera, grid, wand_frames, wand_rig_cameras,
};
use stereoscope_geometry::transform::{camera_pose_error, look_at};
use stereoscope_geometry::{Camera, Distortion, Intrinsics};
use stereoscope_numeric::SplitMix64;
use stereoscope_proto::reports::{CalibrationReport, DepthFitReport, TriangulatedPoint};
use stereoscope_rig::Rig;
use stereoscope_vision::raster::add_gaussian_noise;

mod common;
use common::{TempDir, repo_root, run, stderr};

/// A CSV of `views` tilted views (up to about 40°: straight-on views do not pin the focal
/// length down) of a 12 × 9 grid with 10 cm spacing, coordinates in centimetres.
fn calibration_csv(views: usize, noise: f64) -> String {
    let spread = ViewSpread {
        lateral_m: 1.05,
        distance_m: (1.3, 1.8),
        aim_jitter_m: 0.0,
        roll: 0.3,
    };
    let mut csv = String::from("view,X,Y,Z,u,v\n");
    for (v, view) in calibration_views(
        &example_camera(),
        &grid(12, 9, 0.1),
        views,
        &spread,
        noise,
        17,
    )
    .iter()
    .enumerate()
    {
        for (p, px) in view {
            writeln!(
                csv,
                "view{v},{},{},0,{},{}",
                (p.x * 100.0).round(),
                (p.y * 100.0).round(),
                px.x,
                px.y
            )
            .unwrap();
        }
    }
    csv
}

#[test]
fn calibrate_from_points_recovers_the_camera_and_writes_a_rig_table() {
    let dir = TempDir::new("cal-points");
    // 30 views × 108 points: the focal length's standard deviation is then about a third of
    // the 0.1 % asked for.
    let csv = dir.file("points.csv", &calibration_csv(30, 0.1));
    let out_toml = dir.0.join("camera.toml");
    let o = run(&[
        "calibrate",
        "--points",
        &csv,
        "--image-size",
        "640x480",
        "--units",
        "cm",
        "--json",
        "--out",
        out_toml.to_str().unwrap(),
        "--id",
        "left",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: CalibrationReport = serde_json::from_slice(&o.stdout).unwrap();
    assert!(
        (r.fx - 812.0).abs() / 812.0 < 1e-3,
        "fx {} ± {:?}, rms {}",
        r.fx,
        r.std_dev[0],
        r.rms_px
    );
    assert!((r.fy - 798.0).abs() / 798.0 < 1e-3, "fy {}", r.fy);
    assert!(r.rms_px > 0.08 && r.rms_px < 0.2, "rms {}", r.rms_px);
    assert_eq!(r.views.len(), 30);
    assert!(r.std_dev[0].unwrap() < 0.3, "{:?}", r.std_dev);
    assert!(r.std_dev[0].unwrap() > 0.0);
    // Translations come back in centimetres (the camera is 1.4–2 m from the target).
    let dist = (r.views[0].translation.iter().map(|t| t * t).sum::<f64>()).sqrt();
    assert!(dist > 100.0 && dist < 300.0, "{dist}");
    // The written table is a valid rig camera.
    let table = std::fs::read_to_string(&out_toml).unwrap();
    let rig = Rig::from_toml(&format!("name = \"t\"\nunits = \"cm\"\n{table}")).unwrap();
    assert_eq!(rig.cameras[0].id, "left");
    assert!((rig.cameras[0].camera.intrinsics.fx - r.fx).abs() < 1e-9);
    // The human report names the figures.
    let h = run(&[
        "calibrate",
        "--points",
        &csv,
        "--image-size",
        "640x480",
        "--units",
        "cm",
    ]);
    let text = String::from_utf8_lossy(&h.stdout);
    assert!(
        text.contains("RMS reprojection error") && text.contains("[[camera]]"),
        "{text}"
    );
}

#[test]
fn calibrate_from_dot_grid_images() {
    let dir = TempDir::new("cal-dots");
    let grid = DotGrid::new(8, 6, 0.05).unwrap();
    let cam = Camera::new(
        Intrinsics::new(700.0, 690.0, 322.0, 241.0, 640, 480).unwrap(),
        Distortion {
            k1: -0.1,
            ..Default::default()
        },
        Isometry3::identity(),
    )
    .unwrap();
    let mut rng = SplitMix64::new(3);
    let mut images = Vec::new();
    for k in 0..5 {
        let centre = Point3::new(0.175, 0.125, 0.0);
        let pos = centre
            + Vector3::new(
                rng.range(-0.25, 0.25),
                rng.range(-0.2, 0.2),
                -rng.range(0.9, 1.2),
            );
        let pose = look_at(pos, centre, Vector3::new(rng.range(-0.2, 0.2), -1.0, 0.0))
            .unwrap()
            .inverse();
        let mut img = render(&cam, &pose, &grid, 15.0, 200.0, 6).unwrap();
        add_gaussian_noise(&mut img, 2.0, &mut rng);
        let p = dir.0.join(format!("view{k}.pgm"));
        std::fs::write(&p, stereoscope_imageio::encode_pgm_u8(&img)).unwrap();
        images.push(p.to_str().unwrap().to_string());
    }
    // A picture without the grid is named and skipped; the rest still calibrate.
    let blank = dir.0.join("blank.pgm");
    std::fs::write(
        &blank,
        stereoscope_imageio::encode_pgm_u8(
            &stereoscope_vision::GrayImage::filled(640, 480, 15u8).unwrap(),
        ),
    )
    .unwrap();
    let mut args = vec![
        "calibrate",
        "--dot-grid",
        "8x6",
        "--spacing",
        "5",
        "--units",
        "cm",
        "--distortion",
        "radial",
        "--json",
    ];
    args.extend(images.iter().map(String::as_str));
    args.push(blank.to_str().unwrap());
    let o = run(&args);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("blank.pgm"), "{}", stderr(&o));
    let r: CalibrationReport = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r.views.len(), 5);
    assert!((r.fx - 700.0).abs() / 700.0 < 0.01, "fx {}", r.fx);
}

#[test]
fn calibrate_bad_input_is_named() {
    let dir = TempDir::new("cal-bad");
    let cases = [
        (
            "header.csv",
            "view,X,Y,u,v\n0,1,2,3,4\n",
            "header must be view,X,Y,Z,u,v",
        ),
        (
            "columns.csv",
            "view,X,Y,Z,u,v\n0,1,2,3,4\n",
            "line 2: expected 6 columns",
        ),
        (
            "nan.csv",
            "view,X,Y,Z,u,v\n0,1,2,0,NaN,4\n",
            "line 2: column u is NaN",
        ),
        (
            "text.csv",
            "view,X,Y,Z,u,v\n0,1,2,0,abc,4\n",
            "line 2: column u is \"abc\"",
        ),
    ];
    for (name, text, expect) in cases {
        let f = dir.file(name, text);
        let o = run(&["calibrate", "--points", &f, "--image-size", "640x480"]);
        assert_eq!(o.status.code(), Some(1), "{name}");
        let e = stderr(&o);
        assert!(e.contains(name) && e.contains(expect), "{name}: {e}");
        assert!(!e.contains("panicked"));
    }
    // One planar view cannot give a full camera.
    let one: String = calibration_csv(1, 0.0);
    let f = dir.file("one.csv", &one);
    let e = stderr(&run(&[
        "calibrate",
        "--points",
        &f,
        "--image-size",
        "640x480",
        "--units",
        "cm",
    ]));
    assert!(e.contains("single planar view"), "{e}");
    // Collinear points.
    let line: String = (0..10).fold(String::from("view,X,Y,Z,u,v\n"), |mut s, i| {
        writeln!(s, "a,{i},0,0,{},{}", 10 * i, 20).unwrap();
        writeln!(s, "b,{i},0,0,{},{}", 12 * i, 25).unwrap();
        s
    });
    let f = dir.file("line.csv", &line);
    let e = stderr(&run(&[
        "calibrate",
        "--points",
        &f,
        "--image-size",
        "640x480",
    ]));
    assert!(e.contains("collinear"), "{e}");
    // Missing image size; a bad size.
    let e = stderr(&run(&["calibrate", "--points", &f]));
    assert!(e.contains("--image-size"), "{e}");
    let o = run(&["calibrate", "--points", &f, "--image-size", "640by480"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn fit_depth_prefers_three_parameters_for_a_ball() {
    let dir = TempDir::new("fit");
    // A 4 cm ball seen on the axis: area ∝ 1/(D² − r²), r = 2 cm.
    let mut csv = String::from("area_px,distance\n");
    for i in 0..21 {
        let d = 75.0 + 10.0 * i as f64;
        writeln!(csv, "{},{d}", 3.65e6 / (d * d - 4.0)).unwrap();
    }
    let f = dir.file("samples.csv", &csv);
    let o = run(&["fit-depth", "--samples", &f, "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let fits: Vec<DepthFitReport> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(fits.len(), 2);
    let (two, three) = (&fits[0], &fits[1]);
    assert_eq!(three.model, "three_parameter");
    assert!(
        three.rms < 1e-6 && two.rms > 1e-3,
        "two {} three {}",
        two.rms,
        three.rms
    );
    assert!((three.c.unwrap() + 4.0).abs() < 1e-3);
    let text = String::from_utf8_lossy(&run(&["fit-depth", "--samples", &f]).stdout).into_owned();
    assert!(
        text.contains("three-parameter") && text.contains("RMS distance error"),
        "{text}"
    );
    let bad = dir.file("bad.csv", "area_px,distance\n100,-5\n50,10\n");
    let e = stderr(&run(&["fit-depth", "--samples", &bad]));
    assert!(e.contains("bad.csv") && e.contains("distance -5"), "{e}");
}

#[test]
fn triangulate_with_the_thesis_rig() {
    let dir = TempDir::new("tri");
    let rig_path = repo_root().join("deploy/rigs/thesis-lab.toml");
    let rig = Rig::from_toml(&std::fs::read_to_string(&rig_path).unwrap()).unwrap();
    let points = [
        Point3::new(0.05, 0.1, 0.3),
        Point3::new(-0.2, -0.15, 1.2),
        Point3::new(0.3, 0.2, 0.02),
    ];
    let mut csv = String::from("point,camera,u,v\n");
    for (i, p) in points.iter().enumerate() {
        for c in &rig.cameras {
            let px: Point2<f64> = c.camera.project(p).unwrap();
            writeln!(csv, "p{i},{},{},{}", c.id, px.x, px.y).unwrap();
        }
    }
    writeln!(csv, "lonely,cam0,100,100").unwrap();
    let f = dir.file("points.csv", &csv);
    let o = run(&[
        "triangulate",
        "--rig",
        rig_path.to_str().unwrap(),
        "--points",
        &f,
        "--json",
    ]);
    assert_eq!(
        o.status.code(),
        Some(1),
        "the lonely point fails: {}",
        stderr(&o)
    );
    assert!(
        stderr(&o).contains("\"lonely\"") && stderr(&o).contains("needs at least 2"),
        "{}",
        stderr(&o)
    );
    let got: Vec<TriangulatedPoint> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(got.len(), 3);
    for (g, p) in got.iter().zip(&points) {
        // The rig file is in centimetres.
        let want = p.coords * 100.0;
        assert!(
            (g.position[0] - want.x).abs() < 1e-6 && (g.position[2] - want.z).abs() < 1e-6,
            "{g:?} vs {want:?}"
        );
        assert_eq!(g.cameras, vec!["cam0", "cam1"]);
        assert!(g.rms_px < 1e-6);
    }
    // Unknown camera, bad rig.
    let f2 = dir.file("unknown.csv", "point,camera,u,v\na,cam9,1,2\n");
    let e = stderr(&run(&[
        "triangulate",
        "--rig",
        rig_path.to_str().unwrap(),
        "--points",
        &f2,
    ]));
    assert!(e.contains("line 2") && e.contains("\"cam9\""), "{e}");
    let bad_rig = dir.file(
        "bad.toml",
        &std::fs::read_to_string(&rig_path)
            .unwrap()
            .replace("focal_length_mm = 12.5", "focal_length_mm = -1.0"),
    );
    let e = stderr(&run(&["triangulate", "--rig", &bad_rig, "--points", &f]));
    assert!(
        e.contains("bad.toml") && e.contains("focal_length_mm: -1"),
        "{e}"
    );
}

/// A CSV frame,camera,u,v of a two-marker wand (500 mm) waved through the volume of
/// `synthetic::wand_rig_cameras`, 0.2 px of noise.
fn wand_csv(cams: &[Camera], frames: usize) -> String {
    csv_of(&wand_frames(cams, &[0.0, 0.5], frames, 0.2, 11))
}

/// Each frame's views as CSV rows frame,camera,u,v.
fn csv_of(frames: &[Vec<Vec<nalgebra::Point2<f64>>>]) -> String {
    let mut csv = String::from("frame,camera,u,v\n");
    for (f, views) in frames.iter().enumerate() {
        for (c, px) in views.iter().enumerate() {
            for p in px {
                writeln!(csv, "{f},cam{c},{:.4},{:.4}", p.x, p.y).unwrap();
            }
        }
    }
    csv
}

/// The rig file of `synthetic::wand_rig_cameras` without poses (millimetres).
fn wand_rig() -> String {
    let mut rig = String::from(
        "# Four cameras round the volume; poses from the wand.\nname = \"wand-ring\"\nunits = \"mm\"\n",
    );
    for c in 0..4 {
        write!(
            rig,
            "\n[[camera]]\nid = \"cam{c}\"\nimage_size = [640, 480]\nfx = 600.0\nfy = 600.0\nprincipal_point = [319.5, 239.5]\n"
        )
        .unwrap();
    }
    rig
}

/// `stereoscope calibrate wand` of the 500 mm wand's CSV, JSON report, the rig written to `out`.
fn calibrate_wand_cli(
    rig: &str,
    csv: &str,
    out: &std::path::Path,
    extra: &[&str],
) -> std::process::Output {
    let mut a = vec![
        "calibrate",
        "wand",
        "--rig",
        rig,
        "--observations",
        csv,
        "--wand",
        "500",
        "--json",
        "--out",
        out.to_str().unwrap(),
    ];
    a.extend_from_slice(extra);
    run(&a)
}

/// Focal lengths 3 % off: `--refine-intrinsics` writes them found again (fx, fy and the
/// principal point in place of what the file said), and the cameras placed.
#[test]
fn calibrate_wand_refines_intrinsics_a_few_percent_off() {
    let dir = TempDir::new("cal-wand-k");
    let truth = wand_rig_cameras();
    let csv = dir.file("wand.csv", &wand_csv(&truth, 800));
    let rig = dir.file(
        "rig.toml",
        &wand_rig().replace("fx = 600.0\nfy = 600.0", "fx = 618.0\nfy = 618.0"),
    );
    let out = dir.0.join("calibrated.toml");
    let args = |refine: bool| {
        let extra: &[&str] = if refine {
            &["--refine-intrinsics"]
        } else {
            &[]
        };
        calibrate_wand_cli(&rig, &csv, &out, extra)
    };
    let o = args(true);
    assert!(o.status.success(), "{}", stderr(&o));
    let got = Rig::load(&out).unwrap();
    for c in &got.cameras {
        let k = &c.camera.intrinsics;
        assert!(
            (k.fx / 600.0 - 1.0).abs() < 2e-3 && (k.fy / 600.0 - 1.0).abs() < 2e-3,
            "{k:?}"
        );
        assert!(
            (k.cx - 319.5).abs() < 1.5 && (k.cy - 239.5).abs() < 1.5,
            "{k:?}"
        );
    }
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(!text.contains("fx = 618"), "{text}");
    // Without, the written rig keeps the focal lengths it was given.
    let o = args(false);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&out).unwrap().contains("fx = 618"));
}

#[test]
fn calibrate_wand_places_a_ring_of_cameras_and_writes_the_rig() {
    let dir = TempDir::new("cal-wand");
    let truth = wand_rig_cameras();
    let csv = dir.file("wand.csv", &wand_csv(&truth, 800));
    let rig = dir.file("rig.toml", &wand_rig());
    let out = dir.0.join("calibrated.toml");
    let report = dir.0.join("report");
    let o = calibrate_wand_cli(&rig, &csv, &out, &["--report", report.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["cameras"].as_array().unwrap().len(), 4, "{r}");
    assert!(
        r["wand_length_mean_error_mm"].as_f64().unwrap().abs() < 0.3,
        "{r}"
    );
    // Eight regions of the volume, every used frame in one, none biased.
    let regions = r["regions"].as_array().unwrap();
    assert_eq!(regions.len(), 8, "{r}");
    let n: u64 = regions.iter().map(|g| g["samples"].as_u64().unwrap()).sum();
    assert_eq!(n, r["frames_used"].as_u64().unwrap(), "{r}");
    for g in regions {
        assert!(g["mean_error_mm"].as_f64().unwrap().abs() < 0.5, "{g}");
    }
    assert!(report.join("wand-report.md").exists() && report.join("wand-report.json").exists());
    // The coverage heat map, read back by MuPDF: a 160 × 120 tile per camera, 4 px apart.
    let o = common::run_program_with_limit(
        &common::python_clients(),
        &[
            common::repo_root()
                .join("tests/clients/image_stats.py")
                .to_str()
                .unwrap(),
            report.join("wand-coverage.png").to_str().unwrap(),
        ],
        std::time::Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let png: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (
            png["width"].as_u64(),
            png["height"].as_u64(),
            png["channels"].as_u64()
        ),
        (Some(4 * 164 - 4), Some(120), Some(3)),
        "{png}"
    );
    assert!(r["cameras"][0]["masked"].as_f64().unwrap() == 0.0, "{r}");
    // The written rig loads, keeps its comment, and puts every camera where it is, camera 0's
    // frame being the world.
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(
        text.starts_with("# Four cameras round the volume"),
        "{text}"
    );
    let got = Rig::load(&out).unwrap();
    let ref_from_world = truth[0].cam_from_world;
    for (c, cam) in truth.iter().enumerate() {
        let want: Isometry3<f64> = cam.cam_from_world * ref_from_world.inverse();
        let (d, a) = camera_pose_error(&got.cameras[c].camera.cam_from_world, &want);
        assert!(d < 1e-3, "camera {c}: {:.3} mm off", d * 1e3);
        assert!(a < 0.05, "camera {c}: {a:.4}° off");
    }
}

#[test]
fn calibrate_wand_bad_input_is_named() {
    let dir = TempDir::new("cal-wand-bad");
    let rig = dir.file("rig.toml", &wand_rig());
    let cases = [
        (
            "frame,camera,u,v\n0,cam0,10,20\n1,cam9,1,2\n",
            "wand.csv:3: camera \"cam9\"",
        ),
        ("frame,camera,u,v\n0,cam0,10,NaN\n", "wand.csv:2: v \"NaN\""),
        ("frame,cam,u,v\n", "wand.csv:1: the header"),
        (
            "frame,camera,u,v\n0,cam0,10,20\n",
            "share too few wand frames",
        ),
    ];
    for (text, want) in cases {
        let csv = dir.file("wand.csv", text);
        let o = run(&[
            "calibrate",
            "wand",
            "--rig",
            &rig,
            "--observations",
            &csv,
            "--wand",
            "500",
        ]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(want), "{want}: {}", stderr(&o));
    }
    // A pixel outside the rig's image (frames of another mode than the rig's).
    let csv = dir.file(
        "wand.csv",
        "frame,camera,u,v\n0,cam0,10,20\n0,cam1,700.5,20\n",
    );
    let o = run(&[
        "calibrate",
        "wand",
        "--rig",
        &rig,
        "--observations",
        &csv,
        "--wand",
        "500",
    ]);
    assert!(
        stderr(&o)
            .contains("wand.csv:3: (700.5, 20) is outside camera \"cam1\"'s image, 640 × 480"),
        "{}",
        stderr(&o)
    );
    let truth = wand_rig_cameras();
    // A camera that never saw the wand.
    let mut frames = wand_frames(&truth, &[0.0, 0.5], 300, 0.2, 11);
    for f in &mut frames {
        f[3].clear();
    }
    let csv = dir.file("wand.csv", &csv_of(&frames));
    let o = run(&[
        "calibrate",
        "wand",
        "--rig",
        &rig,
        "--observations",
        &csv,
        "--wand",
        "500",
    ]);
    assert!(
        stderr(&o).contains("camera cam3 shares too few wand frames")
            && stderr(&o).contains("cam3: 0 frames with the wand's 2 markers, 300 with 0 blobs")
            && stderr(&o).contains("wave the wand where each of these cameras sees it"),
        "{}",
        stderr(&o)
    );
    // A three-marker wand with other distances than said.
    let csv = dir.file(
        "wand.csv",
        &csv_of(&wand_frames(&truth, &[0.0, 0.25, 0.5], 400, 0.2, 11)),
    );
    let o = run(&[
        "calibrate",
        "wand",
        "--rig",
        &rig,
        "--observations",
        &csv,
        "--wand",
        "150,500",
    ]);
    assert!(
        stderr(&o).contains("the wand's middle marker measures 2")
            && stderr(&o).contains("mm from its end marker, not 150.0 mm"),
        "{}",
        stderr(&o)
    );
    // Every sample in one plane (the wand swept in a vertical plane): refused with advice.
    let mut rng = stereoscope_numeric::SplitMix64::new(5);
    let planar: Vec<Vec<Vec<nalgebra::Point2<f64>>>> = (0..600)
        .map(|_| {
            let a = Point3::new(rng.range(-0.6, 0.6), 0.05, rng.range(0.5, 1.5));
            let t = rng.range(0.0, std::f64::consts::TAU);
            let d = Vector3::new(t.cos(), 0.0, t.sin());
            truth
                .iter()
                .map(|c| {
                    [a, a + d * 0.5]
                        .iter()
                        .filter_map(|m| c.project(m))
                        .filter(|p| p.x >= 0.0 && p.y >= 0.0 && p.x < 639.0 && p.y < 479.0)
                        .collect()
                })
                .collect()
        })
        .collect();
    let csv = dir.file("wand.csv", &csv_of(&planar));
    let o = run(&[
        "calibrate",
        "wand",
        "--rig",
        &rig,
        "--observations",
        &csv,
        "--wand",
        "500",
    ]);
    assert!(
        stderr(&o).contains("lie in one plane") && stderr(&o).contains("not in one plane"),
        "{}",
        stderr(&o)
    );
    let o = run(&[
        "calibrate",
        "wand",
        "--rig",
        &rig,
        "--observations",
        "x.csv",
        "--wand",
        "0,0",
    ]);
    assert!(stderr(&o).contains("--wand"), "{}", stderr(&o));
}

/// The rig of `synthetic::wand_rig_cameras` as `calibrate wand` leaves it: poses in the first
/// camera's frame (millimetres).
fn rig_in_first_camera_frame(truth: &[Camera]) -> String {
    rig_in_first_camera_frame_scaled(truth, 1.0)
}

/// [`rig_in_first_camera_frame`] with every length times `scale` (a one-marker wand's rig).
fn rig_in_first_camera_frame_scaled(truth: &[Camera], scale: f64) -> String {
    let mut rig = String::from("name = \"floor-test\"\nunits = \"mm\"\n");
    let world_from_ref = truth[0].cam_from_world.inverse();
    for (c, cam) in truth.iter().enumerate() {
        let pose = cam.cam_from_world * world_from_ref;
        let r = pose.rotation.to_rotation_matrix();
        let row = |i: usize| format!("[{}, {}, {}]", r[(i, 0)], r[(i, 1)], r[(i, 2)]);
        let t = pose.translation.vector * 1e3 * scale;
        write!(
            rig,
            "\n[[camera]]\nid = \"cam{c}\"\nimage_size = [640, 480]\nfx = 600.0\nfy = 600.0\nprincipal_point = [319.5, 239.5]\npose = {{ cam_from_world_rotation = [{}, {}, {}], cam_from_world_translation = [{}, {}, {}] }}\n",
            row(0),
            row(1),
            row(2),
            t.x,
            t.y,
            t.z
        )
        .unwrap();
    }
    rig
}

/// A recording's poses.jsonl: the markers (true-world positions) seen from the first camera's
/// frame, with 0.3 mm of noise, over 40 frames.
fn still_markers_jsonl(truth: &[Camera], markers: &[Point3<f64>]) -> String {
    still_markers_jsonl_scaled(truth, markers, 1.0)
}

/// [`still_markers_jsonl`] triangulated by a rig whose lengths are `scale` times the truth's
/// (its noise scaled with it).
fn still_markers_jsonl_scaled(truth: &[Camera], markers: &[Point3<f64>], scale: f64) -> String {
    use stereoscope_proto::messages::{Pose, PoseFrame, PoseMethod, SCHEMA_VERSION};
    let mut rng = SplitMix64::new(3);
    let ref_from_world = truth[0].cam_from_world;
    let mut out = String::new();
    for k in 0..40u64 {
        let poses = markers
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let p = Point3::from(
                    ((ref_from_world * m).coords
                        + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 3e-4)
                        * scale,
                );
                Pose {
                    object_id: i as u32 + 1,
                    position_m: [p.x, p.y, p.z],
                    velocity_m_per_s: [0.0; 3],
                    heading_deg: None,
                    heading_directed: false,
                    method: PoseMethod::Triangulated,
                    cameras: vec!["cam0".into(), "cam1".into()],
                    residual_px: 0.1,
                    out_of_range: false,
                    body: None,
                    model: None,
                }
            })
            .collect();
        let f = PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "floor-test".into(),
            sequence: k,
            timestamp_ns: 1_000_000_000 + k * 33_333_333,
            frame_published_ns: 0,
            published_ns: 0,
            cameras: vec!["cam0".into(), "cam1".into()],
            poses,
            bodies: Vec::new(),
            models: Vec::new(),
        };
        out.push_str(&serde_json::to_string(&f).unwrap());
        out.push('\n');
    }
    out
}

#[test]
fn calibrate_floor_puts_the_world_on_an_l_frame() {
    let dir = TempDir::new("cal-floor");
    let truth = wand_rig_cameras();
    let rig = dir.file("rig.toml", &rig_in_first_camera_frame(&truth));
    // An L of 600 × 400 mm on the floor (z = 0), turned 0.7 rad, its corner at (0.1, −0.2),
    // and a marker elsewhere.
    let (o, a) = (Point3::new(0.1, -0.2, 0.0), 0.7f64);
    let ex = Vector3::new(a.cos(), a.sin(), 0.0);
    let ey = Vector3::new(-a.sin(), a.cos(), 0.0);
    let extra = Point3::new(-0.3, 0.4, 0.9);
    let poses = dir.file(
        "poses.jsonl",
        &still_markers_jsonl(&truth, &[o + ey * 0.4, extra, o, o + ex * 0.6]),
    );
    let out = dir.0.join("floor.toml");
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &poses,
        "--l-frame",
        "600,400",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(o_run.status.success(), "{}", stderr(&o_run));
    let r: serde_json::Value = serde_json::from_slice(&o_run.stdout).unwrap();
    assert_eq!(
        (
            r["l_frame"]["corner"].as_u64(),
            r["l_frame"]["x_arm"].as_u64(),
            r["l_frame"]["y_arm"].as_u64()
        ),
        (Some(3), Some(4), Some(1)),
        "{r}"
    );
    let got = Rig::load(&out).unwrap();
    let world_from_l = Isometry3::from_parts(
        nalgebra::Translation3::from(o.coords),
        nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a),
    );
    for (c, cam) in truth.iter().enumerate() {
        let want = cam.cam_from_world * world_from_l;
        let pose = got.cameras[c].camera.cam_from_world;
        let (d, ang) = camera_pose_error(&pose, &want);
        assert!(d < 1e-3, "camera {c}: {:.3} mm off", d * 1e3);
        assert!(ang < 0.05, "camera {c}: {ang:.4}° off");
        let h = r["camera_heights"][c][1].as_f64().unwrap();
        assert!((h - (pose.inverse() * Point3::origin()).z * 1e3).abs() < 1e-6);
        assert!(h > 900.0, "camera {c} {h} mm up");
    }
    // A mirrored L (the arms swapped on the floor): z would point down, away from every camera.
    let mirrored = dir.file(
        "mirrored.jsonl",
        &still_markers_jsonl(&truth, &[o, o + ey * 0.6, o + ex * 0.4]),
    );
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &mirrored,
        "--l-frame",
        "600,400",
    ]);
    assert!(!o_run.status.success());
    assert!(
        stderr(&o_run).contains("every camera is below this floor"),
        "{}",
        stderr(&o_run)
    );
    // No L of that size: the markers' distances are listed.
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &poses,
        "--l-frame",
        "800,300",
    ]);
    assert!(!o_run.status.success());
    assert!(
        stderr(&o_run).contains("no 3 steady markers make an L of 800.0 × 300.0 mm"),
        "{}",
        stderr(&o_run)
    );
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &poses,
        "--l-frame",
        "400,600",
    ]);
    assert!(stderr(&o_run).contains("--l-frame"), "{}", stderr(&o_run));
}

/// The rig's poses against the truth in the world `world_from_l` (an L's or the floor's frame).
fn assert_rig_in(got: &Rig, truth: &[Camera], world_from_l: &Isometry3<f64>, tol_mm: f64) {
    for (c, cam) in truth.iter().enumerate() {
        let want = cam.cam_from_world * world_from_l;
        let pose = got.cameras[c].camera.cam_from_world;
        let (d, ang) = camera_pose_error(&pose, &want);
        assert!(d < tol_mm * 1e-3, "camera {c}: {:.3} mm off", d * 1e3);
        assert!(ang < 0.05, "camera {c}: {ang:.4}° off");
    }
}

/// A four-marker L-frame (a fourth marker 250 mm along the long arm) raised 12 mm off the floor
/// by its markers, seen by a rig of unknown scale (a one-marker wand's: 0.37 of the truth):
/// `--scale` finds the factor, `--marker-height` puts z = 0 on the floor, and the markers'
/// order in the file says nothing.
#[test]
fn calibrate_floor_scales_the_rig_to_a_four_marker_l_frame() {
    let dir = TempDir::new("cal-floor-scale");
    let truth = wand_rig_cameras();
    let scale = 0.37;
    let rig = dir.file("rig.toml", &rig_in_first_camera_frame_scaled(&truth, scale));
    let (o, a) = (Point3::new(-0.15, 0.25, 0.012), -1.1f64);
    let ex = Vector3::new(a.cos(), a.sin(), 0.0);
    let ey = Vector3::new(-a.sin(), a.cos(), 0.0);
    let extra = Point3::new(0.3, 0.1, 1.1);
    let poses = dir.file(
        "poses.jsonl",
        &still_markers_jsonl_scaled(
            &truth,
            &[o + ex * 0.25, o + ey * 0.4, extra, o + ex * 0.6, o],
            scale,
        ),
    );
    let out = dir.0.join("floor.toml");
    let floor = |extra_args: &[&str]| {
        let mut args = vec![
            "calibrate",
            "floor",
            "--rig",
            &rig,
            "--poses",
            &poses,
            "--l-frame",
            "600,400,250",
            "--marker-height",
            "12",
            "--json",
        ];
        args.extend_from_slice(extra_args);
        run(&args)
    };
    let o_run = floor(&["--scale", "--out", out.to_str().unwrap()]);
    assert!(o_run.status.success(), "{}", stderr(&o_run));
    let r: serde_json::Value = serde_json::from_slice(&o_run.stdout).unwrap();
    assert_eq!(
        (
            r["l_frame"]["corner"].as_u64(),
            r["l_frame"]["x_arm"].as_u64(),
            r["l_frame"]["y_arm"].as_u64(),
            r["l_frame"]["x_middle"].as_u64()
        ),
        (Some(5), Some(4), Some(2), Some(1)),
        "{r}"
    );
    let got_scale = r["scale"].as_f64().unwrap();
    assert!((got_scale * scale - 1.0).abs() < 2e-3, "{r}");
    let world_from_l = Isometry3::from_parts(
        nalgebra::Translation3::new(o.x, o.y, 0.0),
        nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a),
    );
    // 0.3 mm of noise on each marker in each frame: the L's tilt is known to about 0.03°, so
    // cameras 3 m away within 3 mm.
    assert_rig_in(&Rig::load(&out).unwrap(), &truth, &world_from_l, 3.0);
    // Without --scale the L does not fit: its shape does, its size is 0.37 of it.
    let o_run = floor(&[]);
    assert!(!o_run.status.success());
    assert!(
        stderr(&o_run).contains(
            "no 4 steady markers make an L of 600.0 × 400.0 mm with a marker 250.0 mm along x"
        ),
        "{}",
        stderr(&o_run)
    );
}

/// Markers lying on the floor (five, tilted 2° against the first camera's world), one at the
/// origin and one on +x each recorded on its own; and the errors of a line of markers, an
/// origin recording with two markers and `--scale` with --points.
#[test]
fn calibrate_floor_from_markers_on_it_and_one_at_the_origin() {
    let dir = TempDir::new("cal-floor-points");
    let truth = wand_rig_cameras();
    let rig = dir.file("rig.toml", &rig_in_first_camera_frame(&truth));
    // The floor's world in the truth's: turned 0.4 rad about z and tilted 2° about x, its
    // origin at (0.2, 0.1, 0.05); markers 10 mm above it.
    let floor_in_truth = Isometry3::from_parts(
        nalgebra::Translation3::new(0.2, 0.1, 0.05),
        nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 2f64.to_radians())
            * nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.4),
    );
    let on_floor = |x: f64, y: f64| floor_in_truth * Point3::new(x, y, 0.01);
    let floor_markers = [
        on_floor(-0.5, -0.4),
        on_floor(0.6, -0.3),
        on_floor(0.4, 0.5),
        on_floor(-0.3, 0.6),
        on_floor(0.0, -0.6),
    ];
    let poses = dir.file("floor.jsonl", &still_markers_jsonl(&truth, &floor_markers));
    let origin = dir.file(
        "origin.jsonl",
        &still_markers_jsonl(&truth, &[on_floor(0.0, 0.0)]),
    );
    let x_axis = dir.file(
        "x.jsonl",
        &still_markers_jsonl(&truth, &[on_floor(0.7, 0.0)]),
    );
    let out = dir.0.join("floor.toml");
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &poses,
        "--points",
        "--origin",
        &origin,
        "--x-axis",
        &x_axis,
        "--marker-height",
        "10",
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(o_run.status.success(), "{}", stderr(&o_run));
    let r: serde_json::Value = serde_json::from_slice(&o_run.stdout).unwrap();
    assert_eq!(
        r["points"]["floor_markers"].as_array().map(Vec::len),
        Some(5),
        "{r}"
    );
    assert!(r["fit_error_mm"].as_f64().unwrap() < 0.5, "{r}");
    assert!(
        r["points"]["origin_above_plane_mm"].as_f64().unwrap().abs() < 1.0,
        "{r}"
    );
    assert_rig_in(&Rig::load(&out).unwrap(), &truth, &floor_in_truth, 1.5);
    // Without --x-axis: the same floor and origin, x along camera 0's right.
    let o_run = run(&[
        "calibrate",
        "floor",
        "--rig",
        &rig,
        "--poses",
        &poses,
        "--points",
        "--origin",
        &origin,
        "--marker-height",
        "10",
        "--json",
    ]);
    assert!(o_run.status.success(), "{}", stderr(&o_run));
    let r: serde_json::Value = serde_json::from_slice(&o_run.stdout).unwrap();
    assert_eq!(r["points"]["x_axis_from"], "camera 0's right", "{r}");
    // Errors: markers in a line; two markers in the origin's recording; --scale with --points.
    let line = dir.file(
        "line.jsonl",
        &still_markers_jsonl(
            &truth,
            &[
                on_floor(-0.5, 0.0),
                on_floor(0.0, 0.001),
                on_floor(0.5, 0.0),
            ],
        ),
    );
    let two = dir.file(
        "two.jsonl",
        &still_markers_jsonl(&truth, &[on_floor(0.0, 0.0), on_floor(0.3, 0.3)]),
    );
    for (poses, origin, extra, want) in [
        (&line, &origin, None, "lie (nearly) in a line"),
        (
            &poses,
            &two,
            None,
            "2 steady markers; the origin recording must hold exactly one",
        ),
        (&poses, &origin, Some("--scale"), "cannot be used with"),
    ] {
        let mut args = vec![
            "calibrate",
            "floor",
            "--rig",
            &rig,
            "--poses",
            poses,
            "--points",
            "--origin",
            origin,
        ];
        args.extend(extra);
        let o_run = run(&args);
        assert!(!o_run.status.success());
        assert!(stderr(&o_run).contains(want), "{want}: {}", stderr(&o_run));
    }
}

/// The printable dot grid, SVG and PDF, rasterised by MuPDF (PyMuPDF) at 60 dpi as a camera
/// looking straight at the print would see it: the dot-grid finder labels every dot — the big
/// one the origin, x along the 7 columns, y down the 5 rows — each where the page put it at
/// true size (30 mm = 70.9 px at 60 dpi), within a tenth of a pixel.
#[test]
fn a_printed_dot_grid_is_found_at_true_size_with_its_axes() {
    let dir = TempDir::new("target");
    let python = common::python_clients();
    let script = repo_root().join("tests/clients/rasterise.py");
    let grid = DotGrid::new(7, 5, 30.0).unwrap();
    let layout = stereoscope::target::page(&grid, 1.0);
    let dpi = 60.0;
    let px_per_mm = dpi / 25.4;
    for ext in ["svg", "pdf"] {
        let page = dir.0.join(format!("grid.{ext}"));
        let o = run(&[
            "target",
            "dot-grid",
            "7x5",
            "--spacing",
            "30",
            "--units",
            "mm",
            "--page",
            "any",
            "--out",
            page.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(String::from_utf8_lossy(&o.stdout).contains("7 columns along x"));
        let png = dir.0.join(format!("grid-{ext}.png"));
        let o = common::run_program_with_limit(
            &python,
            &[
                script.to_str().unwrap(),
                page.to_str().unwrap(),
                png.to_str().unwrap(),
                "60",
            ],
            std::time::Duration::from_secs(60),
        );
        assert!(o.status.success(), "{ext}: {}", stderr(&o));
        let size: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let width_mm = size["width_pt"].as_f64().unwrap() * 25.4 / 72.0;
        assert!((width_mm - layout.width_mm).abs() < 0.01, "{ext}: {size}");
        let stereoscope_imageio::AnyGray::U8(img) = stereoscope_imageio::read_gray(&png).unwrap()
        else {
            panic!("{ext}: not an 8-bit image");
        };
        let dots = stereoscope_geometry::dotgrid::detect(img.view(), &grid).unwrap();
        assert_eq!(dots.len(), 35, "{ext}");
        let mut worst: f64 = 0.0;
        for (i, px) in dots {
            let q = grid.point(i);
            // Pixel centres at integers: a point x mm from the page's edge is at x·k − ½.
            let want = Point2::new(
                (layout.origin[0] + q.x) * px_per_mm - 0.5,
                (layout.origin[1] + q.y) * px_per_mm - 0.5,
            );
            worst = worst.max((px - want).norm());
        }
        assert!(
            worst < 0.1,
            "{ext}: a dot {worst:.3} px from its printed place"
        );
    }
    let o = run(&[
        "target",
        "dot-grid",
        "7x5",
        "--spacing",
        "30",
        "--out",
        "grid.png",
    ]);
    assert!(stderr(&o).contains(".svg or .pdf"), "{}", stderr(&o));
    let o = run(&[
        "target",
        "dot-grid",
        "1x5",
        "--spacing",
        "30",
        "--out",
        "g.svg",
    ]);
    assert!(stderr(&o).contains("2 × 2"), "{}", stderr(&o));
    // The page fits A4 and Letter unless told otherwise: 30 mm is refused with the spacing
    // that fits; without --spacing the largest whole millimetre that fits is chosen.
    let o = run(&[
        "target",
        "dot-grid",
        "7x5",
        "--spacing",
        "30",
        "--out",
        "g.svg",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("makes a 260 × 228 mm page, larger than A4 and Letter")
            && stderr(&o).contains("--spacing 27 or less"),
        "{}",
        stderr(&o)
    );
    let fitted = dir.0.join("fitted.svg");
    let o = run(&[
        "target",
        "dot-grid",
        "7x5",
        "--out",
        fitted.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(
        said.contains("236 x 210 mm, fits A4 and Letter (landscape)")
            && said.contains("--dot-grid 7x5 --spacing 27 --units mm"),
        "{said}"
    );
}

/// Calibration with no camera yet (docs/calibration.md opens with it): the synthetic scene holds
/// the printed dot grid (`shape = "dot_grid"`) in front of a 640 × 480 camera, turning and
/// tilting; `grab` saves its frames and `calibrate --dot-grid` recovers the camera's focal
/// lengths — 12.5 mm over 10.75 µm and 12.5 µm pixels: 1162.8 and 1000.0 px — within 0.5 %.
#[test]
fn a_synthetic_dot_grid_calibrates_the_synthetic_camera() {
    let dir = TempDir::new("cal-synthetic");
    let rig = dir.file(
        "rig.toml",
        "name = \"board\"\nunits = \"cm\"\n\n[[camera]]\nid = \"cam0\"\nimage_size = [640, 480]\n\
         focal_length_mm = 12.5\npixel_pitch_um = [10.75, 12.5]\n\
         pose = { position = [0.0, 0.0, 280.0], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }\n\
         source = { kind = \"synthetic\", fps = 30.0 }\n\
         moments = { threshold = \"auto\", max_objects = 40 }\n\n\
         [synthetic]\nseed = 4\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"dot_grid\"\n\
         radius = 0.54\ngrid = { cols = 7, rows = 5, spacing = 2.7 }\n\
         motion = { kind = \"head\", centre = [0.0, 0.0, 200.0], radius = 6.0, period_s = 11.0, turn_period_s = 7.0, nod_deg = 35.0 }\n",
    );
    let frames = dir.0.join("frames");
    let o = run(&[
        "grab",
        &rig,
        "--camera",
        "cam0",
        "--count",
        "16",
        "--every",
        "0.7",
        frames.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut images: Vec<String> = std::fs::read_dir(&frames)
        .unwrap()
        .flatten()
        .map(|e| e.path().display().to_string())
        .filter(|p| p.ends_with(".pgm"))
        .collect();
    images.sort();
    assert_eq!(images.len(), 16);
    let mut args = vec![
        "calibrate",
        "--dot-grid",
        "7x5",
        "--spacing",
        "27",
        "--units",
        "mm",
        "--json",
    ];
    args.extend(images.iter().map(String::as_str));
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let (fx, fy) = (v["fx"].as_f64().unwrap(), v["fy"].as_f64().unwrap());
    let (want_fx, want_fy) = (12.5 / 10.75e-3, 12.5 / 12.5e-3);
    assert!(
        (fx / want_fx - 1.0).abs() < 0.005 && (fy / want_fy - 1.0).abs() < 0.005,
        "fx {fx} (truth {want_fx}), fy {fy} (truth {want_fy})"
    );
    assert!(v["rms_px"].as_f64().unwrap() < 0.2, "{v}");
}
