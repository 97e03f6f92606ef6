//! Models from URDF, the robot description ROS uses: links, and joints with their origin
//! (`xyz`, `rpy` about fixed x, y, z), axis and limits, read by the `urdf-rs` crate. Markers
//! are not part of URDF: the rig places them on the URDF's links by name.
//!
//! Joint types: `revolute`, `continuous`, `prismatic`, `fixed` and `spherical` (URDF 1.2's)
//! are used as they are; `floating` and `planar` are refused (a floating joint between two
//! links is two models; a planar one is not tracked). A `revolute` or `prismatic` joint whose
//! limits read 0 to 0 (URDF 1.0 with no `<limit>`) or infinite is taken as unlimited.

use crate::model::{Base, JointKind, JointSpec, Limits, MarkerSpec, Model, ModelError, rpy};
use nalgebra::{Isometry3, Translation3, Unit, Vector3};

/// A URDF that cannot be used, naming the file and, where the text shows it, the line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UrdfError {
    #[error("{file}: not a URDF robot: {message}")]
    Parse { file: String, message: String },
    #[error("{file}{}: joint {joint:?}: {what} {value:?}", at(*.line))]
    Joint {
        file: String,
        line: Option<usize>,
        joint: String,
        what: &'static str,
        value: String,
    },
    #[error("{file}{}: {source}", at(*.line))]
    Model {
        file: String,
        line: Option<usize>,
        source: Box<ModelError>,
    },
}

fn at(line: Option<usize>) -> String {
    line.map(|l| format!(":{l}")).unwrap_or_default()
}

/// The line (1-based) of the `nth` (0-based) element `<tag …>` whose `name` attribute is
/// `name`, found in the text (an element's start tag on one line, as URDF files are written).
fn line_of(text: &str, tag: &str, name: &str, nth: usize) -> Option<usize> {
    let open = format!("<{tag}");
    let quoted = [format!("name=\"{name}\""), format!("name='{name}'")];
    text.lines()
        .enumerate()
        .filter(|(_, l)| {
            l.contains(&open)
                && l.split(&open).skip(1).any(|after| {
                    after.starts_with(|c: char| c.is_whitespace())
                        && quoted.iter().any(|q| after.contains(q.as_str()))
                })
        })
        .nth(nth)
        .map(|(i, _)| i + 1)
}

fn limits(l: &urdf_rs::JointLimit) -> Option<Limits> {
    let unset = l.lower == 0.0 && l.upper == 0.0;
    (!unset && l.lower.is_finite() && l.upper.is_finite()).then_some(Limits {
        lower: l.lower,
        upper: l.upper,
    })
}

