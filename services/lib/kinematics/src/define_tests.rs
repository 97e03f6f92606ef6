//! `define_model` against the synthetic models' truth: a range-of-motion recording rendered
//! from the model with its markers, the markers forgotten, found again.

use crate::define::{DefineError, DefineOptions, Track, define_model};
use crate::model::{Base, JointKind, JointSpec, Model, Swing};
use crate::synthetic::{arm6, arm6_base, leg};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use stereoscope_numeric::random::SplitMix64;

/// The model without its markers: what `model define` is given.
fn skeleton(m: &Model) -> Model {
    let links: Vec<String> = m.links.iter().map(|l| l.name.clone()).collect();
    Model::new(&m.name, &links, &m.joint_specs(), &[], m.base.clone()).unwrap()
}

/// A take at 60 frames a second: every degree of freedom on a sine (none: the zero pose);
/// markers with `sigma_m` noise, one track per marker (ids from 100, shuffled by a stride
/// prime to the count).
fn take(
    m: &Model,
    root: impl Fn(f64) -> Isometry3<f64>,
    swings: &[Swing],
    frames: usize,
    sigma_m: f64,
) -> Vec<Track> {
    let mut rng = SplitMix64::new(11);
    let mut tracks: Vec<Track> = (0..m.markers.len())
        .map(|k| Track {
            id: 100 + ((k * 5) % m.markers.len()) as u32,
            points: Vec::new(),
        })
        .collect();
    let mut poses = Vec::new();
    for f in 0..frames {
        let t = f as f64 / 60.0;
        let values = m.swing_values(swings, t);
        m.forward(&root(t), &values, &mut poses);
        for (k, p) in m.marker_positions(&poses).iter().enumerate() {
            let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma_m;
            tracks[k].points.push(Some(p + noise));
        }
    }
    tracks
}

fn swing(amplitude: f64, hz: f64) -> Swing {
    Swing {
        centre: 0.0,
        amplitude,
        hz,
        phase_rad: 0.0,
    }
}

