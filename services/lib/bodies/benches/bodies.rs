//! Rigid-body benchmarks (docs/performance.md, "Rigid bodies"): identifying 8 bodies among 40
//! markers per frame, and Kabsch against SciPy's `Rotation.align_vectors` on the same points
//! (`compare-scipy.sh` runs both).
//!
//!   cargo bench -p stereoscope-bodies --bench bodies -- [--quick] [--points FILE.json]
//!
//! With `--points`, writes the Kabsch inputs (body points, world points with 0.2 mm noise, the
//! true rotation) and this side's results and time per call, for the SciPy script.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::hint::black_box;
use std::time::Instant;
use stereoscope_bodies::{BodyDef, Sighting, check_bodies, identify, kabsch, refine_reprojection};
use stereoscope_numeric::random::SplitMix64 as Rng;

fn random_pose(rng: &mut Rng, at: Vector3<f64>) -> Isometry3<f64> {
    let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal());
    Isometry3::from_parts(
        Translation3::from(at),
        UnitQuaternion::from_scaled_axis(axis.normalize() * rng.uniform() * std::f64::consts::TAU),
    )
}

/// Eight bodies of four markers within 15 cm, none confusable with another or itself.
fn eight_bodies(rng: &mut Rng) -> Vec<BodyDef> {
    let mut defs: Vec<BodyDef> = Vec::new();
    while defs.len() < 8 {
        let d = BodyDef {
            name: format!("body{}", defs.len()),
            markers_m: (0..4)
                .map(|_| Point3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.15)
                .collect(),
            tolerance_m: 0.003,
        };
        let mut with = defs.clone();
        with.push(d.clone());
        if check_bodies(&with).is_ok() {
            defs.push(d);
        }
    }
    defs
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let points_out = args
        .iter()
        .position(|a| a == "--points")
        .and_then(|i| args.get(i + 1).cloned());
    let mut rng = Rng::new(2026);
    let defs = eight_bodies(&mut rng);
    let frames = if quick { 200 } else { 2000 };
    let mut times = Vec::new();
    let mut found_all = 0;
    for _ in 0..frames {
        let mut pts = Vec::new();
        for (i, d) in defs.iter().enumerate() {
            let pose = random_pose(
                &mut rng,
                Vector3::new((i % 4) as f64 * 0.5, (i / 4) as f64 * 0.5, 1.0),
            );
            for m in &d.markers_m {
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0002;
                pts.push(pose * m + noise);
            }
        }
        for _ in 0..8 {
            pts.push(Point3::new(
                rng.uniform() * 2.0,
                rng.uniform() * 1.0,
                0.5 + rng.uniform(),
            ));
        }
        let t = Instant::now();
        let found = black_box(identify(&defs, &pts));
        times.push(t.elapsed().as_secs_f64() * 1e6);
        if found.len() == 8 && found.iter().all(|f| f.seen() == 4) {
            found_all += 1;
        }
    }
    println!(
        "identify 8 bodies (4 markers) among 40 points: median {:.1} µs, p99 {:.1} µs per frame; all 8 found whole in {found_all} of {frames} frames",
        median(times.clone()),
        {
            let mut t = times;
            t.sort_by(f64::total_cmp);
            t[t.len() * 99 / 100]
        }
    );

    // Kabsch on 4 and 100 points with 0.2 mm noise.
    let mut json = Vec::new();
    for n in [4usize, 100] {
        let sets = if quick { 200 } else { 2000 };
        let mut cases = Vec::new();
        for _ in 0..sets {
            let truth = random_pose(&mut rng, Vector3::new(0.5, 0.5, 1.0));
            let body: Vec<Point3<f64>> = (0..n)
                .map(|_| Point3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 0.2)
                .collect();
            let world: Vec<Point3<f64>> = body
                .iter()
                .map(|p| {
                    truth * p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0002
                })
                .collect();
            cases.push((truth, body, world));
        }
        let w = vec![1.0; n];
        let reps = if quick { 5 } else { 20 };
        let mut per_call = Vec::new();
        for _ in 0..reps {
            let t = Instant::now();
            for (_, b, p) in &cases {
                black_box(kabsch(b, p, &w));
            }
            per_call.push(t.elapsed().as_secs_f64() * 1e6 / cases.len() as f64);
        }
        let errs: Vec<f64> = cases
            .iter()
            .map(|(truth, b, p)| {
                let (pose, _) = kabsch(b, p, &w).expect("a pose");
                pose.rotation.angle_to(&truth.rotation).to_degrees()
            })
            .collect();
        let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
        let us = median(per_call);
        println!(
            "kabsch, {n} points: {us:.3} µs per call; rotation error RMS {rms:.5}° over {} sets",
            cases.len()
        );
        if points_out.is_some() {
            let case_json: Vec<String> = cases
                .iter()
                .map(|(truth, b, p)| {
                    let q = truth.rotation.quaternion();
                    let ours = kabsch(b, p, &w).expect("a pose").0.rotation;
                    let oq = ours.quaternion();
                    let pts = |v: &[Point3<f64>]| {
                        v.iter()
                            .map(|x| format!("[{:.17e},{:.17e},{:.17e}]", x.x, x.y, x.z))
                            .collect::<Vec<_>>()
                            .join(",")
                    };
                    format!(
                        "{{\"truth_xyzw\":[{},{},{},{}],\"ours_xyzw\":[{},{},{},{}],\"body\":[{}],\"world\":[{}]}}",
                        q.i, q.j, q.k, q.w, oq.i, oq.j, oq.k, oq.w,
                        pts(b),
                        pts(p)
                    )
                })
                .collect();
            json.push(format!(
                "{{\"points\":{n},\"ours_us_per_call\":{us},\"ours_rms_deg\":{rms},\"cases\":[{}]}}",
                case_json.join(",")
            ));
        }
    }
    if let Some(path) = points_out {
        std::fs::write(&path, format!("[{}]\n", json.join(",\n"))).expect("write points");
    }

    // Refinement on pixels: 4 markers seen by 2 pinhole cameras (0.3 m apart, 1.5 m away,
    // 800 px focal length), 0.1 px noise, from the Kabsch pose of points 1 mm off.
    let cam = |x: f64| {
        move |p: &Point3<f64>| {
            let q = p - Vector3::new(x, 0.0, 0.0);
            (q.z > 0.0).then(|| {
                nalgebra::Point2::new(800.0 * q.x / q.z + 320.0, 800.0 * q.y / q.z + 240.0)
            })
        }
    };
    let cams = [cam(-0.15), cam(0.15)];
    let markers = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.18, 0.0, 0.0),
        Point3::new(0.0, 0.11, 0.0),
        Point3::new(0.06, 0.06, 0.08),
    ];
    let n = if quick { 200 } else { 2000 };
    let mut cases = Vec::new();
    for _ in 0..n {
        let truth = random_pose(&mut rng, Vector3::new(0.0, 0.0, 1.5));
        let pixels: Vec<(usize, usize, nalgebra::Point2<f64>)> = (0..4)
            .flat_map(|m| (0..2).map(move |c| (m, c)))
            .filter_map(|(m, c)| {
                let p = cams[c](&(truth * markers[m]))?;
                Some((m, c, p))
            })
            .map(|(m, c, p)| {
                (
                    m,
                    c,
                    nalgebra::Point2::new(p.x + 0.1 * rng.normal(), p.y + 0.1 * rng.normal()),
                )
            })
            .collect();
        let start = truth * Isometry3::translation(0.001, -0.001, 0.001);
        cases.push((truth, start, pixels));
    }
    let mut times = Vec::new();
    let mut errs = Vec::new();
    for (truth, start, pixels) in &cases {
        let sightings: Vec<Sighting<'_>> = pixels
            .iter()
            .map(|(m, c, p)| Sighting {
                marker_body: markers[*m],
                project: &cams[*c],
                pixel: *p,
            })
            .collect();
        let t = Instant::now();
        let r = black_box(refine_reprojection(start, &sightings, 10));
        times.push(t.elapsed().as_secs_f64() * 1e6);
        if let Some((pose, _)) = r {
            errs.push(pose.rotation.angle_to(&truth.rotation).to_degrees());
        }
    }
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt();
    times.sort_by(f64::total_cmp);
    println!(
        "refine on pixels, 4 markers × 2 cameras: median {:.1} µs, p99 {:.1} µs per body; rotation error RMS {rms:.4}° over {} poses",
        times[times.len() / 2],
        times[times.len() * 99 / 100],
        errs.len()
    );
}
