//! Blob-extraction benchmark: full-frame and windowed, single thread and all cores, at
//! 640×480, 1920×1080 and 3840×2160 with 4, 50 and 500 blobs.
//!
//! `cargo bench -p stereoscope-vision --bench moments -- [--quick] [--frames-dir DIR] [--json FILE]`
//!
//! `--frames-dir` writes each scene as a PGM so that `compare-opencv.sh` can time OpenCV on the
//! very same frames in the same run; `--json` writes the timings for it to merge.
//! Times are the median of timed batches (each ≥ 20 ms), in milliseconds per frame.

use std::hint::black_box;
use std::io::Write;
use std::time::{Duration, Instant};
use stereoscope_vision::histogram::Histogram;
use stereoscope_vision::raster::random_scene;
use stereoscope_vision::{ExtractConfig, Extractor, GrayImage, Tracker, TrackerConfig};

const THRESHOLD: u32 = 128;

struct Options {
    quick: bool,
    frames_dir: Option<std::path::PathBuf>,
    json: Option<std::path::PathBuf>,
}

fn parse_args() -> Options {
    let mut o = Options {
        quick: false,
        frames_dir: None,
        json: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--quick" => o.quick = true,
            "--frames-dir" => o.frames_dir = args.next().map(Into::into),
            "--json" => o.json = args.next().map(Into::into),
            // cargo bench passes --bench; ignore anything else.
            _ => {}
        }
    }
    o
}

/// Median milliseconds per call over `batches` batches of at least `min_batch` each.
fn time_ms(batches: usize, min_batch: Duration, mut f: impl FnMut()) -> f64 {
    // Warm up and size a batch.
    let start = Instant::now();
    let mut n = 0u64;
    while start.elapsed() < min_batch / 4 || n < 3 {
        f();
        n += 1;
    }
    let per_call = start.elapsed().as_secs_f64() / n as f64;
    let iters = ((min_batch.as_secs_f64() / per_call).ceil() as u64).max(3);
    let mut samples: Vec<f64> = (0..batches)
        .map(|_| {
            let t = Instant::now();
            for _ in 0..iters {
                f();
            }
            t.elapsed().as_secs_f64() * 1e3 / iters as f64
        })
        .collect();
    samples.sort_by(f64::total_cmp);
    samples[samples.len() / 2]
}

fn write_pgm(path: &std::path::Path, img: &GrayImage<u8>) -> std::io::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(f, "P5\n{} {}\n255\n", img.width(), img.height())?;
    f.write_all(img.as_slice())?;
    f.flush()
}

/// Windowed tracking of `n` markers in steady state, and a full-frame pass of the very same
/// frame, single thread: `(windowed ms, full ms)` (medians), once both found the same `n`
/// blobs (the tracker's positions within 0.01 px of the full pass's centroids); `None` if the
/// scene could not be tracked.
fn windowed_ms(
    w: u32,
    h: u32,
    n: usize,
    batches: usize,
    min_batch: Duration,
) -> Option<(f64, f64)> {
    let (img, placed) = random_scene(w, h, n, (5.0, 8.0), 2.0, 4242).ok()?;
    let mut tr = Tracker::new(
        TrackerConfig {
            max_objects: n,
            search_every_frames: u32::MAX,
            ..Default::default()
        },
        ExtractConfig {
            threads: 1,
            ..Default::default()
        },
    )
    .ok()?;
    for _ in 0..3 {
        tr.step(img.view(), THRESHOLD).ok()?;
    }
    let step = tr.step(img.view(), THRESHOLD).ok()?;
    if step.full_frame || step.tracked != placed.len() {
        return None;
    }
    let mut full = Extractor::new(ExtractConfig {
        threads: 1,
        max_blobs: 4096,
        ..Default::default()
    });
    let blobs: Vec<(f64, f64)> = full
        .extract(img.view(), THRESHOLD, &[])
        .ok()?
        .iter()
        .map(|b| b.best_centroid_px())
        .collect();
    let same = blobs.len() == tr.tracks().len()
        && tr.tracks().iter().all(|t| {
            blobs
                .iter()
                .any(|&(x, y)| (x - t.x_px).abs() < 0.01 && (y - t.y_px).abs() < 0.01)
        });
    if !same {
        eprintln!("error: windowed and full passes found different blobs in the {w}×{h} frame");
        std::process::exit(1);
    }
    let windowed = time_ms(batches, min_batch, || {
        black_box(
            tr.step(img.view(), THRESHOLD)
                .map(|s| s.tracked)
                .unwrap_or(0),
        );
    });
    let full_ms = time_ms(batches, min_batch, || {
        black_box(
            full.extract(img.view(), THRESHOLD, &[])
                .map(|b| b.len())
                .unwrap_or(0),
        );
    });
    Some((windowed, full_ms))
}

