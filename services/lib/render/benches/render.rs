//! Renderer throughput: frames per second at 320×240, 640×480 and 1920×1080 for the thesis's
//! scene (three double ping-pong balls in motion, a distractor, uneven light), with and
//! without the realistic noise and blur. `cargo bench -p stereoscope-render --bench render`
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Point3, Vector3};
use std::hint::black_box;
use std::time::Instant;
use stereoscope_geometry::transform::look_at;
use stereoscope_geometry::{Camera, Distortion, Intrinsics};
use stereoscope_render::{
    Actor, Background, Distractor, Motion, RenderOptions, Scene, Shape, render_u8, scene_at,
};

fn main() {
    let actors = [
        Actor {
            shape: Shape::DoubleSphere { radius_m: 0.02 },
            contrast: 190.0,
            hidden: None,
            motion: Motion::Circle {
                centre: Point3::new(0.0, 0.0, 0.3),
                radius_m: 0.3,
                period_s: 5.0,
            },
        },
        Actor {
            shape: Shape::DoubleSphere { radius_m: 0.02 },
            contrast: 190.0,
            hidden: None,
            motion: Motion::Line {
                from: Point3::new(-0.5, -0.3, 0.02),
                to: Point3::new(0.5, 0.3, 0.8),
                period_s: 7.0,
            },
        },
        Actor {
            shape: Shape::DoubleSphere { radius_m: 0.02 },
            contrast: 190.0,
            hidden: None,
            motion: Motion::Wander {
                centre: Point3::new(0.1, 0.1, 0.5),
                extent_m: Vector3::new(0.4, 0.3, 0.3),
                seed: 3,
            },
        },
    ];
    let base = Scene {
        background: Background {
            level: 18.0,
            gradient_per_px: (0.02, 0.0),
        },
        distractors: vec![Distractor {
            position_world: Point3::new(0.6, -0.4, 0.0),
            radius_m: 0.005,
            contrast: 150.0,
        }],
        ..Scene::default()
    };
    println!(
        "{:>10} {:>22} {:>10} {:>10}",
        "frame", "options", "ms/frame", "frames/s"
    );
    for (w, h, f) in [
        (320u32, 240u32, 581.4f64),
        (640, 480, 1162.8),
        (1920, 1080, 3488.4),
    ] {
        let intr = Intrinsics::new(
            f,
            f * 0.86,
            (w as f64 - 1.0) / 2.0,
            (h as f64 - 1.0) / 2.0,
            w,
            h,
        )
        .unwrap();
        let world_from_cam =
            look_at(Point3::new(0.0, 0.0, 2.8), Point3::origin(), Vector3::y()).unwrap();
        let cam = Camera::new(
            intr,
            Distortion {
                k1: -0.05,
                ..Default::default()
            },
            world_from_cam.inverse(),
        )
        .unwrap();
        for (label, opts) in [
            (
                "clean, 4×4 samples",
                RenderOptions {
                    samples: 4,
                    ..Default::default()
                },
            ),
            (
                "noise σ2 + blur 0.5px",
                RenderOptions {
                    samples: 4,
                    noise_sigma: 2.0,
                    blur_sigma_px: 0.5,
                    ..Default::default()
                },
            ),
        ] {
            let frames = if w > 1000 { 10 } else { 40 };
            let start = Instant::now();
            for k in 0..frames {
                let (scene, _) = scene_at(&base, &actors, k as f64 / 60.0);
                black_box(render_u8(&cam, &scene, &RenderOptions { seed: k, ..opts }).unwrap());
            }
            let ms = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
            println!(
                "{:>10} {:>22} {:>10.3} {:>10.1}",
                format!("{w}×{h}"),
                label,
                ms,
                1e3 / ms
            );
        }
    }
}
