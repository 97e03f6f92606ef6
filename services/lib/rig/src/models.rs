//! The rig's kinematic models (`[[model]]`, `docs/models.md`) built into checked
//! [`stereoscope_kinematics::Model`]s: a URDF read from its file (relative to the rig file),
//! or joints given in the rig; markers placed on links by name; file units turned into metres
//! and degrees into radians. Every problem names the model's key and the value.

use crate::error::{RigError, err};
use crate::schema::{ModelJointSpec, ModelSpec, RigFile};
use nalgebra::{Isometry3, Quaternion, Translation3, Unit, UnitQuaternion, Vector3};
use std::path::Path;
use stereoscope_kinematics::{
    Base, JointKind, JointSpec, Limits, MarkerSpec, Model, model_from_urdf,
};

/// Most models a rig may define, joints a model may have, and markers on one model.
pub const MAX_MODELS: usize = 8;
pub const MAX_MODEL_JOINTS: usize = 64;
pub const MAX_MODEL_MARKERS: usize = 256;

/// A model as the rig defines it, ready for fusion.
#[derive(Debug, Clone, PartialEq)]
pub struct RigModel {
    pub model: Model,
    /// Identification tolerance of a link's inter-marker distances, metres.
    pub tolerance_m: f64,
    /// Largest RMS residual of a valid frame, metres.
    pub max_rms_m: f64,
}

fn axis(key: &str, a: [f64; 3]) -> Result<Unit<Vector3<f64>>, RigError> {
    let v = Vector3::from(a);
    if !(v.iter().all(|x| x.is_finite()) && v.norm() > 1e-9) {
        return Err(err(
            key,
            format!("{a:?} is not a finite, non-zero direction"),
        ));
    }
    Ok(Unit::new_normalize(v))
}

fn limits(key: &str, l: Option<[f64; 2]>, scale: f64) -> Result<Option<Limits>, RigError> {
    match l {
        None => Ok(None),
        Some([lo, hi]) if lo.is_finite() && hi.is_finite() && lo <= hi => Ok(Some(Limits {
            lower: lo * scale,
            upper: hi * scale,
        })),
        Some(v) => Err(err(key, format!("{v:?} must be finite with lower ≤ upper"))),
    }
}

fn joint(key: &str, j: &ModelJointSpec, m: f64) -> Result<JointSpec, RigError> {
    let r = j.rpy_deg.map(f64::to_radians);
    if !(j.origin.iter().chain(&j.rpy_deg).all(|v| v.is_finite())) {
        return Err(err(
            format!("{key}.origin"),
            format!("{:?} / rpy_deg {:?} must be finite", j.origin, j.rpy_deg),
        ));
    }
    let parent_from_joint = Isometry3::from_parts(
        Translation3::new(j.origin[0] * m, j.origin[1] * m, j.origin[2] * m),
        UnitQuaternion::from_euler_angles(r[0], r[1], r[2]),
    );
    let need_axis = || {
        j.axis
            .ok_or_else(|| {
                err(
                    format!("{key}.axis"),
                    format!("a {} joint needs an axis", j.kind),
                )
            })
            .and_then(|a| axis(&format!("{key}.axis"), a))
    };
    let deg = 1f64.to_radians();
    let kind = match j.kind.as_str() {
        "fixed" => JointKind::Fixed,
        "spherical" => JointKind::Spherical,
        "revolute" => JointKind::Revolute {
            axis: need_axis()?,
            limits: limits(&format!("{key}.limits"), j.limits, deg)?,
        },
        "continuous" => JointKind::Revolute {
            axis: need_axis()?,
            limits: None,
        },
        "prismatic" => JointKind::Prismatic {
            axis: need_axis()?,
            limits: limits(&format!("{key}.limits"), j.limits, m)?,
        },
        "universal" => {
            let [a, b] = j.axes.ok_or_else(|| {
                err(
                    format!("{key}.axes"),
                    "a universal joint needs its two axes".to_string(),
                )
            })?;
            let l = j.axes_limits_deg;
            JointKind::Universal {
                axes: [
                    axis(&format!("{key}.axes[0]"), a)?,
                    axis(&format!("{key}.axes[1]"), b)?,
                ],
                limits: [
                    limits(&format!("{key}.axes_limits_deg[0]"), l.map(|l| l[0]), deg)?,
                    limits(&format!("{key}.axes_limits_deg[1]"), l.map(|l| l[1]), deg)?,
                ],
            }
        }
        other => {
            return Err(err(
                format!("{key}.type"),
                format!(
                    "{other:?} is not a joint type (revolute, continuous, prismatic, fixed, universal, spherical)"
                ),
            ));
        }
    };
    Ok(JointSpec {
        name: j.name.clone(),
        parent: j.parent.clone(),
        child: j.child.clone(),
        parent_from_joint,
        kind,
    })
}

