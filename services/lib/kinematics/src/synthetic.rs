//! Two models with known motion — the truth for tests, benchmarks and demo rigs:
//!
//! - **arm6**: `deploy/models/arm6.urdf`, six revolute joints of a teleoperated manipulator's
//!   proportions (the thesis's §5.3 robot), four markers on each moving link and on the base;
//!   each joint swings on its own slow sine.
//! - **leg**: a right leg — pelvis (floating), hip (ball joint), knee (hinge about the lateral
//!   axis, flexion positive), ankle (universal: dorsiflexion about the lateral axis, then
//!   inversion about the foot's long axis) — four markers on each segment, walking in place
//!   with a gait's ranges (hip flexion ±20°, knee 3–60°, ankle ±11°) at 0.9 strides a second.

use crate::model::{Base, JointKind, JointSpec, JointValue, Limits, MarkerSpec, Model, ModelError};
use crate::urdf::{UrdfError, model_from_urdf};
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use std::f64::consts::TAU;

/// The arm's URDF, as in `deploy/models/arm6.urdf`.
pub const ARM6_URDF: &str = include_str!("../../../../deploy/models/arm6.urdf");

fn marker(link: &str, k: usize, p: [f64; 3]) -> MarkerSpec {
    MarkerSpec {
        name: format!("{link}_{k}"),
        link: link.into(),
        in_link_m: p,
    }
}

/// The arm's markers: clusters of four, 5–17 cm from their joint, the last link's (the tool's
/// cluster, whose joint no later marker steadies) the widest; no two clusters alike and none
/// alike turned over (each pairwise distance layout differs by more than 12 mm:
/// `stereoscope_bodies::check_bodies` at 6 mm), so each link is identified from nothing.
pub fn arm6_markers() -> Vec<MarkerSpec> {
    let clusters: [(&str, [[f64; 3]; 4]); 7] = [
        (
            "base",
            [
                [0.168, -0.016, 0.035],
                [-0.086, 0.108, -0.001],
                [-0.115, -0.113, 0.027],
                [-0.011, 0.028, 0.095],
            ],
        ),
        (
            "shoulder",
            [
                [0.075, 0.011, 0.051],
                [0.013, 0.076, -0.022],
                [-0.099, -0.013, 0.077],
                [-0.019, 0.062, 0.146],
            ],
        ),
        (
            "upper_arm",
            [
                [0.062, 0.026, 0.072],
                [-0.058, -0.02, 0.204],
                [0.004, 0.06, 0.323],
                [0.058, -0.049, 0.364],
            ],
        ),
        (
            "forearm",
            [
                [0.109, -0.004, 0.077],
                [-0.092, 0.009, 0.212],
                [0.005, 0.066, 0.303],
                [0.078, 0.039, 0.367],
            ],
        ),
        (
            "wrist_1",
            [
                [0.089, 0.045, 0.008],
                [-0.043, 0.123, 0.05],
                [0.002, 0.042, -0.083],
                [0.05, 0.089, 0.047],
            ],
        ),
        (
            "wrist_2",
            [
                [0.083, -0.027, 0.032],
                [-0.073, 0.115, 0.015],
                [0.028, -0.096, 0.063],
                [0.059, 0.029, 0.09],
            ],
        ),
        (
            "wrist_3",
            [
                [0.159, 0.076, 0.015],
                [-0.121, 0.023, 0.082],
                [-0.019, 0.052, -0.111],
                [0.062, 0.134, 0.073],
            ],
        ),
    ];
    clusters
        .iter()
        .flat_map(|(link, ps)| ps.iter().enumerate().map(|(k, p)| marker(link, k, *p)))
        .collect()
}

/// The arm with its markers, its base floating (fitted every frame from the base's markers).
pub fn arm6() -> Result<Model, UrdfError> {
    model_from_urdf(
        "deploy/models/arm6.urdf",
        ARM6_URDF,
        &arm6_markers(),
        Base::Floating,
    )
}

