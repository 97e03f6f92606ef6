//! Frame → shared memory, per pixel format (docs/performance.md, "Camera frames into shared
//! memory"): the one pass each camera frame takes from the driver's or Aravis's buffer into
//! the frame the moment worker reads — GenICam's one `memcpy` of the buffer (Mono8, Mono16),
//! V4L2's row copy (GREY, Y16: rows may be padded), the luma of YUYV, the decode of MJPEG —
//! timed on a motion-capture frame (dark, noisy, a few bright markers) at three sizes.
//!
//!   cargo bench -p stereoscope-sources --bench frame_copy -- [--rounds N] [--frames N]
//!
//! Each round times `frames` conversions of the same buffer into the same output and takes
//! their median; the table gives the median round and the worst round.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;
use std::time::Instant;
use stereoscope_numeric::random::SplitMix64 as Rng;
use stereoscope_sources::v4l2::{Wire, convert, wire_of};

/// A grey motion-capture frame: background 20, noise σ 2, twelve bright discs.
fn scene(w: usize, h: usize) -> Vec<u8> {
    let mut rng = Rng::new(7);
    let mut img: Vec<u8> = (0..w * h)
        .map(|_| (20.0 + 2.0 * rng.normal()).clamp(0.0, 255.0) as u8)
        .collect();
    for _ in 0..12 {
        let (cx, cy) = (rng.uniform() * w as f64, rng.uniform() * h as f64);
        let r = 3.0 + rng.uniform() * 6.0;
        for y in (cy - r).max(0.0) as usize..((cy + r) as usize).min(h) {
            for x in (cx - r).max(0.0) as usize..((cx + r) as usize).min(w) {
                if (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) <= r * r {
                    img[y * w + x] = 200;
                }
            }
        }
    }
    img
}

/// The scene as the camera sends it in `wire` (bytes per row: the second value).
fn on_the_wire(wire: Wire, grey: &[u8], w: usize, h: usize) -> (Vec<u8>, usize) {
    match wire {
        Wire::Grey => (grey.to_vec(), w),
        Wire::Y16 => (
            grey.iter()
                .flat_map(|&v| (u16::from(v) << 8).to_le_bytes())
                .collect(),
            2 * w,
        ),
        Wire::Yuyv => (grey.iter().flat_map(|&v| [v, 128]).collect(), 2 * w),
        Wire::Mjpg => {
            let mut jpeg = Vec::new();
            jpeg_encoder::Encoder::new(&mut jpeg, 85)
                .encode(grey, w as u16, h as u16, jpeg_encoder::ColorType::Luma)
                .unwrap();
            (jpeg, 0)
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str, default: usize| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let rounds = arg("--rounds", 5).max(1);
    let frames = arg("--frames", 200).max(1);
    println!(
        "frame → shared memory, µs per frame: median round (worst round) of {rounds} rounds × {frames} frames"
    );
    println!(
        "{:<26} {:>20} {:>20} {:>20}",
        "format", "640×480", "1280×720", "1920×1080"
    );
    let sizes = [(640usize, 480usize), (1280, 720), (1920, 1080)];
    let rows: [(&str, Option<&str>, usize); 6] = [
        ("GenICam Mono8 (memcpy)", None, 1),
        ("V4L2 GREY (row copy)", Some("GREY"), 1),
        ("GenICam Mono16 (memcpy)", None, 2),
        ("V4L2 Y16 (row copy)", Some("Y16 "), 2),
        ("V4L2 YUYV (luma)", Some("YUYV"), 1),
        ("V4L2 MJPG (decode, q 85)", Some("MJPG"), 1),
    ];
    for (name, code, bytes_per_px) in rows {
        let mut cells = Vec::new();
        for (w, h) in sizes {
            let grey = scene(w, h);
            let mut out = vec![0u8; w * h * bytes_per_px];
            let (data, stride) = match code {
                Some(c) => on_the_wire(wire_of(c).unwrap(), &grey, w, h),
                None => (vec![7u8; w * h * bytes_per_px], 0),
            };
            let wire = code.and_then(wire_of);
            // Checked once: the conversion gives the scene back.
            if let Some(wire) = wire {
                convert(wire, &data, w, h, stride, &mut out).unwrap();
                if wire != Wire::Mjpg {
                    let back: Vec<u8> = if bytes_per_px == 2 {
                        out.chunks_exact(2).map(|p| p[1]).collect()
                    } else {
                        out.clone()
                    };
                    assert_eq!(back, grey, "{name} at {w}×{h}");
                }
            }
            let mut per_round = Vec::new();
            for _ in 0..rounds {
                let mut times = Vec::with_capacity(frames);
                for _ in 0..frames {
                    let t = Instant::now();
                    match wire {
                        Some(wire) => {
                            convert(wire, black_box(&data), w, h, stride, &mut out).unwrap()
                        }
                        None => out.copy_from_slice(black_box(&data)),
                    }
                    black_box(&out);
                    times.push(t.elapsed().as_secs_f64() * 1e6);
                }
                per_round.push(median(times));
            }
            let worst = per_round.iter().copied().fold(0.0, f64::max);
            cells.push(format!("{:.1} ({:.1})", median(per_round), worst));
        }
        println!(
            "{:<26} {:>20} {:>20} {:>20}",
            name, cells[0], cells[1], cells[2]
        );
    }
}