fn model(i: usize, s: &ModelSpec, m: f64, base_dir: Option<&Path>) -> Result<RigModel, RigError> {
    let key = format!("model[{i}]");
    let markers: Vec<MarkerSpec> = s
        .markers
        .iter()
        .map(|k| MarkerSpec {
            name: k.name.clone(),
            link: k.link.clone(),
            in_link_m: k.position.map(|v| v * m),
        })
        .collect();
    if markers.len() > MAX_MODEL_MARKERS {
        return Err(err(
            format!("{key}.marker"),
            format!(
                "{} markers, over the {MAX_MODEL_MARKERS} a model may have",
                markers.len()
            ),
        ));
    }
    let base = match &s.fixed_base {
        None => Base::Floating,
        Some(b) => {
            let q = Quaternion::new(
                b.orientation_xyzw[3],
                b.orientation_xyzw[0],
                b.orientation_xyzw[1],
                b.orientation_xyzw[2],
            );
            let finite = b
                .position
                .iter()
                .chain(&b.orientation_xyzw)
                .all(|v| v.is_finite());
            if !finite || (q.norm() - 1.0).abs() > 1e-3 {
                return Err(err(
                    format!("{key}.fixed_base"),
                    format!(
                        "position {:?}, orientation_xyzw {:?}: finite, and a unit quaternion",
                        b.position, b.orientation_xyzw
                    ),
                ));
            }
            Base::Fixed(Isometry3::from_parts(
                Translation3::new(b.position[0] * m, b.position[1] * m, b.position[2] * m),
                UnitQuaternion::from_quaternion(q),
            ))
        }
    };
    let model = match (&s.urdf, s.joints.is_empty()) {
        (Some(_), false) => {
            return Err(err(
                format!("{key}.urdf"),
                "a model is a URDF or [[model.joint]] tables, not both".to_string(),
            ));
        }
        (Some(path), true) => {
            let file = crate::check::resolve(base_dir, path);
            let text = std::fs::read_to_string(&file).map_err(|e| {
                err(
                    format!("{key}.urdf"),
                    format!("cannot read {}: {e}", file.display()),
                )
            })?;
            let mut model = model_from_urdf(&file.display().to_string(), &text, &markers, base)
                .map_err(|e| err(format!("{key}.urdf"), e.to_string()))?;
            // The rig's name for the model, not the URDF's robot name.
            model.name = s.name.clone();
            model
        }
        (None, true) => {
            return Err(err(
                key,
                "a model needs a urdf or [[model.joint]] tables".to_string(),
            ));
        }
        (None, false) => {
            let joints = s
                .joints
                .iter()
                .enumerate()
                .map(|(j, spec)| joint(&format!("{key}.joint[{j}]"), spec, m))
                .collect::<Result<Vec<_>, _>>()?;
            let mut links: Vec<String> = Vec::new();
            for j in &s.joints {
                for l in [&j.parent, &j.child] {
                    if !links.contains(l) {
                        links.push(l.clone());
                    }
                }
            }
            Model::new(&s.name, &links, &joints, &markers, base)
                .map_err(|e| err(key.clone(), e.to_string()))?
        }
    };
    if model.joints.len() > MAX_MODEL_JOINTS {
        return Err(err(
            key,
            format!(
                "{} joints, over the {MAX_MODEL_JOINTS} a model may have",
                model.joints.len()
            ),
        ));
    }
    let tolerance_m = match s.tolerance {
        None => 0.003,
        Some(v) if v.is_finite() && v > 0.0 && v * m <= 0.1 => v * m,
        Some(v) => {
            return Err(err(
                format!("{key}.tolerance"),
                format!("{v} must be above 0 and at most 0.1 m"),
            ));
        }
    };
    // Each link with 3 to 8 markers is found from nothing as a rigid cluster: no two may be
    // alike, nor one alike turned over (as bodies are checked).
    let clusters: Vec<stereoscope_bodies::BodyDef> = model
        .links
        .iter()
        .enumerate()
        .filter_map(|(l, link)| {
            let pts: Vec<_> = model
                .markers
                .iter()
                .filter(|k| k.link == l)
                .map(|k| k.in_link_m)
                .collect();
            (3..=stereoscope_bodies::MAX_MARKERS)
                .contains(&pts.len())
                .then(|| stereoscope_bodies::BodyDef {
                    name: link.name.clone(),
                    markers_m: pts,
                    tolerance_m,
                })
        })
        .collect();
    stereoscope_bodies::check_bodies(&clusters).map_err(|e| {
        err(
            format!("{key}.marker"),
            format!("the links' marker clusters could be confused (names are links): {e}"),
        )
    })?;
    let positive = |what: &str, v: Option<f64>, default_m: f64| -> Result<f64, RigError> {
        match v {
            None => Ok(default_m),
            Some(v) if v.is_finite() && v > 0.0 && v * m <= 0.1 => Ok(v * m),
            Some(v) => Err(err(
                format!("{key}.{what}"),
                format!("{v} must be above 0 and at most 0.1 m"),
            )),
        }
    };
    Ok(RigModel {
        tolerance_m,
        max_rms_m: positive("max_rms", s.max_rms, 0.005)?,
        model,
    })
}

