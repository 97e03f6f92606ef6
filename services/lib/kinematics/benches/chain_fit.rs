//! The chain fit's cost per frame (docs/performance.md, "Kinematic models"): the six-joint arm
//! and the leg, warm-started frame to frame at 120 fps with 0.3 mm of noise per coordinate,
//! one thread. Each round fits the same precomputed frames in the same order; the figures are
//! the median and the worst round's median, and the p99 of single frames.
//!
//!   cargo bench -p stereoscope-kinematics --bench chain_fit -- [--rounds N] [--frames N] [--only arm6|leg]
//!
//! `--frames` also serves callgrind (`valgrind --tool=callgrind` on the bench binary with
//! `--rounds 1`): instructions per frame = the total ÷ frames, the setup included.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Isometry3, Point3};
use std::hint::black_box;
use std::time::Instant;
use stereoscope_kinematics::synthetic::{arm6, arm6_base, arm6_values, leg, leg_state};
use stereoscope_kinematics::{ChainState, FitOptions, JointValue, Model, fit_chain};
use stereoscope_numeric::random::SplitMix64;

fn frames(
    model: &Model,
    truth: impl Fn(f64) -> (Isometry3<f64>, Vec<JointValue>),
    n: usize,
) -> Vec<Vec<Option<Point3<f64>>>> {
    let mut rng = SplitMix64::new(3);
    let mut poses = Vec::new();
    (0..n)
        .map(|k| {
            let (root, values) = truth(k as f64 / 120.0);
            model.forward(&root, &values, &mut poses);
            model
                .marker_positions(&poses)
                .into_iter()
                .map(|p| {
                    Some(Point3::new(
                        p.x + 0.3e-3 * rng.normal(),
                        p.y + 0.3e-3 * rng.normal(),
                        p.z + 0.3e-3 * rng.normal(),
                    ))
                })
                .collect()
        })
        .collect()
}

fn run(name: &str, model: &Model, frames: &[Vec<Option<Point3<f64>>>], rounds: usize) {
    let opts = FitOptions::default();
    let mut medians = Vec::new();
    let mut all = Vec::new();
    let mut iterations = 0usize;
    for _ in 0..rounds {
        let mut prev: Option<ChainState> = None;
        let mut times = Vec::with_capacity(frames.len());
        for seen in frames {
            let t = Instant::now();
            let f = fit_chain(model, black_box(seen), prev.as_ref(), &opts).unwrap();
            times.push(t.elapsed().as_secs_f64() * 1e6);
            iterations += f.iterations;
            prev = Some(f.state);
        }
        all.extend_from_slice(&times);
        times.sort_by(f64::total_cmp);
        medians.push(times[times.len() / 2]);
    }
    medians.sort_by(f64::total_cmp);
    all.sort_by(f64::total_cmp);
    let p99 = all[(all.len() * 99 / 100).min(all.len() - 1)];
    println!(
        "{name}: {} markers, {} joints; {} frames × {rounds} rounds: median {:.1} µs a frame \
         (worst round's median {:.1}), p99 {:.1} µs, {:.2} iterations a frame",
        model.markers.len(),
        model.joints.len(),
        frames.len(),
        medians[medians.len() / 2],
        medians[medians.len() - 1],
        p99,
        iterations as f64 / (frames.len() * rounds) as f64,
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let value = |flag: &str, default: usize| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let rounds = value("--rounds", 5);
    let n = value("--frames", 2400);
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1))
        .cloned();
    let wanted = |name: &str| only.as_deref().is_none_or(|o| o == name);
    if wanted("arm6") {
        let arm = arm6().unwrap();
        let arm_frames = frames(&arm, |t| (arm6_base(), arm6_values(t)), n);
        run("arm6", &arm, &arm_frames, rounds);
    }
    if wanted("leg") {
        let leg = leg().unwrap();
        let leg_frames = frames(&leg, leg_state, n);
        run("leg", &leg, &leg_frames, rounds);
    }
}
