use super::*;
use stereoscope_numeric::random::SplitMix64 as Rng;

fn body(name: &str, pts: &[[f64; 3]]) -> BodyDef {
    BodyDef {
        name: name.into(),
        markers_m: pts.iter().map(|p| Point3::new(p[0], p[1], p[2])).collect(),
        tolerance_m: 0.003,
    }
}

/// Three asymmetric bodies of four markers (every distance distinct by well over 6 mm).
fn three_bodies() -> Vec<BodyDef> {
    vec![
        body(
            "head",
            &[
                [0.0, 0.0, 0.0],
                [0.09, 0.0, 0.0],
                [0.0, 0.05, 0.0],
                [0.03, 0.02, 0.07],
            ],
        ),
        body(
            "hand",
            &[
                [0.0, 0.0, 0.0],
                [0.12, 0.0, 0.0],
                [0.0, 0.08, 0.02],
                [0.06, 0.1, 0.0],
            ],
        ),
        body(
            "tool",
            &[
                [0.0, 0.0, 0.0],
                [0.2, 0.0, 0.0],
                [0.05, 0.15, 0.0],
                [0.1, 0.03, 0.11],
            ],
        ),
    ]
}

fn random_pose(rng: &mut Rng, at: Vector3<f64>) -> Isometry3<f64> {
    let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal());
    let angle = rng.uniform() * std::f64::consts::TAU;
    Isometry3::from_parts(
        Translation3::from(at),
        UnitQuaternion::from_scaled_axis(axis.normalize() * angle),
    )
}

fn angle_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

#[test]
fn kabsch_recovers_a_pose_and_weights_remove_an_outlier() {
    let mut rng = Rng::new(7);
    let b = &three_bodies()[2];
    for _ in 0..50 {
        let x = rng.uniform();
        let truth = random_pose(&mut rng, Vector3::new(x, 1.0, 0.5));
        let world: Vec<Point3<f64>> = b.markers_m.iter().map(|p| truth * p).collect();
        let (pose, rms) = kabsch(&b.markers_m, &world, &[1.0; 4]).unwrap();
        assert!(angle_deg(&pose, &truth) < 1e-9 && rms < 1e-12);
        assert!((pose.translation.vector - truth.translation.vector).norm() < 1e-12);
        // One point 5 cm off: with weight 0 it changes nothing.
        let mut bad = world.clone();
        bad[3].x += 0.05;
        let (p2, _) = kabsch(&b.markers_m, &bad, &[1.0, 1.0, 1.0, 0.0]).unwrap();
        assert!(angle_deg(&p2, &truth) < 1e-9);
    }
    // Collinear points give no rotation about their line.
    let line = [
        Point3::origin(),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(2.0, 0.0, 0.0),
    ];
    assert!(kabsch(&line, &line, &[1.0; 3]).is_none());
    assert!(kabsch(&line[..2], &line[..2], &[1.0; 2]).is_none());
}

#[test]
fn bodies_are_found_among_stray_points_with_a_marker_missing() {
    let defs = three_bodies();
    check_bodies(&defs).unwrap();
    let mut rng = Rng::new(11);
    for trial in 0..100 {
        let mut points = Vec::new();
        let mut truth = Vec::new();
        let mut owner = Vec::new();
        for (i, d) in defs.iter().enumerate() {
            let y = 0.3 * rng.uniform();
            let pose = random_pose(&mut rng, Vector3::new(0.6 * i as f64, y, 1.0));
            for (k, m) in d.markers_m.iter().enumerate() {
                // In every other trial the hand's marker 1 is hidden.
                if i == 1 && k == 1 && trial % 2 == 1 {
                    continue;
                }
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0003;
                points.push(pose * m + noise);
                owner.push(Some((i, k)));
            }
            truth.push(pose);
        }
        // Loose markers scattered around.
        for _ in 0..20 {
            points.push(Point3::new(
                rng.uniform() * 2.0 - 0.3,
                rng.uniform(),
                0.5 + rng.uniform(),
            ));
            owner.push(None);
        }
        // Shuffle.
        let mut order: Vec<usize> = (0..points.len()).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, (rng.uniform() * (i + 1) as f64) as usize % (i + 1));
        }
        let pts: Vec<Point3<f64>> = order.iter().map(|&i| points[i]).collect();
        let own: Vec<Option<(usize, usize)>> = order.iter().map(|&i| owner[i]).collect();
        let found = identify(&defs, &pts);
        assert_eq!(found.len(), 3, "trial {trial}: {found:?}");
        for f in &found {
            // 0.3 mm of noise on markers 5–20 cm apart: a few tenths of a degree.
            let err = angle_deg(&f.world_from_body, &truth[f.body]);
            assert!(err < 1.5, "trial {trial}: {err}°");
            assert!(f.residual_m < 0.001, "trial {trial}: {}", f.residual_m);
            for (k, p) in f.markers.iter().enumerate() {
                if let Some(p) = p {
                    assert_eq!(own[*p], Some((f.body, k)), "trial {trial}: {f:?}");
                }
            }
            let expect = if f.body == 1 && trial % 2 == 1 { 3 } else { 4 };
            assert_eq!(f.seen(), expect, "trial {trial}");
        }
    }
}

#[test]
fn a_body_too_deformed_is_not_reported() {
    let defs = three_bodies();
    let pose = Isometry3::translation(0.0, 0.0, 1.0);
    let mut pts: Vec<Point3<f64>> = defs[0].markers_m.iter().map(|m| pose * m).collect();
    // One marker 10 mm off: its distances break the tolerance; three remain consistent.
    pts[3].z += 0.01;
    let found = identify(&defs, &pts);
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].seen(), 3);
    assert_eq!(found[0].markers[3], None);
}

