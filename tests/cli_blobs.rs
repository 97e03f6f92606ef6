#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers may fail loudly
//! System tests of `stereoscope blobs`: the real binary on real files.
//! Every child is waited for with a bound; every test works in its own temporary folder.

use std::process::Output;
use stereoscope_proto::blobs::BlobsReport;
use stereoscope_vision::GrayImage;
use stereoscope_vision::raster::{Ellipse, draw_ellipse};

mod common;
use common::{TempDir, repo_root, run};

fn reports(out: &Output) -> Vec<BlobsReport> {
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("bad JSON line {l:?}: {e}")))
        .collect()
}

#[test]
fn quick_start_example_finds_the_three_targets() {
    let out = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--par",
        "0.86",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = reports(&out);
    assert_eq!(r.len(), 1);
    let blobs = &r[0].blobs;
    assert_eq!(blobs.len(), 3, "{blobs:?}");
    // Truth from services/stereoscope/src/example.rs, in raster order.
    for (b, (x, y)) in blobs
        .iter()
        .zip([(110.4, 95.3), (230.7, 160.2), (70.25, 184.6)])
    {
        assert!(
            (b.x_px - x).abs() < 0.15 && (b.y_px - y).abs() < 0.15,
            "{b:?} vs ({x}, {y})"
        );
    }
    // The glued balls lie at 30°, the oblong marker at −50° (PAR 0.86 corrected).
    assert!(
        (blobs[0].orientation_deg - 30.0).abs() < 1.0,
        "{}",
        blobs[0].orientation_deg
    );
    assert!(
        (blobs[2].orientation_deg + 50.0).abs() < 1.0,
        "{}",
        blobs[2].orientation_deg
    );
    // The human table names the same image.
    let table = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--par",
        "0.86",
    ]);
    assert!(table.status.success());
    assert!(String::from_utf8_lossy(&table.stdout).contains("3 blobs"));
}

#[test]
fn sixteen_bit_pgm_and_png_give_the_same_blobs_as_eight_bit() {
    let dir = TempDir::new("formats");
    let mut img8 = GrayImage::filled(120, 80, 10u8).unwrap();
    let e = Ellipse {
        cx_px: 50.3,
        cy_px: 40.6,
        semi_major: 14.0,
        semi_minor: 6.0,
        angle_deg: 20.0,
    };
    draw_ellipse(&mut img8, &e, 1.0, 10.0, 210.0, 8);
    let img16 = GrayImage::from_vec(
        img8.as_slice().iter().map(|&p| p as u16 * 257).collect(),
        120,
        80,
    )
    .unwrap();
    let p8 = dir.0.join("a.pgm");
    let p16 = dir.0.join("b.pgm");
    let png = dir.0.join("c.png");
    std::fs::write(&p8, stereoscope_imageio::encode_pgm_u8(&img8)).unwrap();
    std::fs::write(&p16, stereoscope_imageio::encode_pgm_u16(&img16, 65535)).unwrap();
    std::fs::write(&png, stereoscope_imageio::encode_png_u8(&img8).unwrap()).unwrap();
    let out8 = run(&[
        "blobs",
        p8.to_str().unwrap(),
        png.to_str().unwrap(),
        "--threshold",
        "110",
        "--json",
    ]);
    let out16 = run(&[
        "blobs",
        p16.to_str().unwrap(),
        "--threshold",
        "28270",
        "--json",
    ]);
    assert!(out8.status.success() && out16.status.success());
    let (r8, r16) = (reports(&out8), reports(&out16));
    assert_eq!(r8.len(), 2);
    assert_eq!(r8[0].blobs, r8[1].blobs, "PGM and PNG disagree");
    assert_eq!(r8[0].blobs, r16[0].blobs, "8- and 16-bit disagree");
    assert_eq!(r8[0].blobs.len(), 1);
    assert!((r8[0].blobs[0].orientation_deg - 20.0).abs() < 1.0);
}