/// A synthetic target of shape "model" as the renderer moves it (`[[synthetic.target]]` with
/// a `joints` motion): its root's pose and one swing per degree of freedom, in metres and
/// radians — the scene's truth for the model's joints.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelMotion {
    /// The target's index in `[synthetic]`.
    pub target: usize,
    pub model: Model,
    pub world_from_root: Isometry3<f64>,
    pub swings: Vec<stereoscope_kinematics::Swing>,
    /// A link whose markers are hidden periodically: its index, every, for (seconds).
    pub hide: Option<(usize, f64, f64)>,
}

impl ModelMotion {
    /// The link hidden at scene time `t_s`, if any.
    pub fn hidden_at(&self, t_s: f64) -> Option<usize> {
        let (link, every, for_s) = self.hide?;
        (t_s.rem_euclid(every) < for_s).then_some(link)
    }
}

/// Each model target's `hide` names a link of its model (the rig's other checks hold).
pub(crate) fn check_hidden_links(file: &RigFile, models: &[RigModel]) -> Result<(), RigError> {
    let Some(spec) = &file.synthetic else {
        return Ok(());
    };
    for (i, t) in spec.targets.iter().enumerate() {
        let crate::schema::MotionSpec::Joints { hide: Some(h), .. } = &t.motion else {
            continue;
        };
        let Some(m) = models
            .iter()
            .find(|m| t.model.as_ref() == Some(&m.model.name))
        else {
            continue;
        };
        if !m.model.links.iter().any(|l| l.name == h.link) {
            return Err(err(
                format!("synthetic.target[{i}].motion.hide.link"),
                format!(
                    "{:?} is not a link of model {:?} (links: {:?})",
                    h.link,
                    m.model.name,
                    m.model.links.iter().map(|l| &l.name).collect::<Vec<_>>()
                ),
            ));
        }
    }
    Ok(())
}

