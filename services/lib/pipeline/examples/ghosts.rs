//! Ghost sweep: a rig's synthetic scene rendered, tracked and fused in one process, frame by
//! frame at 30 fps, the same libraries as the services; prints every published pose that is no
//! target (`stereoscope_rig::truth`) and a summary. Deterministic: a ghost found here is found
//! again, and `--dump FRAME` prints that frame's blobs and poses (and the two after it).
//!
//!   cargo run --release -p stereoscope-pipeline --example ghosts -- \
//!       [--seconds 600] [--from 0] [--phase 0] [--rig deploy/rigs/demo.toml] [--dump FRAME]
//!
//! `--phase P` samples the scene at (k + P) / 30 s (0 ≤ P < 1): the live demo's frames fall
//! between the sweep's, and another phase shows the configurations they meet. `--skew-ms S`
//! renders camera c at S·c ms after the set's time, as live cameras' exposures differ.
//!
//! `--ring CAMERAS --markers M` (instead of `--rig`) makes a dense scene (`stereoscope_rig::scenes::dense_ring`): a ring
//! of 640 × 480 cameras round M markers moving through a 2 m volume. Beside the ghosts the
//! summary then gives how many of the markers two cameras saw were reconstructed, and fusion's
//! time per set (the renderer and the workers are not in it).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use stereoscope_pipeline::Fusion;
use stereoscope_pipeline::worker::Worker;
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_rig::Rig;
use stereoscope_rig::truth::Layouts;
use stereoscope_sources::FrameSource;
use stereoscope_sources::synthetic::SyntheticSource;

fn iso(p: [f64; 3], q: [f64; 4]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2])),
    )
}

/// The One Euro filter (defaults, then a few settings) over the helmet's measured poses:
/// position jitter (RMS of the error's frame-to-frame change), lag (the least-squares time
/// shift of the error along the true velocity) and RMS error against the truth, raw and
/// filtered. Runs of consecutive frames only (a gap restarts the filter).
fn one_euro(track: &[(u64, Isometry3<f64>, Isometry3<f64>)]) {
    use stereoscope_bodies::filter::{OneEuroConfig, PoseFilter};
    let one = |min_cutoff_hz: f64, beta: f64| {
        Some(OneEuroConfig {
            min_cutoff_hz,
            beta,
            ..OneEuroConfig::default()
        })
    };
    let settings = [
        ("raw", None),
        ("One Euro 1 Hz, beta 0.5 (the rig's default)", one(1.0, 0.5)),
        ("One Euro 1 Hz, beta 5", one(1.0, 5.0)),
        ("One Euro 1 Hz, beta 20", one(1.0, 20.0)),
        ("One Euro 1 Hz, beta 50", one(1.0, 50.0)),
        ("One Euro 3 Hz, beta 20", one(3.0, 20.0)),
        ("One Euro 5 Hz, beta 50", one(5.0, 50.0)),
    ];
    for (name, cfg) in settings {
        let mut f = cfg.map(PoseFilter::new);
        let (mut jit, mut nj, mut sq, mut n) = (0.0, 0usize, 0.0, 0usize);
        let (mut ev, mut vv, mut rot) = (0.0, 0.0, 0.0);
        let mut last: Option<(u64, nalgebra::Vector3<f64>, nalgebra::Vector3<f64>)> = None;
        for &(t, est, truth) in track {
            if last.is_some_and(|l| t - l.0 > 40_000_000) {
                if let Some(f) = f.as_mut() {
                    f.reset();
                }
                last = None;
            }
            let out = match f.as_mut() {
                Some(f) => f.filter(&est, t),
                None => est,
            };
            let e = out.translation.vector - truth.translation.vector;
            let p = truth.translation.vector;
            sq += e.norm_squared();
            rot += out.rotation.angle_to(&truth.rotation).to_degrees().powi(2);
            n += 1;
            if let Some((t0, e0, p0)) = last {
                jit += (e - e0).norm_squared();
                nj += 1;
                let v = (p - p0) / ((t - t0) as f64 * 1e-9);
                ev += e.dot(&v);
                vv += v.norm_squared();
            }
            last = Some((t, e, p));
        }
        println!(
            "{name}: position RMS {:.2} mm, rotation RMS {:.3} deg, jitter {:.3} mm a frame, lag {:.1} ms over {n} poses",
            (sq / n.max(1) as f64).sqrt() * 1e3,
            (rot / n.max(1) as f64).sqrt(),
            (jit / nj.max(1) as f64).sqrt() * 1e3,
            -ev / vv.max(1e-12) * 1e3,
        );
    }
}