#[test]
fn symmetric_and_confusable_layouts_are_refused_with_what_to_move() {
    let square = body(
        "square",
        &[
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.1, 0.1, 0.0],
            [0.0, 0.1, 0.0],
        ],
    );
    let e = check_bodies(&[square]).unwrap_err();
    let BodyError::Ambiguous(a) = &e else {
        panic!("{e}")
    };
    assert!(a.other.is_none());
    assert!(
        e.to_string().contains("symmetric") && e.to_string().contains("move marker"),
        "{e}"
    );
    // An isosceles triangle: its two equal sides swap.
    let iso = body(
        "iso",
        &[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.05, 0.08, 0.0]],
    );
    assert!(matches!(check_bodies(&[iso]), Err(BodyError::Ambiguous(_))));
    // Two copies of one layout, and one that is three markers of another.
    let defs = three_bodies();
    let mut copy = defs[0].clone();
    copy.name = "copy".into();
    let e = check_bodies(&[defs[0].clone(), copy]).unwrap_err();
    assert!(e.to_string().contains("matches body"), "{e}");
    let part = BodyDef {
        name: "part".into(),
        markers_m: defs[2].markers_m[..3].to_vec(),
        tolerance_m: 0.003,
    };
    assert!(matches!(
        check_bodies(&[defs[2].clone(), part]),
        Err(BodyError::Ambiguous(_))
    ));
    // Moved far enough apart, they pass.
    let mut moved = defs[0].clone();
    moved.name = "moved".into();
    moved.markers_m[3].z += 0.03;
    check_bodies(&[defs[0].clone(), moved]).unwrap();
}

#[test]
fn bad_definitions_are_named() {
    let e = check_bodies(&[body("one", &[[0.0, 0.0, 0.0]])]).unwrap_err();
    assert!(matches!(e, BodyError::MarkerCount { count: 1, .. }), "{e}");
    let e = check_bodies(&[body(
        "line",
        &[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.25, 0.001, 0.0]],
    )])
    .unwrap_err();
    assert!(matches!(e, BodyError::Collinear { .. }), "{e}");
    let e = check_bodies(&[body(
        "near",
        &[[0.0, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.1, 0.0]],
    )])
    .unwrap_err();
    assert!(matches!(e, BodyError::TooClose { a: 0, b: 1, .. }), "{e}");
    let e = check_bodies(&[body("nan", &[[0.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0]])]).unwrap_err();
    assert!(matches!(e, BodyError::NotFinite { marker: 1, .. }), "{e}");
    let mut t = three_bodies();
    t[1].name = "head".into();
    assert_eq!(
        check_bodies(&t).unwrap_err(),
        BodyError::DuplicateName("head".into())
    );
    // A pointer of two markers is accepted.
    check_bodies(&[body("pointer", &[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])]).unwrap();
}

/// Two pinhole cameras 0.3 m apart look at a body 1.5 m away; from a pose 5 mm and 2° off,
/// refining on exact pixels recovers the pose, and on pixels with 0.1 px noise it lands far
/// nearer than Kabsch on points triangulated from the same noisy pixels would need.
#[test]
fn refining_on_pixels_recovers_the_pose() {
    use nalgebra::{Point2, Translation3, UnitQuaternion};
    let def = body(
        "head",
        &[
            [0.0, 0.0, 0.0],
            [0.18, 0.0, 0.0],
            [0.0, 0.11, 0.0],
            [0.06, 0.06, 0.08],
        ],
    );
    let truth = Isometry3::from_parts(
        Translation3::new(0.05, -0.02, 1.5),
        UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0),
    );
    let cam = |x: f64| {
        move |p: &Point3<f64>| {
            let q = p - Vector3::new(x, 0.0, 0.0);
            (q.z > 0.0).then(|| Point2::new(800.0 * q.x / q.z + 320.0, 800.0 * q.y / q.z + 240.0))
        }
    };
    let cams = [cam(-0.15), cam(0.15)];
    let start = Isometry3::from_parts(
        Translation3::new(0.055, -0.02, 1.504),
        UnitQuaternion::from_euler_angles(0.33, -0.2, 1.01),
    );
    let mut rng = Rng::new(5);
    for noise in [0.0, 0.1] {
        let sightings: Vec<Sighting<'_>> = def
            .markers_m
            .iter()
            .flat_map(|m| cams.iter().map(move |c| (m, c)))
            .map(|(m, c)| {
                let px = c(&(truth * m)).unwrap();
                Sighting {
                    marker_body: *m,
                    project: c,
                    pixel: Point2::new(px.x + noise * rng.normal(), px.y + noise * rng.normal()),
                }
            })
            .collect();
        let (got, rms) = refine_reprojection(&start, &sightings, 20).unwrap();
        let dt = (got.translation.vector - truth.translation.vector).norm();
        let da = got.rotation.angle_to(&truth.rotation).to_degrees();
        if noise == 0.0 {
            assert!(
                dt < 1e-6 && da < 1e-4 && rms < 1e-6,
                "{dt} m, {da}°, {rms} px"
            );
        } else {
            assert!(
                dt < 0.002 && da < 0.3 && rms < 0.2,
                "{dt} m, {da}°, {rms} px"
            );
        }
    }
    // Too few sightings to pose: none.
    let one = [Sighting {
        marker_body: def.markers_m[0],
        project: &cams[0],
        pixel: Point2::new(320.0, 240.0),
    }];
    assert!(refine_reprojection(&start, &one, 5).is_none());
}