#[test]
fn bad_files_are_named_and_do_not_stop_the_others() {
    let dir = TempDir::new("bad");
    let truncated = dir.0.join("truncated.pgm");
    std::fs::write(&truncated, b"P5\n10 10\n255\n\x00\x00\x00").unwrap();
    let garbage = dir.0.join("garbage.png");
    std::fs::write(&garbage, b"this is not an image").unwrap();
    let missing = dir.0.join("missing.pgm");
    let good = repo_root().join("docs/examples/thesis-targets-320x240.pgm");
    let args = [
        "blobs",
        truncated.to_str().unwrap(),
        garbage.to_str().unwrap(),
        missing.to_str().unwrap(),
        good.to_str().unwrap(),
        "--json",
    ];
    let out = run(&args);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("truncated.pgm") && err.contains("truncated"),
        "{err}"
    );
    assert!(
        err.contains("garbage.png") && err.contains("not a PGM or PNG"),
        "{err}"
    );
    assert!(
        err.contains("missing.pgm") && err.contains("cannot read"),
        "{err}"
    );
    assert_eq!(reports(&out).len(), 1, "the good image is still reported");
    assert!(!err.contains("panicked"));
}

#[test]
fn bad_options_are_rejected_with_the_value() {
    let out = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--threshold",
        "bright",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("bright"));
    let out = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--threshold",
        "300",
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("threshold 300 is out of range"));
    let out = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--connectivity",
        "6",
    ]);
    assert_eq!(out.status.code(), Some(2));
    let out = run(&[
        "blobs",
        "docs/examples/thesis-targets-320x240.pgm",
        "--par",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("pixel aspect ratio 0"));
}

/// `stereoscope grab` on the demo rig's synthetic camera: three frames half a second of
/// scene time apart and a preview, read back by MuPDF (PyMuPDF), software the project did
/// not write: the frames have the camera's size and the preview marks in red the pixels the
/// worker's threshold keeps (less those its boxes and crosses cover). A camera the rig does
/// not have, and a count of 0, are refused with the value named.
#[test]
fn grab_saves_frames_and_a_preview_to_aim_a_camera_with() {
    let dir = TempDir::new("grab");
    let out_dir = dir.0.join("frames");
    let out_s = out_dir.to_str().unwrap();
    let grab = |camera: &str, count: &str| {
        run(&[
            "grab",
            "deploy/rigs/demo.toml",
            "--camera",
            camera,
            "--count",
            count,
            "--every",
            "0.5",
            out_s,
        ])
    };
    let o = grab("cam0", "3");
    let text = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}{text}", common::stderr(&o));
    // The last frame's threshold: the preview is of the last frame.
    let threshold: u32 = text
        .lines()
        .filter(|l| l.contains("(frame "))
        .filter_map(|l| l.split("threshold ").nth(1))
        .next_back()
        .and_then(|r| r.split(',').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("no threshold in {text}"));
    assert!(text.contains("cam0-preview.png"), "{text}");
    let files: Vec<String> = [
        "cam0-0001.pgm",
        "cam0-0002.pgm",
        "cam0-0003.pgm",
        "cam0-preview.png",
    ]
    .iter()
    .map(|f| out_dir.join(f).to_str().unwrap().to_string())
    .collect();
    let script = repo_root().join("tests/clients/image_stats.py");
    let mut args = vec![script.to_str().unwrap()];
    args.extend(files.iter().map(String::as_str));
    let o = common::run_program_with_limit(
        &common::python_clients(),
        &args,
        std::time::Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", common::stderr(&o));
    let stats: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for s in &stats[..3] {
        assert_eq!(
            (s["width"].as_u64(), s["height"].as_u64()),
            (Some(320), Some(240)),
            "{s}"
        );
    }
    // Frames of a moving scene half a second apart differ.
    assert_ne!(stats[0]["levels"], stats[2]["levels"]);
    let over = stats[2]["levels"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|v| v.as_u64().unwrap() as u32 >= threshold)
        .count();
    let red = stats[3]["red"].as_u64().unwrap() as usize;
    assert!(over > 50, "{over} pixels over {threshold}");
    assert!(
        red <= over && red * 10 >= over * 6,
        "{red} red of {over} over the threshold"
    );
    // Refusals name the value.
    let o = grab("cam7", "1");
    assert!(!o.status.success());
    let e = common::stderr(&o);
    assert!(e.contains("cam7") && e.contains("cam0"), "{e}");
    let o = grab("cam0", "0");
    assert!(!o.status.success() && common::stderr(&o).contains("--count 0"));
}
