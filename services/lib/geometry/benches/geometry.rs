//! Criterion benchmarks of the geometry library: triangulating 1000 points from 4 cameras
//! (DLT + refinement), and calibrating a camera from 20 views of 100 points.
//! `cargo bench -p stereoscope-geometry --bench geometry`
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/fixtures/mod.rs"]
mod fixtures;

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Point2, Point3};
use std::hint::black_box;
use stereoscope_geometry::calibrate::{DistortionModel, calibrate_camera};
use stereoscope_geometry::synthetic::{
    ViewSpread, calibration_views, example_camera, grid, ring_cameras,
};
use stereoscope_geometry::triangulate::{Observation, triangulate};
use stereoscope_numeric::SplitMix64;

fn bench_triangulation(c: &mut Criterion) {
    let cams = ring_cameras(4);
    let mut rng = SplitMix64::new(1);
    let points: Vec<Vec<Observation>> = (0..1000)
        .map(|_| {
            let p = Point3::new(
                rng.range(-0.5, 0.5),
                rng.range(-0.5, 0.5),
                rng.range(0.0, 0.9),
            );
            (0..4)
                .map(|k| {
                    let q = cams[k].project(&p).unwrap();
                    Observation {
                        camera: k,
                        pixel: Point2::new(q.x + 0.5 * rng.normal(), q.y + 0.5 * rng.normal()),
                    }
                })
                .collect()
        })
        .collect();
    c.bench_function("triangulate 1000 points, 4 cameras", |b| {
        b.iter(|| {
            for obs in &points {
                black_box(triangulate(&cams, obs).unwrap());
            }
        })
    });
}

fn bench_calibration(c: &mut Criterion) {
    let spread = ViewSpread {
        lateral_m: 0.4,
        distance_m: (0.9, 1.2),
        aim_jitter_m: 0.0,
        roll: 0.3,
    };
    let views = calibration_views(&example_camera(), &grid(10, 10, 0.05), 20, &spread, 0.1, 2);
    let mut g = c.benchmark_group("calibration");
    g.sample_size(10);
    g.bench_function("calibrate from 20 views of 100 points", |b| {
        b.iter(|| black_box(calibrate_camera(640, 480, &views, DistortionModel::Full).unwrap()))
    });
    g.finish();
}

/// The same input OpenCV is timed on by `opencv_reference.py` (tests/data).
fn bench_fixtures(c: &mut Criterion) {
    let views = fixtures::calibration_views();
    let mut g = c.benchmark_group("same input as OpenCV");
    g.sample_size(10);
    g.bench_function("calibrate the fixture (20 views)", |b| {
        b.iter(|| black_box(calibrate_camera(640, 480, &views, DistortionModel::Full).unwrap()))
    });
    let (cams, points) = fixtures::triangulation();
    let obs: Vec<Vec<Observation>> = points
        .iter()
        .map(|(_, px)| {
            (0..2)
                .map(|c| Observation {
                    camera: c,
                    pixel: px[c],
                })
                .collect()
        })
        .collect();
    g.bench_function("triangulate 300 points, 2 views (DLT only)", |b| {
        b.iter(|| {
            for o in &obs {
                black_box(stereoscope_geometry::triangulate::triangulate_dlt(&cams, o).unwrap());
            }
        })
    });
    g.bench_function("triangulate 300 points, 2 views (DLT + refinement)", |b| {
        b.iter(|| {
            for o in &obs {
                black_box(triangulate(&cams, o).unwrap());
            }
        })
    });
    g.finish();
}

criterion_group!(
    benches,
    bench_triangulation,
    bench_calibration,
    bench_fixtures
);
criterion_main!(benches);