fn main() {
    let opts = parse_args();
    let (batches, min_batch) = if opts.quick {
        (3, Duration::from_millis(10))
    } else {
        (11, Duration::from_millis(25))
    };
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let sizes = [(640u32, 480u32), (1920, 1080), (3840, 2160)];
    let counts = [4usize, 50, 500];
    println!(
        "blob extraction, threshold {THRESHOLD}, noise σ=2, {cores} cores; ms per frame (median of {batches} batches)"
    );
    println!(
        "{:>10} {:>5} {:>7} | {:>9} {:>10} {:>10} {:>10} {:>12}",
        "frame", "blobs", "found", "read", "full 1T", "full allT", "window 1T", "full/window"
    );
    let mut rows = Vec::new();
    if let Some(dir) = &opts.frames_dir
        && let Err(e) = std::fs::create_dir_all(dir)
    {
        eprintln!("error: cannot create {}: {e}", dir.display());
        std::process::exit(1);
    }
    for &(w, h) in &sizes {
        for &count in &counts {
            let scale = ((w as f64 * h as f64) / (count as f64 * 900.0))
                .sqrt()
                .clamp(0.3, 1.5);
            let (img, _placed) = match random_scene(
                w,
                h,
                count,
                (3.0 * scale, 12.0 * scale),
                2.0,
                42 + count as u64,
            ) {
                Ok(s) => s,
                Err(e) => {
                    eprintln!("error: scene {w}×{h}: {e}");
                    std::process::exit(1);
                }
            };
            let name = format!("{w}x{h}_{count}");
            if let Some(dir) = &opts.frames_dir
                && let Err(e) = write_pgm(&dir.join(format!("{name}.pgm")), &img)
            {
                eprintln!("error: writing frame {name}: {e}");
                std::process::exit(1);
            }
            // The floor: reading every byte once.
            let read = time_ms(batches, min_batch, || {
                black_box(img.as_slice().iter().fold(0u8, |m, &p| m.max(p)));
            });
            let mut ex1 = Extractor::new(ExtractConfig {
                threads: 1,
                max_blobs: 4096,
                ..Default::default()
            });
            let found = ex1
                .extract(img.view(), THRESHOLD, &[])
                .map(|b| b.len())
                .unwrap_or(0);
            let full1 = time_ms(batches, min_batch, || {
                black_box(
                    ex1.extract(img.view(), THRESHOLD, &[])
                        .map(|b| b.len())
                        .unwrap_or(0),
                );
            });
            let mut exn = Extractor::new(ExtractConfig {
                threads: 0,
                max_blobs: 4096,
                ..Default::default()
            });
            let fulln = time_ms(batches, min_batch, || {
                black_box(
                    exn.extract(img.view(), THRESHOLD, &[])
                        .map(|b| b.len())
                        .unwrap_or(0),
                );
            });
            // Windowed tracking of as many markers as the row has blobs (radius 5–8 px, the size
            // of a motion-capture marker in these frames; 4, 50 and the 512 a worker tracks at
            // most, as 500) on the same background, in steady state: each found in its window
            // every frame. Windows follow Eq. 5.1 with the 30 px floor. Its ratio is to a full
            // pass of its own frame (the same markers), not of this row's ellipses.
            let window = windowed_ms(w, h, count, batches, min_batch);
            // The moment worker's threshold histogram: every k-th row, at least 240 rows (its
            // rule, `stereoscope_moments::THRESHOLD_ROWS`; 270 until 2026-12-06). OpenCV's
            // `calcHist` counts the same rows in `opencv_bench.py`, which checks that the
            // counts are equal.
            let step = (h / 240).max(1);
            let counts = Histogram::of_rows(&img.view(), step).counts().to_vec();
            let hist = time_ms(batches, min_batch, || {
                black_box(Histogram::of_rows(&img.view(), step).total());
            });
            let fmt = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.4}"));
            println!(
                "{:>10} {:>5} {:>7} | {:>9.4} {:>10.4} {:>10.4} {:>10} {:>12}",
                format!("{w}×{h}"),
                count,
                found,
                read,
                full1,
                fulln,
                fmt(window.map(|v| v.0)),
                window.map_or("-".to_string(), |(win, full)| format!("{:.0}×", full / win)),
            );
            rows.push(format!(
                "{{\"frame\":\"{name}\",\"width\":{w},\"height\":{h},\"blobs\":{count},\"found\":{found},\"read_ms\":{read},\"full_1t_ms\":{full1},\"full_all_ms\":{fulln},\"window_1t_ms\":{},\"window_frame_full_1t_ms\":{},\"cores\":{cores},\"histogram_step\":{step},\"histogram_ms\":{hist},\"histogram_counts\":{counts:?}}}",
                window.map_or("null".to_string(), |v| v.0.to_string()),
                window.map_or("null".to_string(), |v| v.1.to_string())
            ));
        }
    }
    if let Some(path) = &opts.json {
        let body = format!("[\n{}\n]\n", rows.join(",\n"));
        if let Err(e) = std::fs::write(path, body) {
            eprintln!("error: writing {}: {e}", path.display());
            std::process::exit(1);
        }
    }
}