/// The rig's model targets and how they move (targets naming no model of `models` are left
/// out; the rig's check refuses them).
pub fn model_motions(file: &RigFile, models: &[RigModel]) -> Vec<ModelMotion> {
    let scale = file.units.metres();
    let Some(spec) = &file.synthetic else {
        return Vec::new();
    };
    spec.targets
        .iter()
        .enumerate()
        .filter_map(|(i, t)| {
            let crate::schema::MotionSpec::Joints {
                base,
                base_rpy_deg,
                swing,
                hide,
            } = &t.motion
            else {
                return None;
            };
            let def = models
                .iter()
                .find(|m| t.model.as_ref() == Some(&m.model.name))?;
            let model = def.model.clone();
            let r = base_rpy_deg.map(f64::to_radians);
            let world_from_root = Isometry3::from_parts(
                Translation3::new(base[0] * scale, base[1] * scale, base[2] * scale),
                UnitQuaternion::from_euler_angles(r[0], r[1], r[2]),
            );
            // Degrees for angles, the file unit for slides, in tree order.
            let units: Vec<f64> = model
                .joints
                .iter()
                .flat_map(|j| {
                    let u = match j.kind {
                        JointKind::Prismatic { .. } => scale,
                        _ => 1f64.to_radians(),
                    };
                    std::iter::repeat_n(u, j.kind.dof())
                })
                .collect();
            let swings = swing
                .iter()
                .zip(&units)
                .map(|(w, u)| stereoscope_kinematics::Swing {
                    centre: w[0] * u,
                    amplitude: w[1] * u,
                    hz: w[2],
                    phase_rad: w[3].to_radians(),
                })
                .collect();
            let hide = hide.as_ref().and_then(|h| {
                let link = model.links.iter().position(|l| l.name == h.link)?;
                Some((link, h.every_s, h.for_s))
            });
            Some(ModelMotion {
                target: i,
                model,
                world_from_root,
                swings,
                hide,
            })
        })
        .collect()
}