#[test]
fn the_arms_markers_and_link_lengths_are_found_from_its_motion() {
    let truth = arm6().unwrap();
    let swings = [
        swing(1.0, 0.11),
        swing(0.7, 0.17),
        swing(0.9, 0.13),
        swing(1.0, 0.23),
        swing(1.1, 0.19),
        swing(1.2, 0.29),
    ];
    let mut tracks = take(&truth, |_| arm6_base(), &swings, 1260, 0.3e-3);
    let home = take(&truth, |_| arm6_base(), &[], 60, 0.3e-3);
    // A marker's track breaks once (a new id after a long occlusion), and a stray is seen now
    // and then: the two pieces are one marker, the stray is left out.
    let broken: Vec<Option<Point3<f64>>> = tracks[9].points[700..].to_vec();
    for p in &mut tracks[9].points[600..] {
        *p = None;
    }
    let mut piece = vec![None; 700];
    piece.extend(broken);
    tracks.push(Track {
        id: 500,
        points: piece,
    });
    tracks.push(Track {
        id: 900,
        points: (0..1260)
            .map(|f| (f % 3 == 0).then(|| Point3::new(2.0, 0.0, f as f64 * 1e-4)))
            .collect(),
    });
    let d = define_model(&skeleton(&truth), &tracks, &home, &DefineOptions::default()).unwrap();
    assert_eq!(d.left_out, vec![900], "{:?}", d.links);
    assert_eq!(d.markers.len(), truth.markers.len());
    // Every marker on its true link, within 0.5 mm of where the rig places it.
    // Every marker on its true link, within 0.5 mm of where the rig places one there.
    for spec in &d.markers {
        let link = truth.link_index(&spec.link).unwrap();
        let e = truth
            .markers
            .iter()
            .filter(|m| m.link == link)
            .map(|m| (Point3::from(spec.in_link_m) - m.in_link_m).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(e < 0.5e-3, "{}: {:.3} mm off", spec.name, e * 1e3);
    }
    // The marker whose id changed is found all through (but for the 100 frames it was hidden).
    assert!(
        d.observations
            .iter()
            .all(|o| o.iter().flatten().count() >= 1150)
    );
    // Link lengths within the 0.3 mm of the URDF; hinge angles within 0.2°.
    assert_eq!(d.lengths.len(), 5, "{:?}", d.lengths);
    for l in &d.lengths {
        let e = (l.measured_m - l.model_m).abs();
        assert!(e < 0.3e-3, "{l:?}: {:.3} mm", e * 1e3);
        if let (Some(a), Some(b)) = (l.measured_angle_rad, l.model_angle_rad) {
            assert!((a - b).abs().to_degrees() < 0.2, "{l:?}");
        }
    }
    let upper = d.lengths.iter().find(|l| l.link == "upper_arm").unwrap();
    assert!((upper.model_m - 0.425).abs() < 1e-9, "{upper:?}");
    for j in &d.joints {
        // Per frame, each link's pose from 4 markers of 0.3 mm noise: about a millimetre.
        println!("{j:?}");
        assert!(j.residual_m < 1.5e-3, "{j:?}");
        assert!(j.registration_m < 1e-3, "{j:?}");
    }
    let base = d.world_from_root_home;
    let e = (base.translation.vector - arm6_base().translation.vector).norm();
    assert!(e < 1e-3, "base {:.3} mm off", e * 1e3);
}

#[test]
fn the_legs_hip_centre_knee_axis_and_ankle_centre_are_found() {
    let truth = leg().unwrap();
    // Pelvis moving too; hip flexion, abduction, rotation, knee flexion, ankle two ways.
    let swings = [
        swing(0.5, 0.21),
        swing(0.3, 0.13),
        swing(0.3, 0.17),
        Swing {
            centre: 0.6,
            amplitude: 0.6,
            hz: 0.19,
            phase_rad: -std::f64::consts::FRAC_PI_2,
        },
        swing(0.4, 0.23),
        swing(0.3, 0.29),
    ];
    let root = |t: f64| {
        Isometry3::from_parts(
            Translation3::new(0.1 * (0.3 * t).sin(), 0.0, 0.95),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.2 * (0.2 * t).sin()),
        )
    };
    let tracks = take(&truth, root, &swings, 1260, 0.3e-3);
    let home = take(&truth, |_| root(0.0), &[], 60, 0.3e-3);
    let d = define_model(&skeleton(&truth), &tracks, &home, &DefineOptions::default()).unwrap();
    // Thigh: hip centre to knee axis 0.42 m; shank: knee axis to ankle centre 0.41 m.
    for (link, want) in [("thigh", 0.42), ("shank", 0.41)] {
        let l = d.lengths.iter().find(|l| l.link == link).unwrap();
        assert!((l.model_m - want).abs() < 1e-9, "{l:?}");
        assert!((l.measured_m - want).abs() < 0.3e-3, "{l:?}");
    }
    for spec in &d.markers {
        let link = truth.link_index(&spec.link).unwrap();
        let e = truth
            .markers
            .iter()
            .filter(|m| m.link == link)
            .map(|m| (Point3::from(spec.in_link_m) - m.in_link_m).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(e < 1e-3, "{}: {:.3} mm off", spec.name, e * 1e3);
    }
}

#[test]
fn a_still_joint_or_a_slide_is_refused_naming_what_is_missing() {
    let truth = arm6().unwrap();
    // The elbow never moves: the upper arm and the forearm are one rigid cluster.
    let swings = [
        swing(1.0, 0.11),
        swing(0.7, 0.17),
        swing(0.0, 0.13),
        swing(1.0, 0.23),
        swing(1.1, 0.19),
        swing(1.2, 0.29),
    ];
    let tracks = take(&truth, |_| arm6_base(), &swings, 700, 0.3e-3);
    let home = take(&truth, |_| arm6_base(), &[], 60, 0.3e-3);
    let e = define_model(&skeleton(&truth), &tracks, &home, &DefineOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            DefineError::Clusters {
                found: 6,
                links: 7,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("every joint must move"), "{e}");
    // A prismatic joint has no centre or axis to find.
    let links = vec!["a".to_string(), "b".to_string()];
    let slide = JointSpec {
        name: "slide".into(),
        parent: "a".into(),
        child: "b".into(),
        parent_from_joint: Isometry3::identity(),
        kind: JointKind::Prismatic {
            axis: Vector3::x_axis(),
            limits: None,
        },
    };
    let m = Model::new("s", &links, &[slide], &[], Base::Floating).unwrap();
    let e = define_model(&m, &tracks, &home, &DefineOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("joint \"slide\" is prismatic"),
        "{e}"
    );
    // Too short a take.
    let short: Vec<Track> = tracks
        .iter()
        .map(|t| Track {
            id: t.id,
            points: t.points[..50].to_vec(),
        })
        .collect();
    assert!(matches!(
        define_model(&skeleton(&truth), &short, &home, &DefineOptions::default()),
        Err(DefineError::TooShort { frames: 50, .. })
    ));
    // A zero-pose take that moves is refused.
    let e = define_model(
        &skeleton(&truth),
        &tracks,
        &tracks,
        &DefineOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e, DefineError::HomeMoved { .. }), "{e}");
}

/// A wand of four markers carried through the volume for 4 s beside two markers standing
/// still and one moving on its own, 0.3 mm of noise, a second of the take standing still: the
/// wand's four are the one group that moved together.
#[test]
fn the_markers_that_moved_together_are_found() {
    use crate::define::moved_together;
    let frames = 240;
    let mut rng = SplitMix64::new(11);
    let wand = [
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(0.12, 0.0, 0.0),
        Vector3::new(0.0, 0.08, 0.0),
        Vector3::new(0.05, 0.04, 0.06),
    ];
    let mut tracks: Vec<Track> = (0..7)
        .map(|i| Track {
            id: 20 + i,
            points: vec![None; frames],
        })
        .collect();
    for f in 0..frames {
        // Still for the first second, then moving.
        let t = (f as f64 / 60.0 - 1.0).max(0.0);
        let pose = Isometry3::from_parts(
            Translation3::new(0.3 * t.sin(), 0.2 * t, 1.0 + 0.1 * (2.0 * t).sin()),
            UnitQuaternion::from_euler_angles(0.3 * t, 0.2 * (1.5 * t).sin(), t),
        );
        let mut noisy =
            |p: Point3<f64>| p + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0003;
        for (k, m) in wand.iter().enumerate() {
            tracks[k].points[f] = Some(noisy(pose * Point3::from(*m)));
        }
        tracks[4].points[f] = Some(noisy(Point3::new(1.0, 1.0, 0.0)));
        tracks[5].points[f] = Some(noisy(Point3::new(1.2, 0.9, 0.0)));
        tracks[6].points[f] = Some(noisy(Point3::new(-0.5 + 0.3 * t, 0.4 * t.cos(), 0.5)));
    }
    let found = moved_together(&tracks, &DefineOptions::default());
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0].ids, [20, 21, 22, 23]);
    assert_eq!(found[0].frames_together, frames);
    assert!(found[0].travel_m > 0.2, "{found:?}");
}
