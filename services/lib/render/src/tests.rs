//! The renderer's truth against the projection math.

use super::*;
use nalgebra::{Isometry3, Point2, Point3, Vector3};
use stereoscope_geometry::transform::look_at;
use stereoscope_geometry::{Camera, Distortion, Intrinsics};
use stereoscope_vision::{ExtractConfig, Extractor};

/// The thesis's camera: 2.8 m above the floor looking down, 320 × 240, PAR 0.86.
fn down_camera(dist: Distortion) -> Camera {
    let intr = Intrinsics::new(581.4, 500.0, 159.5, 119.5, 320, 240).unwrap();
    let w = look_at(Point3::new(0.0, 0.0, 2.8), Point3::origin(), Vector3::y()).unwrap();
    Camera::new(intr, dist, w.inverse()).unwrap()
}

/// Renders with 8 × 8 samples at edges, no noise: the truth tests' setting.
fn fine(cam: &Camera, scene: &Scene) -> Frame<u8> {
    render_u8(
        cam,
        scene,
        &RenderOptions {
            samples: 8,
            ..Default::default()
        },
    )
    .unwrap()
}

fn one(shape: Shape, at: Point3<f64>, heading_deg: f64) -> Scene {
    let state = State {
        position: at,
        heading_deg,
        tilt: nalgebra::UnitQuaternion::identity(),
    };
    Scene {
        targets: vec![Target {
            shape,
            world_from_body: state.world_from_body(),
            contrast: 180.0,
        }],
        ..Scene::default()
    }
}

#[test]
fn sphere_on_the_axis_has_the_closed_form_area() {
    let cam = down_camera(Distortion::default());
    for h in [0.02, 0.5, 1.5, 2.0] {
        let r = 0.02;
        let d = 2.8 - h;
        let f = fine(
            &cam,
            &one(Shape::Sphere { radius_m: r }, Point3::new(0.0, 0.0, h), 0.0),
        );
        let t = f.truth[0];
        // Silhouette of a sphere on the axis: a cone of half-angle asin(r/D); normalised radius
        // r/√(D² − r²); area π·fx·fy·ρ².
        let rho2 = r * r / (d * d - r * r);
        let want = std::f64::consts::PI * cam.intrinsics.fx * cam.intrinsics.fy * rho2;
        assert!(
            (t.area_px - want).abs() / want < 0.01,
            "h {h}: {} vs {want}",
            t.area_px
        );
        assert!((t.centroid_px - Point2::new(159.5, 119.5)).norm() < 0.01);
    }
}

#[test]
fn disc_parallel_to_the_image_projects_exactly_anywhere() {
    let cam = down_camera(Distortion::default());
    for (x, y) in [(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4)] {
        let at = Point3::new(x, y, 0.3);
        let f = fine(&cam, &one(Shape::Disc { radius_m: 0.03 }, at, 0.0));
        let t = f.truth[0];
        let d = 2.5;
        let want =
            std::f64::consts::PI * cam.intrinsics.fx * cam.intrinsics.fy * 0.03 * 0.03 / (d * d);
        assert!(
            (t.area_px - want).abs() / want < 0.01,
            "{} vs {want}",
            t.area_px
        );
        let c = cam.project(&at).unwrap();
        assert!(
            (t.centroid_px - c).norm() < 0.02,
            "{:?} vs {c:?}",
            t.centroid_px
        );
    }
}

#[test]
fn distortion_moves_a_small_disc_with_its_centre() {
    let cam = down_camera(Distortion {
        k1: -0.25,
        k2: 0.05,
        ..Default::default()
    });
    let at = Point3::new(0.55, 0.45, 0.0);
    let f = fine(&cam, &one(Shape::Disc { radius_m: 0.01 }, at, 0.0));
    let c = cam.project(&at).unwrap();
    assert!(
        (f.truth[0].centroid_px - c).norm() < 0.05,
        "{:?} vs {c:?}",
        f.truth[0].centroid_px
    );
}

#[test]
fn nearer_targets_hide_farther_ones() {
    let cam = down_camera(Distortion::default());
    let mut scene = one(
        Shape::Sphere { radius_m: 0.02 },
        Point3::new(0.0, 0.0, 0.0),
        0.0,
    );
    scene.targets.push(Target {
        shape: Shape::Sphere { radius_m: 0.04 },
        world_from_body: Isometry3::translation(0.0, 0.0, 1.0),
        contrast: 100.0,
    });
    let f = render_u8(&cam, &scene, &RenderOptions::default()).unwrap();
    assert!(!f.truth[0].visible && f.truth[0].area_px == 0.0);
    assert!(f.truth[1].visible);
    // Half hidden: seen from 2.8 m the occluder's edge is 0.04/1.8 rad off the axis, so a
    // target at 0.062 m on the floor straddles it.
    let x = 0.062;
    scene.targets[0].world_from_body = Isometry3::translation(x, 0.0, 0.0);
    let f = fine(&cam, &scene);
    let alone = fine(
        &cam,
        &one(
            Shape::Sphere { radius_m: 0.02 },
            Point3::new(x, 0.0, 0.0),
            0.0,
        ),
    );
    assert!(f.truth[0].area_px > 0.0 && f.truth[0].area_px < alone.truth[0].area_px * 0.9);
}