/// Every `[[model]]` of the rig, built and checked; `base_dir` is where a URDF's relative path
/// starts.
pub fn build_models(file: &RigFile, base_dir: Option<&Path>) -> Result<Vec<RigModel>, RigError> {
    if file.models.len() > MAX_MODELS {
        return Err(err(
            "model",
            format!(
                "{} models, over the {MAX_MODELS} a rig may have",
                file.models.len()
            ),
        ));
    }
    let m = file.units.metres();
    let mut out: Vec<RigModel> = Vec::with_capacity(file.models.len());
    for (i, s) in file.models.iter().enumerate() {
        if !stereoscope_proto::names::valid_segment(&s.name) {
            return Err(err(
                format!("model[{i}].name"),
                format!(
                    "{:?} must be 1–32 characters of letters, digits, '_' or '-' (it is part of network keys)",
                    s.name
                ),
            ));
        }
        if out.iter().any(|o| o.model.name == s.name)
            || file.bodies.iter().any(|b| b.name == s.name)
        {
            return Err(err(
                format!("model[{i}].name"),
                format!("{:?} is already the name of a body or model", s.name),
            ));
        }
        out.push(model(i, s, m, base_dir)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Rig;

    const THESIS_LAB: &str = include_str!("../../../../deploy/rigs/thesis-lab.toml");

    fn with(model: &str) -> Result<Rig, RigError> {
        Rig::from_toml(&format!("{THESIS_LAB}\n{model}"))
    }

    const KNEE: &str = r#"
[[model]]
name = "knee"
[[model.joint]]
name = "knee"
type = "revolute"
parent = "thigh"
child = "shank"
origin = [0.0, 0.0, -42.0]
axis = [0.0, 1.0, 0.0]
limits = [-5.0, 140.0]
[[model.joint]]
name = "ankle"
type = "universal"
parent = "shank"
child = "foot"
origin = [0.0, 0.0, -41.0]
axes = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
axes_limits_deg = [[-40.0, 40.0], [-30.0, 30.0]]
[[model.marker]]
name = "t1"
link = "thigh"
position = [6.0, -4.0, -15.0]
"#;

    #[test]
    fn a_model_in_the_rig_is_built_in_metres_and_radians() {
        let rig = with(KNEE).unwrap();
        let m = &rig.models[0].model;
        assert_eq!(m.links[0].name, "thigh");
        assert!((m.joints[0].parent_from_joint.translation.z + 0.42).abs() < 1e-12);
        let JointKind::Revolute {
            limits: Some(l), ..
        } = m.joints[0].kind
        else {
            panic!("{:?}", m.joints[0].kind)
        };
        assert!((l.upper - 140f64.to_radians()).abs() < 1e-12);
        assert_eq!(m.joints[1].kind.name(), "universal");
        assert!((m.markers[0].in_link_m.z + 0.15).abs() < 1e-12);
        assert!((rig.models[0].tolerance_m - 0.003).abs() < 1e-15);
    }

    /// A model target's `hide` names a link of its model and hides it `for_s` of every
    /// `every_s`; a link the model lacks, or longer hidden than the period, is refused by key.
    #[test]
    fn a_hidden_link_is_checked_and_hidden_on_its_period() {
        let target = |hide: &str| {
            format!(
                "{KNEE}\n[[synthetic.target]]\nshape = \"model\"\nmodel = \"knee\"\nradius = 7.0\n\
                 motion = {{ kind = \"joints\", base = [0.0, 0.0, 900.0], hide = {hide} }}\n"
            )
        };
        let rig = with(&target("{ link = \"shank\", every_s = 4.0, for_s = 1.0 }")).unwrap();
        let m = model_motions(&rig.spec, &rig.models);
        let shank = m[0].model.links.iter().position(|l| l.name == "shank");
        assert!(shank.is_some());
        assert_eq!(m[0].hidden_at(8.5), shank);
        assert_eq!(m[0].hidden_at(9.5), None);
        assert_eq!(m[0].hidden_at(-3.5), shank);
        let e = with(&target("{ link = \"hand\", every_s = 4.0, for_s = 1.0 }"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("synthetic.target[0].motion.hide.link") && e.contains("\"hand\""),
            "{e}"
        );
        let e = with(&target("{ link = \"shank\", every_s = 1.0, for_s = 2.0 }"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("synthetic.target[0].motion.hide.for_s"), "{e}");
    }

    #[test]
    fn a_urdf_model_reads_its_file_relative_to_the_rig() {
        let dir = std::env::temp_dir().join(format!("stsc-rig-urdf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let urdf = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../../deploy/models/arm6.urdf"
        );
        std::fs::copy(urdf, dir.join("arm6.urdf")).unwrap();
        let text = format!(
            "{THESIS_LAB}\n[[model]]\nname = \"arm\"\nurdf = \"arm6.urdf\"\n[[model.marker]]\nname = \"a\"\nlink = \"forearm\"\nposition = [8.0, 0.0, 10.0]\n"
        );
        let path = dir.join("rig.toml");
        std::fs::write(&path, &text).unwrap();
        let rig = Rig::load(&path).unwrap();
        assert_eq!(rig.models[0].model.name, "arm");
        assert_eq!(rig.models[0].model.joints.len(), 7);
        // A missing file, a marker on no link: named with the key, the file and the value.
        std::fs::write(&path, text.replace("arm6.urdf", "nowhere.urdf")).unwrap();
        let e = Rig::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("model[0].urdf") && e.contains("nowhere.urdf"),
            "{e}"
        );
        std::fs::write(&path, text.replace("\"forearm\"", "\"hand\"")).unwrap();
        let e = Rig::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("model[0].urdf") && e.contains("marker \"a\" is on link \"hand\""),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_bad_model_is_refused_naming_its_key() {
        for (change, key, words) in [
            (
                ("type = \"revolute\"", "type = \"hinge\""),
                "model[0].joint[0].type",
                "\"hinge\" is not a joint type",
            ),
            (
                ("axis = [0.0, 1.0, 0.0]\n", ""),
                "model[0].joint[0].axis",
                "needs an axis",
            ),
            (
                ("limits = [-5.0, 140.0]", "limits = [140.0, -5.0]"),
                "model[0].joint[0].limits",
                "lower ≤ upper",
            ),
            (
                (
                    "axes = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]",
                    "axes = [[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]",
                ),
                "model[0]",
                "must not be parallel",
            ),
            (
                ("link = \"thigh\"", "link = \"hip\""),
                "model[0]",
                "marker \"t1\" is on link \"hip\"",
            ),
            (
                (
                    "name = \"knee\"\n[[model.joint]]",
                    "name = \"a/b\"\n[[model.joint]]",
                ),
                "model[0].name",
                "network keys",
            ),
        ] {
            let e = with(&KNEE.replacen(change.0, change.1, 1))
                .unwrap_err()
                .to_string();
            assert!(e.contains(key) && e.contains(words), "{change:?}: {e}");
        }
        let both = KNEE.replace(
            "name = \"knee\"\n[[model.joint]]",
            "name = \"knee\"\nurdf = \"x.urdf\"\n[[model.joint]]",
        );
        let e = with(&both).unwrap_err().to_string();
        assert!(e.contains("not both"), "{e}");
    }
}