/// Reads a URDF's text (`file` names it in errors) into a model with `markers` on its links.
pub fn model_from_urdf(
    file: &str,
    text: &str,
    markers: &[MarkerSpec],
    base: Base,
) -> Result<Model, UrdfError> {
    let robot = urdf_rs::read_from_string(text).map_err(|e| UrdfError::Parse {
        file: file.to_string(),
        message: e.to_string(),
    })?;
    let mut joints = Vec::with_capacity(robot.joints.len());
    for j in &robot.joints {
        let line = || line_of(text, "joint", &j.name, 0);
        let bad = |what: &'static str, value: String| UrdfError::Joint {
            file: file.to_string(),
            line: line(),
            joint: j.name.clone(),
            what,
            value,
        };
        let xyz = j.origin.xyz.0;
        let r = j.origin.rpy.0;
        let parent_from_joint = Isometry3::from_parts(
            Translation3::new(xyz[0], xyz[1], xyz[2]),
            rpy(r[0], r[1], r[2]),
        );
        let axis = || {
            let a = Vector3::from(j.axis.xyz.0);
            if !(a.iter().all(|v| v.is_finite()) && a.norm() > 1e-9) {
                return Err(bad(
                    "axis must be a finite, non-zero direction, not",
                    format!("{:?}", j.axis.xyz.0),
                ));
            }
            Ok(Unit::new_normalize(a))
        };
        let kind = match j.joint_type {
            urdf_rs::JointType::Fixed => JointKind::Fixed,
            urdf_rs::JointType::Revolute => JointKind::Revolute {
                axis: axis()?,
                limits: limits(&j.limit),
            },
            urdf_rs::JointType::Continuous => JointKind::Revolute {
                axis: axis()?,
                limits: None,
            },
            urdf_rs::JointType::Prismatic => JointKind::Prismatic {
                axis: axis()?,
                limits: limits(&j.limit),
            },
            urdf_rs::JointType::Spherical => JointKind::Spherical,
            urdf_rs::JointType::Floating | urdf_rs::JointType::Planar => {
                return Err(bad(
                    "type is not tracked (revolute, continuous, prismatic, fixed or spherical):",
                    format!("{:?}", j.joint_type).to_lowercase(),
                ));
            }
        };
        joints.push(JointSpec {
            name: j.name.clone(),
            parent: j.parent.link.clone(),
            child: j.child.link.clone(),
            parent_from_joint,
            kind,
        });
    }
    let links: Vec<String> = robot.links.iter().map(|l| l.name.clone()).collect();
    Model::new(&robot.name, &links, &joints, markers, base).map_err(|source| {
        let line = match &source {
            ModelError::Duplicate { what, name, .. } if *what == "joint" => {
                line_of(text, "joint", name, 1)
            }
            ModelError::Duplicate { what, name, .. } if *what == "link" => {
                line_of(text, "link", name, 1)
            }
            ModelError::NoSuchLink { joint, .. }
            | ModelError::TwoParents { second: joint, .. }
            | ModelError::BadJoint { joint, .. } => line_of(text, "joint", joint, 0),
            _ => None,
        };
        UrdfError::Model {
            file: file.to_string(),
            line,
            source: Box::new(source),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO: &str = r#"<?xml version="1.0"?>
<robot name="two">
  <link name="base"/>
  <link name="upper"/>
  <link name="lower"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/>
    <child link="upper"/>
    <origin xyz="0 0 0.1" rpy="0 0 1.5707963267948966"/>
    <axis xyz="0 1 0"/>
    <limit lower="-1.5" upper="1.5" effort="1" velocity="1"/>
  </joint>
  <joint name="elbow" type="continuous">
    <parent link="upper"/>
    <child link="lower"/>
    <origin xyz="0.3 0 0"/>
    <axis xyz="0 1 0"/>
  </joint>
</robot>
"#;

    fn on(link: &str, name: &str) -> MarkerSpec {
        MarkerSpec {
            name: name.into(),
            link: link.into(),
            in_link_m: [0.1, 0.0, 0.0],
        }
    }

    #[test]
    fn a_urdf_gives_its_joints_origins_axes_and_limits() {
        let m = model_from_urdf("two.urdf", TWO, &[on("lower", "tip")], Base::Floating).unwrap();
        assert_eq!(m.links[0].name, "base");
        let sh = &m.joints[m.joint_index("shoulder").unwrap()];
        assert!(matches!(
            sh.kind,
            JointKind::Revolute {
                limits: Some(Limits {
                    lower: -1.5,
                    upper: 1.5
                }),
                ..
            }
        ));
        assert!((sh.parent_from_joint.translation.z - 0.1).abs() < 1e-15);
        let el = &m.joints[m.joint_index("elbow").unwrap()];
        assert_eq!(el.kind.name(), "continuous");
        // The tip at zero: 0.1 up, then 0.3 + 0.1 along the yawed x (the world's y).
        let mut poses = Vec::new();
        m.forward(&Isometry3::identity(), &m.zero(), &mut poses);
        let tip = m.marker_positions(&poses)[0];
        assert!(
            (tip - nalgebra::Point3::new(0.0, 0.4, 0.1)).norm() < 1e-12,
            "{tip}"
        );
    }

    #[test]
    fn a_bad_urdf_is_refused_naming_the_file_line_and_value() {
        let twice = TWO.replace("name=\"elbow\"", "name=\"shoulder\"");
        let e = model_from_urdf("arm.urdf", &twice, &[], Base::Floating).unwrap_err();
        assert_eq!(
            e.to_string(),
            "arm.urdf:13: model \"two\": joint \"shoulder\" is named twice"
        );
        let e = model_from_urdf("arm.urdf", TWO, &[on("hand", "m1")], Base::Floating)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "arm.urdf: model \"two\": marker \"m1\" is on link \"hand\", which the model does not have"
        );
        let e = model_from_urdf("arm.urdf", "<robot name=\"x\"><joint", &[], Base::Floating)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("arm.urdf: not a URDF robot: "), "{e}");
        let floating = TWO.replace("type=\"continuous\"", "type=\"floating\"");
        let e = model_from_urdf("arm.urdf", &floating, &[], Base::Floating)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("arm.urdf:13: joint \"elbow\": type is not tracked")
                && e.ends_with("\"floating\""),
            "{e}"
        );
        let nowhere = TWO.replace("<child link=\"lower\"/>", "<child link=\"forearm\"/>");
        let e = model_from_urdf("arm.urdf", &nowhere, &[], Base::Floating)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "arm.urdf:13: model \"two\": joint \"elbow\" names child link \"forearm\", which the model does not have"
        );
        let zero_axis = TWO.replace(
            "<axis xyz=\"0 1 0\"/>\n  </joint>\n</robot>",
            "<axis xyz=\"0 0 0\"/>\n  </joint>\n</robot>",
        );
        let e = model_from_urdf("arm.urdf", &zero_axis, &[], Base::Floating)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("arm.urdf:13: joint \"elbow\": axis must be"),
            "{e}"
        );
    }
}