#[test]
fn noise_blur_and_seeds() {
    let cam = down_camera(Distortion::default());
    let empty = Scene::default();
    let noisy = render_u8(
        &cam,
        &empty,
        &RenderOptions {
            noise_sigma: 2.0,
            seed: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let px: Vec<f64> = noisy.image.as_slice().iter().map(|&p| p as f64).collect();
    let mean = px.iter().sum::<f64>() / px.len() as f64;
    let sd = (px.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / px.len() as f64).sqrt();
    assert!(
        (mean - 20.0).abs() < 0.05 && (sd - 2.0).abs() < 0.1,
        "{mean} {sd}"
    );
    let again = render_u8(
        &cam,
        &empty,
        &RenderOptions {
            noise_sigma: 2.0,
            seed: 1,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(noisy, again);
    let other = render_u8(
        &cam,
        &empty,
        &RenderOptions {
            noise_sigma: 2.0,
            seed: 2,
            ..Default::default()
        },
    )
    .unwrap();
    assert_ne!(noisy.image, other.image);
    // Blur spreads a target but keeps its brightness (16-bit, so rounding does not hide it).
    let scene = one(Shape::Sphere { radius_m: 0.03 }, Point3::origin(), 0.0);
    let sharp = render_u16(&cam, &scene, &RenderOptions::default(), 256.0).unwrap();
    let soft = render_u16(
        &cam,
        &scene,
        &RenderOptions {
            blur_sigma_px: 1.0,
            ..Default::default()
        },
        256.0,
    )
    .unwrap();
    let sum = |f: &Frame<u16>| {
        f.image
            .as_slice()
            .iter()
            .map(|&p| p as f64 - 20.0 * 256.0)
            .sum::<f64>()
    };
    assert!((sum(&sharp) - sum(&soft)).abs() / sum(&sharp) < 0.01);
    let peak = |f: &Frame<u16>| *f.image.as_slice().iter().max().unwrap();
    assert!(peak(&soft) < peak(&sharp));
    // Shot noise grows with brightness.
    let shot = render_u8(
        &cam,
        &Scene {
            background: Background {
                level: 200.0,
                gradient_per_px: (0.0, 0.0),
            },
            ..Scene::default()
        },
        &RenderOptions {
            shot_noise_gain: Some(4.0),
            seed: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let v: Vec<f64> = shot.image.as_slice().iter().map(|&p| p as f64).collect();
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let s = (v.iter().map(|p| (p - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    assert!((s - (200.0f64 / 4.0).sqrt()).abs() < 0.3, "{s}");
}

#[test]
fn double_ball_images_along_its_heading() {
    // Seen from straight above with square pixels, the image axis is the heading (mirrored by
    // the image's downward y: world +y is image up here). On the optical axis, so that
    // perspective does not skew the pair.
    let intr = Intrinsics::new(600.0, 600.0, 159.5, 119.5, 320, 240).unwrap();
    let w = look_at(Point3::new(0.0, 0.0, 2.8), Point3::origin(), Vector3::y()).unwrap();
    let cam = Camera::new(intr, Distortion::default(), w.inverse()).unwrap();
    for heading in [0.0, 30.0, 75.0, 120.0, 160.0] {
        let f = render_u8(
            &cam,
            &one(
                Shape::DoubleSphere { radius_m: 0.02 },
                Point3::new(0.0, 0.0, 0.3),
                heading,
            ),
            &RenderOptions {
                samples: 6,
                ..Default::default()
            },
        )
        .unwrap();
        // Grey-level moments: the balls are only ~5 px in radius.
        let mut ex = Extractor::new(ExtractConfig {
            weighting: stereoscope_vision::Weighting::Intensity { background: 20 },
            ..Default::default()
        });
        let blobs = ex.extract(f.image.view(), 40, &[]).unwrap();
        assert_eq!(blobs.len(), 1);
        let got = blobs[0].best_central().orientation_deg(1.0);
        let diff = stereoscope_numeric::angle::wrap_half_turn_deg(got - heading);
        // The camera's x axis is world −x when looking down with +y up: headings mirror.
        let mirrored = stereoscope_numeric::angle::wrap_half_turn_deg(got + heading);
        assert!(
            diff.abs() < 1.0 || mirrored.abs() < 1.0,
            "heading {heading}: image axis {got}"
        );
    }
}

#[test]
fn motions_are_deterministic_and_in_bounds() {
    let circle = Motion::Circle {
        centre: Point3::new(0.0, 0.0, 0.5),
        radius_m: 0.3,
        period_s: 4.0,
    };
    let s = circle.at(1.0);
    assert!(
        (s.position - Point3::new(0.0, 0.3, 0.5)).norm() < 1e-12
            && (s.heading_deg - 180.0).abs() < 1e-9
    );
    let line = Motion::Line {
        from: Point3::origin(),
        to: Point3::new(1.0, 0.0, 0.0),
        period_s: 2.0,
    };
    assert!((line.at(0.5).position.x - 0.5).abs() < 1e-12 && line.at(0.5).heading_deg == 0.0);
    assert!((line.at(1.5).position.x - 0.5).abs() < 1e-12 && line.at(1.5).heading_deg == 180.0);
    let spin = Motion::Spin {
        position: Point3::origin(),
        deg_per_s: 90.0,
    };
    assert!((spin.at(5.0).heading_deg - 90.0).abs() < 1e-9);
    let wander = Motion::Wander {
        centre: Point3::new(1.0, 1.0, 0.5),
        extent_m: Vector3::new(0.5, 0.4, 0.2),
        seed: 7,
    };
    for k in 0..500 {
        let p = wander.at(k as f64 * 0.1).position;
        assert!(
            (p.x - 1.0).abs() <= 0.5 + 1e-9
                && (p.y - 1.0).abs() <= 0.4 + 1e-9
                && (p.z - 0.5).abs() <= 0.2 + 1e-9
        );
    }
    assert_eq!(wander.at(3.3), wander.at(3.3));
    let walk = Motion::RandomWalk {
        centre: Point3::new(0.0, 0.0, 0.5),
        extent_m: Vector3::new(0.3, 0.3, 0.1),
        step_m: 0.05,
        step_s: 0.1,
        seed: 3,
    };
    let mut prev = walk.at(0.0).position;
    assert_eq!(prev, Point3::new(0.0, 0.0, 0.5));
    for k in 1..300 {
        let p = walk.at(k as f64 * 0.05).position;
        assert!(
            p.x.abs() <= 0.3 + 1e-12
                && p.y.abs() <= 0.3 + 1e-12
                && (p.z - 0.5).abs() <= 0.1 + 1e-12
        );
        // Continuous: half a step apart in time, never more than a few step sizes apart.
        assert!((p - prev).norm() < 0.5, "{k}");
        prev = p;
    }
    assert_eq!(walk.at(7.77), walk.at(7.77));
    let actors = [Actor {
        shape: Shape::Sphere { radius_m: 0.02 },
        contrast: 150.0,
        motion: circle.clone(),
        hidden: None,
    }];
    let (scene, states) = scene_at(&Scene::default(), &actors, 1.0);
    assert_eq!(scene.targets.len(), 1);
    assert_eq!(states[0], circle.at(1.0));
}

#[test]
fn a_ring_light_shades_a_sphere_symmetrically_about_each_line_of_sight() {
    // A ball off to the side, seen obliquely. Under the lamp above, its top is brightest and
    // the grey-level centroid leans from the silhouette's; under a ring light at the camera
    // the shading is symmetric about the ray and the two centroids agree.
    let cam = down_camera(Distortion::default());
    let grey_centroid = |scene: &Scene| {
        let f = fine(&cam, scene);
        let (w, img) = (f.image.width(), f.image.as_slice());
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (i, &p) in img.iter().enumerate() {
            let v = (p as f64 - 20.0).max(0.0);
            s += v;
            sx += v * (i as u32 % w) as f64;
            sy += v * (i as u32 / w) as f64;
        }
        (Point2::new(sx / s, sy / s), f.truth[0].centroid_px)
    };
    let mut scene = one(
        Shape::Sphere { radius_m: 0.03 },
        Point3::new(0.5, 0.35, 0.3),
        0.0,
    );
    scene.light = Light::Overhead {
        towards: nalgebra::Unit::new_normalize(Vector3::new(-1.0, 0.0, 1.0)),
    };
    let (lamp, silhouette) = grey_centroid(&scene);
    assert!(
        (lamp - silhouette).norm() > 0.3,
        "under the lamp {lamp} vs silhouette {silhouette}"
    );
    scene.light = Light::Ring;
    let (ring, silhouette) = grey_centroid(&scene);
    assert!(
        (ring - silhouette).norm() < 0.05,
        "under the ring light {ring} vs silhouette {silhouette}"
    );
}