/// The arm's joint angles at `t_s`: each joint on its own sine (0.07–0.23 Hz, 0.5–1.2 rad).
pub fn arm6_values(t_s: f64) -> Vec<JointValue> {
    let swing: [(f64, f64, f64, f64); 6] = [
        (0.0, 1.2, 0.07, 0.0),
        (-0.6, 0.6, 0.11, 1.0),
        (1.2, 0.7, 0.13, 2.0),
        (-0.8, 0.9, 0.17, 0.5),
        (0.3, 1.0, 0.19, 1.5),
        (0.0, 1.1, 0.23, 2.5),
    ];
    let mut v: Vec<JointValue> = swing
        .iter()
        .map(|(c, a, f, p)| JointValue::Angle(c + a * (TAU * f * t_s + p).sin()))
        .collect();
    v.push(JointValue::Fixed);
    v
}

/// Where the arm's base stands in the world: on a table, turned 30° about the vertical.
pub fn arm6_base() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.2, -0.1, 0.75),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 30f64.to_radians()),
    )
}

/// The right leg, pelvis floating.
pub fn leg() -> Result<Model, ModelError> {
    let lim = |lower: f64, upper: f64| Some(Limits { lower, upper });
    let joints = [
        JointSpec {
            name: "hip".into(),
            parent: "pelvis".into(),
            child: "thigh".into(),
            parent_from_joint: Isometry3::translation(0.0, -0.09, -0.08),
            kind: JointKind::Spherical,
        },
        JointSpec {
            name: "knee".into(),
            parent: "thigh".into(),
            child: "shank".into(),
            parent_from_joint: Isometry3::translation(0.0, 0.0, -0.42),
            kind: JointKind::Revolute {
                axis: Vector3::y_axis(),
                limits: lim(-0.1, 2.4),
            },
        },
        JointSpec {
            name: "ankle".into(),
            parent: "shank".into(),
            child: "foot".into(),
            parent_from_joint: Isometry3::translation(0.0, 0.0, -0.41),
            kind: JointKind::Universal {
                axes: [Vector3::y_axis(), Unit::new_normalize(Vector3::x())],
                limits: [lim(-0.7, 0.7), lim(-0.5, 0.5)],
            },
        },
    ];
    let markers: Vec<MarkerSpec> = [
        (
            "pelvis",
            [
                [0.05, 0.12, 0.0],
                [0.05, -0.12, 0.0],
                [-0.12, 0.05, 0.02],
                [-0.12, -0.05, 0.02],
            ],
        ),
        (
            "thigh",
            [
                [0.06, -0.04, -0.15],
                [0.0, -0.07, -0.25],
                [-0.05, -0.03, -0.32],
                [0.05, -0.06, -0.38],
            ],
        ),
        (
            "shank",
            [
                [0.05, -0.04, -0.12],
                [0.0, -0.07, -0.2],
                [-0.04, -0.03, -0.3],
                [0.04, -0.05, -0.36],
            ],
        ),
        (
            "foot",
            [
                [-0.06, 0.0, -0.05],
                [0.15, 0.0, -0.06],
                [0.1, -0.04, -0.05],
                [0.05, 0.03, -0.02],
            ],
        ),
    ]
    .iter()
    .flat_map(|(link, ps)| ps.iter().enumerate().map(|(k, p)| marker(link, k, *p)))
    .collect();
    let links: Vec<String> = ["pelvis", "thigh", "shank", "foot"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    Model::new("leg", &links, &joints, &markers, Base::Floating)
}

/// The leg at `t_s`: pelvis 0.95 m up, swaying and turning a little; the joints at a gait's
/// ranges. Returns the pelvis pose and the joints' values.
pub fn leg_state(t_s: f64) -> (Isometry3<f64>, Vec<JointValue>) {
    let w = TAU * 0.9 * t_s;
    let pelvis = Isometry3::from_parts(
        Translation3::new(
            0.1 * w.sin(),
            0.03 * (w + 0.3).sin(),
            0.95 + 0.02 * (2.0 * w).sin(),
        ),
        UnitQuaternion::from_euler_angles(0.05 * w.sin(), 0.04 * (w + 1.0).sin(), 0.1 * w.cos()),
    );
    let hip = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -0.35 * w.sin())
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.08 * (w + 0.5).sin())
        * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1 * (w + 1.2).sin());
    let knee = 0.55 + 0.5 * (w + 1.3).sin();
    let ankle = [0.2 * (w + 2.0).sin(), 0.1 * (w + 0.7).sin()];
    (
        pelvis,
        vec![
            JointValue::Rotation(hip),
            JointValue::Angle(knee),
            JointValue::Angles(ankle),
        ],
    )
}