fn arg(args: &[String], name: &str) -> Option<String> {
    let i = args.iter().position(|a| a == name)?;
    args.get(i + 1).cloned()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seconds: f64 = arg(&args, "--seconds").map_or(600.0, |s| s.parse().unwrap());
    let from: f64 = arg(&args, "--from").map_or(0.0, |s| s.parse().unwrap());
    let dump: Option<u64> = arg(&args, "--dump").map(|s| s.parse().unwrap());
    let ring: Option<usize> = arg(&args, "--ring").map(|s| s.parse().unwrap());
    let text = match (arg(&args, "--rig"), ring) {
        (Some(p), _) => std::fs::read_to_string(p).unwrap(),
        (None, Some(cameras)) => {
            let markers = arg(&args, "--markers").map_or(60, |s| s.parse().unwrap());
            stereoscope_rig::scenes::dense_ring(cameras, markers, 30.0, None)
        }
        (None, None) => include_str!("../../../../deploy/rigs/demo.toml").to_string(),
    };
    let rig = Rig::from_toml(&text).unwrap();
    let file = &rig.spec;
    let n = rig.cameras.len();
    let mut sources: Vec<SyntheticSource> = (0..n)
        .map(|i| {
            SyntheticSource::new(
                file,
                &rig.models,
                rig.cameras[i].camera,
                i,
                30.0,
                None,
                None,
            )
            .unwrap()
        })
        .collect();
    let mut workers: Vec<Worker> = (0..n)
        .map(|i| {
            Worker::new(
                rig.worker_settings(i).unwrap(),
                &rig.name,
                &rig.cameras[i].id,
            )
            .unwrap()
        })
        .collect();
    let mut fusion = Fusion::of_rig(&rig);
    let layouts = Layouts::of_rig(file);
    let phase: f64 = arg(&args, "--phase").map_or(0.0, |s| s.parse().unwrap());
    let skew: f64 = arg(&args, "--skew-ms").map_or(0.0, |s| s.parse::<f64>().unwrap() * 1e-3);
    let first = (from * 30.0) as u64;
    let frames = (seconds * 30.0) as u64;
    let (mut ghosts, mut ghost_frames, mut body_sq, mut body_n) = (0, 0, 0.0, 0);
    let mut body_sum = [0.0f64; 3];
    let mut rot_sq = 0.0;
    let mut body_errs: Vec<(f64, u64)> = Vec::new();
    // The helmet's measured and true poses, frame by frame, for the One Euro figures.
    let mut track: Vec<(u64, Isometry3<f64>, Isometry3<f64>)> = Vec::new();
    let mut bufs: Vec<Vec<u8>> = vec![Vec::new(); n];
    let mut cent = vec![(0.0f64, 0.0f64, 0.0f64, 0.0f64); n];
    let (mut visible, mut reconstructed) = (0u64, 0u64);
    // Misses of markers three or more cameras saw, and of those only two saw.
    let mut missed_by = [0u64; 2];
    let mut fuse_us: Vec<f64> = Vec::new();
    for k in first..first + frames {
        let t = (k as f64 + phase) / 30.0;
        let ts = 1_000_000_000_000 + (t * 1e9) as u64;
        let dumped = dump.is_some_and(|d| d <= k && k < d + 3);
        let mut set = Vec::new();
        let mut truth = Vec::new();
        let mut seen_by: Vec<u32> = Vec::new();
        for c in 0..n {
            let (w, h) = sources[c].size();
            bufs[c].resize((w * h) as usize, 0);
            sources[c]
                .read(k, t + c as f64 * skew, &mut bufs[c])
                .unwrap();
            let this_truth = sources[c].truth().unwrap();
            let mut hd = FrameHeader::new(&rig.cameras[c].id, PixelFormat::Gray8, w, h).unwrap();
            hd.sequence = k;
            hd.timestamp_ns = ts;
            let obs = workers[c].process_frame(&hd, &bufs[c]).unwrap();
            if dumped {
                println!("frame {k} camera {c} blobs (track, status, x, y, area, merged):");
                for b in &obs.blobs {
                    println!(
                        "    {} {:?} {:.2} {:.2} {} {}",
                        b.track_id, b.status, b.x_px, b.y_px, b.area_px, b.merged
                    );
                }
                let centroids: Vec<_> = this_truth.iter().map(|t| t.centroid_px).collect();
                println!("  truth centroids {centroids:?}");
            }
            // Each isolated body marker's image against its true centre's projection.
            for (_, _, m) in layouts.markers(&this_truth) {
                let cam = &rig.cameras[c].camera;
                let Some(px) = cam.project(&m) else { continue };
                let near: Vec<_> = obs
                    .blobs
                    .iter()
                    .filter(|b| ((b.x_px - px.x).powi(2) + (b.y_px - px.y).powi(2)).sqrt() < 4.0)
                    .collect();
                if let [b] = near[..]
                    && !b.merged
                {
                    cent[c].0 += (b.x_px - px.x).powi(2);
                    cent[c].1 += (b.y_px - px.y).powi(2);
                    cent[c].2 += b.y_px - px.y;
                    cent[c].3 += 1.0;
                }
            }
            seen_by.resize(this_truth.len(), 0);
            for (k, t) in this_truth.iter().enumerate() {
                seen_by[k] += u32::from(t.visible);
            }
            if c == 0 {
                truth = this_truth;
            }
            set.push((c, obs));
        }
        let started = std::time::Instant::now();
        let (poses, found) = fusion.fuse(&set, ts);
        fuse_us.push(started.elapsed().as_secs_f64() * 1e6);
        // Loose markers two cameras saw, and of those the ones a pose is near.
        for (tt, &views) in truth.iter().zip(&seen_by) {
            // After a second: each marker's first frames are tentative by design.
            if tt.body.is_some() || views < 2 || k < first + 30 {
                continue;
            }
            visible += 1;
            let two = usize::from(views == 2);
            let at = nalgebra::Point3::from(tt.position_m);
            if poses.iter().any(|p| {
                (nalgebra::Point3::from(p.position_m) - at).norm()
                    < stereoscope_rig::truth::GHOST_DISTANCE_M
            }) {
                reconstructed += 1;
            } else {
                missed_by[two] += 1;
            }
        }
        if dumped {
            for p in &poses {
                println!(
                    "  pose {} {:.3?} {:?} from {:?}",
                    p.object_id,
                    p.position_m,
                    p.body,
                    fusion.fuser.pixels_of(p.object_id)
                );
            }
        }
        for tt in &truth {
            let Some(name) = &tt.body else { continue };
            if let Some(b) = found.iter().find(|b| &b.name == name && !b.held) {
                let d2 = (0..3)
                    .map(|i| (b.position_m[i] - tt.position_m[i]).powi(2))
                    .sum::<f64>();
                body_sq += d2;
                body_errs.push((d2.sqrt() * 1e3, k));
                if let Some(q) = tt.orientation_xyzw {
                    let dot: f64 = (0..4).map(|i| b.orientation_xyzw[i] * q[i]).sum();
                    rot_sq += (2.0 * dot.abs().min(1.0).acos()).to_degrees().powi(2);
                }
                if let Some(q) = tt.orientation_xyzw {
                    track.push((
                        ts,
                        iso(b.position_m, b.orientation_xyzw),
                        iso(tt.position_m, q),
                    ));
                }
                for (i, sum) in body_sum.iter_mut().enumerate() {
                    *sum += b.position_m[i] - tt.position_m[i];
                }
                body_n += 1;
            }
        }
        let bad = layouts.ghosts(&poses, &truth);
        if !bad.is_empty() {
            ghosts += bad.len();
            ghost_frames += 1;
            let markers = layouts.markers(&truth);
            for p in &bad {
                let at = nalgebra::Point3::from(p.position_m);
                let nearest = truth
                    .iter()
                    .map(|tt| nalgebra::Point3::from(tt.position_m))
                    .chain(markers.iter().map(|m| m.2))
                    .map(|q| (q - at).norm())
                    .fold(f64::INFINITY, f64::min);
                println!(
                    "frame {k} t {t:.2} s: object {} at {:.3?} {:?}, residual {:.2} px, {} views, nearest truth {:.0} mm",
                    p.object_id,
                    p.position_m,
                    p.body,
                    p.residual_px,
                    fusion.fuser.pixels_of(p.object_id).len(),
                    nearest * 1e3
                );
            }
        }
    }
    for (c, (sx, sy, mx, k)) in cent.iter().enumerate() {
        println!(
            "camera {c}: isolated body markers' centroid error RMS x {:.3} y {:.3} px, mean y {:.3} px, {k} images",
            (sx / k).sqrt(),
            (sy / k).sqrt(),
            mx / k
        );
    }
    one_euro(&track);
    fuse_us.sort_by(f64::total_cmp);
    let q = |p: f64| fuse_us[((fuse_us.len() - 1) as f64 * p) as usize];
    println!(
        "loose markers two or more cameras saw (after the first second): {visible}, of them with a pose within {} mm: {reconstructed} ({:.3} %; of the misses {} seen by three cameras or more, {} by two); fusion per set: p50 {:.0} µs, p99 {:.0} µs, worst {:.0} µs ({} cameras, {} sets)",
        stereoscope_rig::truth::GHOST_DISTANCE_M * 1e3,
        100.0 * reconstructed as f64 / visible.max(1) as f64,
        missed_by[0],
        missed_by[1],
        q(0.5),
        q(0.99),
        q(1.0),
        n,
        fuse_us.len()
    );
    body_errs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let pct = |q: f64| {
        body_errs
            .get(((body_errs.len() as f64 - 1.0) * q) as usize)
            .map_or(f64::NAN, |e| e.0)
    };
    println!(
        "bodies' position error p50 {:.2} p90 {:.2} p99 {:.2} max {:.2} mm (frame {:?})",
        pct(0.5),
        pct(0.9),
        pct(0.99),
        pct(1.0),
        body_errs.last().map(|e| e.1)
    );
    println!(
        "{frames} frames from {from} s: {ghost_frames} frames with {ghosts} ghost poses; bodies' position RMS {:.2} mm (mean error {:.2?} mm), rotation RMS {:.3}° over {body_n} sightings; fusion: {} blobs out of line by area, {} blobs only one camera saw (no point), {} cut by an edge, {} hiding another object",
        (body_sq / body_n.max(1) as f64).sqrt() * 1e3,
        body_sum.map(|v| v / body_n.max(1) as f64 * 1e3),
        (rot_sq / body_n.max(1) as f64).sqrt(),
        fusion.fuser.area_mismatch,
        fusion.fuser.single_view_unmatched,
        fusion.fuser.clipped,
        fusion.fuser.hiding_blobs,
    );
}
