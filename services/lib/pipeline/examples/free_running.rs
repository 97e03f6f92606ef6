//! Free-running cameras against synchronised ones (docs/performance.md, "Free-running
//! cameras"): two 640 × 480 cameras 2.8 m from a marker (a 1 cm ball) going round a 30 cm
//! circle at 1 and 3 m/s (3.3 and 30 m/s² towards its centre: a swung hand's), rendered in
//! process; camera 1 exposes at a random phase of the
//! frame period after camera 0 (a new phase each run, seeded), its frames fused at camera 0's
//! instant. Prints, per speed, the marker's position RMS from the truth: synchronised, free-
//! running with fusion's interpolation (the default) and fused as seen.
//!
//!   cargo run --release -p stereoscope-pipeline --example free_running -- [--runs N] [--seconds S] [--fps F]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use stereoscope_pipeline::Fusion;
use stereoscope_pipeline::worker::Worker;
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_rig::Rig;
use stereoscope_sources::FrameSource;
use stereoscope_sources::synthetic::SyntheticSource;

fn rig(fps: f64, speed_m_per_s: f64) -> String {
    // Round a 30 cm circle: the period is its circumference over the speed.
    let period = 2.0 * std::f64::consts::PI * 0.3 / speed_m_per_s;
    let camera = |id: &str, x: f64| {
        format!(
            "[[camera]]\nid = \"{id}\"\nimage_size = [640, 480]\nfocal_length_mm = 12.5\n\
             pixel_pitch_um = [10.75, 12.5]\n\
             pose = {{ position = [{x}, 0.0, 280.0], look_at = [{x}, 0.0, 0.0], up = [0.0, 1.0, 0.0] }}\n\
             source = {{ kind = \"synthetic\", fps = {fps} }}\n\
             moments = {{ threshold = \"auto\", max_objects = 8 }}\n\n"
        )
    };
    format!(
        "name = \"free\"\nunits = \"cm\"\n\n{}{}[fusion]\nmax_skew_ms = {}\n\n\
         [synthetic]\nseed = 2\nlight = \"ring\"\n\n[[synthetic.target]]\nshape = \"sphere\"\n\
         radius = 0.5\nmotion = {{ kind = \"circle\", centre = [0.0, 0.0, 60.0], radius = 30.0, period_s = {period} }}\n",
        camera("cam0", -20.0),
        camera("cam1", 20.0),
        500.0 / fps
    )
}

/// The marker's position RMS (m) over `frames` frames, camera 1 `offset_s` after camera 0.
fn rms(text: &str, fps: f64, offset_s: f64, interpolate: bool, frames: u64) -> f64 {
    let rig = Rig::from_toml(text).unwrap();
    let mut sources: Vec<SyntheticSource> = (0..2)
        .map(|i| {
            SyntheticSource::new(
                &rig.spec,
                &rig.models,
                rig.cameras[i].camera,
                i,
                fps,
                None,
                None,
            )
            .unwrap()
        })
        .collect();
    let mut workers: Vec<Worker> = (0..2)
        .map(|i| Worker::new(rig.worker_settings(i).unwrap(), "free", &rig.cameras[i].id).unwrap())
        .collect();
    let mut fusion = Fusion::of_rig(&rig);
    fusion.interpolate = interpolate;
    let mut sq = Vec::new();
    for k in 0..frames {
        let t0 = 100.0 + k as f64 / fps;
        let mut set = Vec::new();
        let mut truth = [0.0; 3];
        for c in 0..2 {
            let t = t0 + if c == 1 { offset_s } else { 0.0 };
            let (w, h) = sources[c].size();
            let mut buf = vec![0u8; (w * h) as usize];
            sources[c].read(k, t, &mut buf).unwrap();
            if c == 0 {
                truth = sources[c].truth().unwrap()[0].position_m;
            }
            let mut hd = FrameHeader::new(&rig.cameras[c].id, PixelFormat::Gray8, w, h).unwrap();
            hd.sequence = k;
            hd.timestamp_ns = (t * 1e9) as u64;
            set.push((c, workers[c].process_frame(&hd, &buf).unwrap()));
        }
        let (poses, _) = fusion.fuse(&set, (t0 * 1e9) as u64);
        if k < 10 {
            continue;
        }
        if let Some(d) = poses
            .iter()
            .filter(|p| p.cameras.len() == 2)
            .map(|p| {
                (0..3)
                    .map(|i| (p.position_m[i] - truth[i]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .reduce(f64::min)
        {
            sq.push(d * d);
        }
    }
    (sq.iter().sum::<f64>() / sq.len().max(1) as f64).sqrt()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let get = |k: &str, d: f64| {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let runs = get("--runs", 5.0) as usize;
    let seconds = get("--seconds", 5.0);
    let fps = get("--fps", 120.0);
    let frames = (seconds * fps) as u64;
    let mut random = stereoscope_numeric::random::SplitMix64::new(7);
    println!(
        "{frames} frames at {fps} fps, {runs} runs at random phases; marker RMS from the truth, mm"
    );
    println!(
        "| speed | synchronised | free-running, interpolated: median (worst) | ratio to synchronised: median (worst) | free-running, as seen: median |"
    );
    println!("|---|---|---|---|---|");
    for speed in [1.0, 3.0] {
        let text = rig(fps, speed);
        let synced = rms(&text, fps, 0.0, true, frames);
        let mut moved = Vec::new();
        let mut seen = Vec::new();
        for _ in 0..runs {
            let offset = random.uniform() / fps;
            moved.push(rms(&text, fps, offset, true, frames));
            seen.push(rms(&text, fps, offset, false, frames));
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let worst = moved.iter().copied().fold(0.0, f64::max);
        let m = median(&mut moved);
        println!(
            "| {speed} m/s | {:.2} | {:.2} ({:.2}) | {:.2}× ({:.2}×) | {:.2} |",
            synced * 1e3,
            m * 1e3,
            worst * 1e3,
            m / synced,
            worst / synced,
            median(&mut seen) * 1e3
        );
    }
}
