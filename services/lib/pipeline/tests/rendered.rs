//! Fusion on rendered frames: the demo rig's synthetic cameras render the scene, the moment
//! workers' per-frame processing tracks it, fusion recovers positions and headings; errors
//! against the renderer's truth.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use stereoscope_pipeline::Fusion;
use stereoscope_pipeline::worker::Worker;
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_rig::Rig;
use stereoscope_sources::FrameSource;
use stereoscope_sources::synthetic::SyntheticSource;

const RIG: &str = include_str!("../../../../deploy/rigs/demo.toml");

/// Per frame: each loose target's position error and heading error; and the helmet body's
/// position and rotation errors (degrees) where it was measured.
type Errors = (Vec<(f64, Option<f64>)>, Vec<(f64, f64)>);

fn errors(rig_text: &str, frames: u64) -> Errors {
    sweep(rig_text, 1000.0, frames).0
}

/// `frames` frames of the scene at 30 fps from `from_s` seconds: the errors (the first five
/// frames, finding the targets, not scored), and the ghosts published
/// (`stereoscope_rig::truth`), every frame counted.
fn sweep(rig_text: &str, from_s: f64, frames: u64) -> (Errors, Vec<String>) {
    let rig = Rig::from_toml(rig_text).unwrap();
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
            let s = rig.worker_settings(i).unwrap();
            Worker::new(s, "demo", &rig.cameras[i].id).unwrap()
        })
        .collect();
    let mut fusion = Fusion::of_rig(&rig);
    let layouts = stereoscope_rig::truth::Layouts::of_rig(file);
    let mut ghosts = Vec::new();
    let mut out = Vec::new();
    let mut body_out = Vec::new();
    let first = (from_s * 30.0).round() as u64;
    for k in 0..frames {
        let t = (first + k) as f64 / 30.0;
        let ts = (t * 1e9) as u64;
        let mut set = Vec::new();
        let mut truth = Vec::new();
        for c in 0..n {
            let (w, h) = sources[c].size();
            let mut buf = vec![0u8; (w * h) as usize];
            sources[c].read(first + k, t, &mut buf).unwrap();
            if c == 0 {
                truth = sources[c].truth().unwrap();
            }
            let mut hd = FrameHeader::new(&rig.cameras[c].id, PixelFormat::Gray8, w, h).unwrap();
            hd.sequence = k;
            hd.timestamp_ns = ts;
            set.push((c, workers[c].process_frame(&hd, &buf).unwrap()));
        }
        let (poses, found) = fusion.fuse(&set, ts);
        for g in layouts.ghosts(&poses, &truth) {
            ghosts.push(format!(
                "{t:.2} s: object {} at {:.3?} {:?}",
                g.object_id, g.position_m, g.body
            ));
        }
        if k < 5 {
            continue;
        }
        for tt in truth.iter().filter(|t| t.body.is_some()) {
            let (Some(b), Some(q)) = (found.iter().find(|b| !b.held), tt.orientation_xyzw) else {
                continue;
            };
            let d = (0..3)
                .map(|i| (b.position_m[i] - tt.position_m[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            let dot: f64 = (0..4).map(|i| b.orientation_xyzw[i] * q[i]).sum();
            body_out.push((d, (2.0 * dot.abs().min(1.0).acos()).to_degrees()));
        }
        // Loose targets: the helmet's markers are scored as its body.
        let poses: Vec<_> = poses.into_iter().filter(|p| p.body.is_none()).collect();
        for tt in truth.iter().filter(|t| t.body.is_none()) {
            let best = poses
                .iter()
                .map(|p| {
                    let d = (0..3)
                        .map(|i| (p.position_m[i] - tt.position_m[i]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    (d, p)
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((d, p)) = best {
                let herr = if tt.has_axis {
                    p.heading_deg.map(|h| {
                        stereoscope_numeric::angle::wrap_half_turn_deg(h - tt.heading_deg).abs()
                    })
                } else {
                    None
                };
                out.push((d, herr));
            }
        }
    }
    ((out, body_out), ghosts)
}

/// Where the demo scene's markers meet — two of the helmet's markers on one image row in both
/// views, merged in one view or in both, a marker's image swallowed by a double ball's — no
/// ghost is published, from the first frame on. The windows had 2, 8, 9 and 21 ghost poses before
/// fusion knew its followed objects' blobs, compared areas across views and kept a merged
/// blob merged (the in-process sweep over ten minutes, `examples/ghosts.rs`: 147 ghosts before,
/// none after).
#[test]
fn no_ghost_where_the_demo_scene_markers_meet() {
    for (from_s, seconds) in [(32.0, 4.0), (142.0, 4.0), (213.0, 4.0), (326.0, 5.0)] {
        let (_, ghosts) = sweep(RIG, from_s, (seconds * 30.0) as u64);
        assert!(ghosts.is_empty(), "from {from_s} s: {ghosts:#?}");
    }
}

#[test]
fn demo_scene_positions_within_millimetres() {
    // Five seconds of the demo scene; the first five frames (finding the targets) are skipped.
    let (e, body) = errors(RIG, 150);
    // The helmet: found in most frames, never turned over (a three-marker fit of the wrong
    // markers was 120–180° off before it was checked against the previous pose).
    assert!(
        body.len() > 120,
        "helmet measured in {} of 145 frames",
        body.len()
    );
    let worst_turn = body.iter().map(|b| b.1).fold(0.0, f64::max);
    assert!(worst_turn < 15.0, "helmet rotation off by {worst_turn:.1}°");
    let brms = (body.iter().map(|b| b.0 * b.0).sum::<f64>() / body.len() as f64).sqrt();
    let rrms = (body.iter().map(|b| b.1 * b.1).sum::<f64>() / body.len() as f64).sqrt();
    assert!(rrms < 1.2, "helmet rotation RMS {rrms:.2}°");
    eprintln!(
        "helmet: {} frames, position RMS {:.2} mm, rotation RMS {rrms:.2}°",
        body.len(),
        brms * 1e3
    );
    // Refined on the pixels: 2.9 mm and 0.75° (Kabsch on the triangulated markers alone gave
    // 4.0 mm and 2.8° on these frames).
    assert!(brms < 0.004, "helmet position RMS {:.2} mm", brms * 1000.0);
    assert_eq!(e.len(), 145 * 3, "every target gets a pose in every frame");
    let rms = (e.iter().map(|x| x.0 * x.0).sum::<f64>() / e.len() as f64).sqrt();
    let worst = e.iter().map(|x| x.0).fold(0.0, f64::max);
    // Depth noise of a 20 cm baseline at 2–2.6 m with 320×240 cameras is a few millimetres.
    assert!(rms < 0.006, "position RMS {:.2} mm", rms * 1000.0);
    assert!(
        worst < 0.03,
        "worst position error {:.1} mm",
        worst * 1000.0
    );
    let h: Vec<f64> = e.iter().filter_map(|x| x.1).collect();
    assert!(
        h.len() >= 2 * 140,
        "headings for the two double balls: {}",
        h.len()
    );
    let hrms = (h.iter().map(|x| x * x).sum::<f64>() / h.len() as f64).sqrt();
    assert!(hrms < 1.0, "heading RMS {hrms:.2}°");
}

/// The loose targets' position RMS (m) over `frames` frames of the demo scene at 30 fps from
/// 20 s, camera 1 exposing `offset_s` after camera 0 (free-running cameras), its frames fused
/// with camera 0's at camera 0's instant; `interpolate` as `Fusion::interpolate`.
fn free_running_rms(offset_s: f64, interpolate: bool, frames: u64) -> f64 {
    let rig = Rig::from_toml(RIG).unwrap();
    let n = rig.cameras.len();
    let mut sources: Vec<SyntheticSource> = (0..n)
        .map(|i| {
            SyntheticSource::new(
                &rig.spec,
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
        .map(|i| Worker::new(rig.worker_settings(i).unwrap(), "demo", &rig.cameras[i].id).unwrap())
        .collect();
    let mut fusion = Fusion::of_rig(&rig);
    fusion.interpolate = interpolate;
    let mut sq = Vec::new();
    for k in 0..frames {
        let t0 = 20.0 + k as f64 / 30.0;
        let ts = (t0 * 1e9) as u64;
        let mut set = Vec::new();
        let mut truth = Vec::new();
        for c in 0..n {
            let t = t0 + if c == 1 { offset_s } else { 0.0 };
            let (w, h) = sources[c].size();
            let mut buf = vec![0u8; (w * h) as usize];
            sources[c].read(600 + k, t, &mut buf).unwrap();
            if c == 0 {
                truth = sources[c].truth().unwrap();
            }
            let mut hd = FrameHeader::new(&rig.cameras[c].id, PixelFormat::Gray8, w, h).unwrap();
            hd.sequence = k;
            hd.timestamp_ns = (t * 1e9) as u64;
            set.push((c, workers[c].process_frame(&hd, &buf).unwrap()));
        }
        let (poses, _) = fusion.fuse(&set, ts);
        if k < 5 {
            continue;
        }
        let loose: Vec<_> = poses.iter().filter(|p| p.body.is_none()).collect();
        for tt in truth.iter().filter(|t| t.body.is_none()) {
            let d = loose
                .iter()
                .map(|p| {
                    (0..3)
                        .map(|i| (p.position_m[i] - tt.position_m[i]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(f64::INFINITY, f64::min);
            if d.is_finite() {
                sq.push(d * d);
            }
        }
    }
    (sq.iter().sum::<f64>() / sq.len().max(1) as f64).sqrt()
}

/// Free-running cameras (issue 43): camera 1 exposing half a frame (16.7 ms) after camera 0.
/// Each of its blobs moved back to camera 0's instant along its track, the targets come out
/// within 1.5× the synchronised rig's error; fused as they were seen, they are further off.
#[test]
fn free_running_cameras_are_fused_at_one_instant() {
    let frames = 120;
    let synced = free_running_rms(0.0, true, frames);
    let moved = free_running_rms(1.0 / 60.0, true, frames);
    let as_seen = free_running_rms(1.0 / 60.0, false, frames);
    eprintln!(
        "loose targets RMS: synchronised {:.2} mm, half a frame apart interpolated {:.2} mm, not interpolated {:.2} mm",
        synced * 1e3,
        moved * 1e3,
        as_seen * 1e3
    );
    assert!(moved < 1.5 * synced.max(0.0005), "{moved} against {synced}");
    assert!(as_seen > moved, "{as_seen} not above {moved}");
}
