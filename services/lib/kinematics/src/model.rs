//! An articulated model: a tree of links joined by joints, markers fixed on links. The thesis's
//! robot of §5.3 (Figs. 5.10–5.11) is such a tree with markers ("OSVEs") on its links; its
//! "link length and link direction" are the joints' origins and axes here.
//!
//! Frames: each link has its own frame; a joint's `parent_from_joint` places the joint's frame
//! in its parent link's frame, and the child link's frame is the joint's frame moved by the
//! joint's value (rotated about the axis, slid along it, ...): `parent_from_child =
//! parent_from_joint * motion(value)`. The root link is placed in the world by a floating base
//! (six degrees of freedom, fitted every frame) or a fixed pose. Units: metres and radians.

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

/// Joint limits, lower ≤ upper (radians for angles, metres for slides).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub lower: f64,
    pub upper: f64,
}

impl Limits {
    pub fn clamp(self, v: f64) -> f64 {
        v.clamp(self.lower, self.upper)
    }
}

/// What a joint lets its child link do relative to its parent.
#[derive(Debug, Clone, PartialEq)]
pub enum JointKind {
    /// No motion (a link bolted on).
    Fixed,
    /// A hinge: one angle about `axis` (in the joint's frame); `limits` `None` is URDF's
    /// `continuous`.
    Revolute {
        axis: Unit<Vector3<f64>>,
        limits: Option<Limits>,
    },
    /// A slide along `axis`.
    Prismatic {
        axis: Unit<Vector3<f64>>,
        limits: Option<Limits>,
    },
    /// Two hinges through one point: `angle[0]` about `axes[0]`, then `angle[1]` about
    /// `axes[1]` as carried by the first (an ankle, a Cardan joint).
    Universal {
        axes: [Unit<Vector3<f64>>; 2],
        limits: [Option<Limits>; 2],
    },
    /// A ball joint: any rotation about the joint's origin (a hip).
    Spherical,
}

impl JointKind {
    /// Degrees of freedom the fit solves for.
    pub fn dof(&self) -> usize {
        match self {
            JointKind::Fixed => 0,
            JointKind::Revolute { .. } | JointKind::Prismatic { .. } => 1,
            JointKind::Universal { .. } => 2,
            JointKind::Spherical => 3,
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            JointKind::Fixed => "fixed",
            JointKind::Revolute { limits: None, .. } => "continuous",
            JointKind::Revolute { .. } => "revolute",
            JointKind::Prismatic { .. } => "prismatic",
            JointKind::Universal { .. } => "universal",
            JointKind::Spherical => "spherical",
        }
    }
}

/// A joint's value: what the fit reports and the renderer moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum JointValue {
    Fixed,
    /// Radians, not wrapped: a continuous joint turned twice reads 4π.
    Angle(f64),
    /// Metres.
    Offset(f64),
    /// Radians about the first axis, then the second.
    Angles([f64; 2]),
    /// The child's rotation about the joint's origin, in the joint's frame.
    Rotation(UnitQuaternion<f64>),
}

impl JointValue {
    /// The value of no motion for a joint of this kind.
    pub fn zero(kind: &JointKind) -> JointValue {
        match kind {
            JointKind::Fixed => JointValue::Fixed,
            JointKind::Revolute { .. } => JointValue::Angle(0.0),
            JointKind::Prismatic { .. } => JointValue::Offset(0.0),
            JointKind::Universal { .. } => JointValue::Angles([0.0; 2]),
            JointKind::Spherical => JointValue::Rotation(UnitQuaternion::identity()),
        }
    }

    /// The motion the value makes: the joint's frame to the child link's.
    pub fn motion(&self, kind: &JointKind) -> Isometry3<f64> {
        match (kind, self) {
            (JointKind::Revolute { axis, .. }, JointValue::Angle(a)) => Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(axis, *a),
            ),
            (JointKind::Prismatic { axis, .. }, JointValue::Offset(d)) => Isometry3::from_parts(
                Translation3::from(axis.into_inner() * *d),
                UnitQuaternion::identity(),
            ),
            (JointKind::Universal { axes, .. }, JointValue::Angles([a, b])) => {
                Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&axes[0], *a)
                        * UnitQuaternion::from_axis_angle(&axes[1], *b),
                )
            }
            (JointKind::Spherical, JointValue::Rotation(q)) => {
                Isometry3::from_parts(Translation3::identity(), *q)
            }
            _ => Isometry3::identity(),
        }
    }
}

/// A joint: `child` link moved relative to `parent` link.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    pub name: String,
    pub parent: usize,
    pub child: usize,
    pub parent_from_joint: Isometry3<f64>,
    pub kind: JointKind,
}

/// A link; `joint` is the joint that carries it (`None` for the root).
#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    pub name: String,
    pub joint: Option<usize>,
}

/// A marker fixed on a link, at `in_link_m` in the link's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    pub name: String,
    pub link: usize,
    pub in_link_m: Point3<f64>,
}

/// How the root link is placed in the world.
#[derive(Debug, Clone, PartialEq)]
pub enum Base {
    /// Fitted every frame (six degrees of freedom): a limb, or a robot whose place in the
    /// capture volume is not surveyed.
    Floating,
    /// Surveyed: the root's pose in the world.
    Fixed(Isometry3<f64>),
}

/// A model that cannot be used, naming the element and the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("model {model:?}: {what} {name:?} is named twice")]
    Duplicate {
        model: String,
        what: &'static str,
        name: String,
    },
    #[error(
        "model {model:?}: joint {joint:?} names {what} link {link:?}, which the model does not have"
    )]
    NoSuchLink {
        model: String,
        joint: String,
        what: &'static str,
        link: String,
    },
    #[error(
        "model {model:?}: marker {marker:?} is on link {link:?}, which the model does not have"
    )]
    MarkerOnNoLink {
        model: String,
        marker: String,
        link: String,
    },
    #[error("model {model:?}: link {link:?} is the child of joints {first:?} and {second:?}")]
    TwoParents {
        model: String,
        link: String,
        first: String,
        second: String,
    },
    #[error(
        "model {model:?}: {count} links have no parent joint ({links:?}); a model has one root"
    )]
    Roots {
        model: String,
        count: usize,
        links: Vec<String>,
    },
    #[error("model {model:?}: joints {joints:?} form a loop; a model is a tree")]
    Loop { model: String, joints: Vec<String> },
    #[error("model {model:?}: joint {joint:?}: {what} {value}")]
    BadJoint {
        model: String,
        joint: String,
        what: &'static str,
        value: String,
    },
    #[error("model {model:?}: marker {marker:?}: position {value:?} is not finite")]
    BadMarker {
        model: String,
        marker: String,
        value: [f64; 3],
    },
    #[error("model {model:?} has no link")]
    Empty { model: String },
    #[error(
        "model {model:?}: {what} name {name:?} must be 1–{MAX_PART_NAME_BYTES} bytes without commas, quotes, spaces or control characters (it labels exports' columns and messages)"
    )]
    BadName {
        model: String,
        what: &'static str,
        name: String,
    },
}

/// The longest link, joint or marker name (a message's name limit).
pub const MAX_PART_NAME_BYTES: usize = 64;

/// Whether `name` can label a CSV column, a C3D point and a message field as it is.
fn usable_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_PART_NAME_BYTES
        && !name
            .chars()
            .any(|c| c.is_control() || c.is_whitespace() || matches!(c, ',' | '"' | '\''))
}

/// A checked model: links in tree order (every joint's parent before its child), each
/// link's path of joints from the root precomputed.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub name: String,
    pub links: Vec<Link>,
    /// In tree order: a joint comes after the joint carrying its parent.
    pub joints: Vec<Joint>,
    pub markers: Vec<Marker>,
    pub base: Base,
    /// For each link, the joints from the root to it, root first.
    paths: Vec<Vec<usize>>,
}

/// A joint as described by a file, links by name.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSpec {
    pub name: String,
    pub parent: String,
    pub child: String,
    pub parent_from_joint: Isometry3<f64>,
    pub kind: JointKind,
}

/// A marker as described by a file, its link by name.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerSpec {
    pub name: String,
    pub link: String,
    pub in_link_m: [f64; 3],
}

fn finite_iso(i: &Isometry3<f64>) -> bool {
    i.translation.vector.iter().all(|v| v.is_finite())
        && i.rotation.coords.iter().all(|v| v.is_finite())
}

fn check_limits(model: &str, joint: &str, l: &Option<Limits>) -> Result<(), ModelError> {
    if let Some(l) = l
        && !(l.lower.is_finite() && l.upper.is_finite() && l.lower <= l.upper)
    {
        return Err(ModelError::BadJoint {
            model: model.into(),
            joint: joint.into(),
            what: "limits must be finite with lower ≤ upper, not",
            value: format!("{} to {}", l.lower, l.upper),
        });
    }
    Ok(())
}

impl Model {
    /// Checks and orders a model given by link names, joints and markers. `links` lists every
    /// link (URDF lists links apart from joints); a link no joint names is the root, and there
    /// must be exactly one.
    pub fn new(
        name: &str,
        links: &[String],
        joints: &[JointSpec],
        markers: &[MarkerSpec],
        base: Base,
    ) -> Result<Model, ModelError> {
        let model = name.to_string();
        if links.is_empty() {
            return Err(ModelError::Empty { model });
        }
        let names = links
            .iter()
            .map(|l| ("link", l))
            .chain(joints.iter().map(|j| ("joint", &j.name)))
            .chain(markers.iter().map(|k| ("marker", &k.name)));
        for (what, n) in names {
            if !usable_name(n) {
                return Err(ModelError::BadName {
                    model,
                    what,
                    name: n.clone(),
                });
            }
        }
        let mut index = std::collections::HashMap::new();
        for (i, l) in links.iter().enumerate() {
            if index.insert(l.as_str(), i).is_some() {
                return Err(ModelError::Duplicate {
                    model,
                    what: "link",
                    name: l.clone(),
                });
            }
        }
        let mut joint_names = std::collections::HashSet::new();
        let mut parent_joint: Vec<Option<usize>> = vec![None; links.len()];
        for (j, s) in joints.iter().enumerate() {
            if !joint_names.insert(s.name.as_str()) {
                return Err(ModelError::Duplicate {
                    model,
                    what: "joint",
                    name: s.name.clone(),
                });
            }
            for (what, l) in [("parent", &s.parent), ("child", &s.child)] {
                if !index.contains_key(l.as_str()) {
                    return Err(ModelError::NoSuchLink {
                        model,
                        joint: s.name.clone(),
                        what,
                        link: l.clone(),
                    });
                }
            }
            if !finite_iso(&s.parent_from_joint) {
                return Err(ModelError::BadJoint {
                    model,
                    joint: s.name.clone(),
                    what: "origin is not finite:",
                    value: format!("{:?}", s.parent_from_joint),
                });
            }
            match &s.kind {
                JointKind::Revolute { axis, limits } | JointKind::Prismatic { axis, limits } => {
                    if !axis.iter().all(|v| v.is_finite()) {
                        return Err(ModelError::BadJoint {
                            model,
                            joint: s.name.clone(),
                            what: "axis is not finite:",
                            value: format!("{:?}", axis.as_slice()),
                        });
                    }
                    check_limits(name, &s.name, limits)?;
                }
                JointKind::Universal { axes, limits } => {
                    let cross = axes[0].cross(&axes[1]).norm();
                    if !cross.is_finite() || cross < 1e-3 {
                        return Err(ModelError::BadJoint {
                            model,
                            joint: s.name.clone(),
                            what: "a universal joint's two axes must not be parallel:",
                            value: format!("{:?} and {:?}", axes[0].as_slice(), axes[1].as_slice()),
                        });
                    }
                    for l in limits {
                        check_limits(name, &s.name, l)?;
                    }
                }
                JointKind::Fixed | JointKind::Spherical => {}
            }
            let child = index[s.child.as_str()];
            if let Some(first) = parent_joint[child] {
                return Err(ModelError::TwoParents {
                    model,
                    link: s.child.clone(),
                    first: joints[first].name.clone(),
                    second: s.name.clone(),
                });
            }
            parent_joint[child] = Some(j);
        }
        let roots: Vec<usize> = (0..links.len())
            .filter(|&l| parent_joint[l].is_none())
            .collect();
        if roots.len() != 1 {
            return Err(ModelError::Roots {
                model,
                count: roots.len(),
                links: roots.iter().map(|&l| links[l].clone()).collect(),
            });
        }
        // Tree order: breadth first from the root; a joint never reached is in a loop.
        let mut order_links = vec![roots[0]];
        let mut order_joints = Vec::new();
        let mut k = 0;
        while k < order_links.len() {
            let l = order_links[k];
            for (j, s) in joints.iter().enumerate() {
                if index[s.parent.as_str()] == l {
                    order_joints.push(j);
                    order_links.push(index[s.child.as_str()]);
                }
            }
            k += 1;
        }
        if order_joints.len() != joints.len() {
            let reached: std::collections::HashSet<usize> = order_joints.iter().copied().collect();
            return Err(ModelError::Loop {
                model,
                joints: (0..joints.len())
                    .filter(|j| !reached.contains(j))
                    .map(|j| joints[j].name.clone())
                    .collect(),
            });
        }
        // Renumber: links and joints in tree order.
        let mut link_at = vec![0; links.len()];
        for (new, &old) in order_links.iter().enumerate() {
            link_at[old] = new;
        }
        let new_links: Vec<Link> = order_links
            .iter()
            .map(|&old| Link {
                name: links[old].clone(),
                joint: None,
            })
            .collect();
        let mut m = Model {
            name: name.to_string(),
            links: new_links,
            joints: Vec::with_capacity(joints.len()),
            markers: Vec::with_capacity(markers.len()),
            base,
            paths: Vec::new(),
        };
        for &old in &order_joints {
            let s = &joints[old];
            let child = link_at[index[s.child.as_str()]];
            m.links[child].joint = Some(m.joints.len());
            m.joints.push(Joint {
                name: s.name.clone(),
                parent: link_at[index[s.parent.as_str()]],
                child,
                parent_from_joint: s.parent_from_joint,
                kind: s.kind.clone(),
            });
        }
        let mut marker_names = std::collections::HashSet::new();
        for s in markers {
            if !marker_names.insert(s.name.as_str()) {
                return Err(ModelError::Duplicate {
                    model: m.name,
                    what: "marker",
                    name: s.name.clone(),
                });
            }
            let Some(&l) = index.get(s.link.as_str()) else {
                return Err(ModelError::MarkerOnNoLink {
                    model: m.name,
                    marker: s.name.clone(),
                    link: s.link.clone(),
                });
            };
            if !s.in_link_m.iter().all(|v| v.is_finite()) {
                return Err(ModelError::BadMarker {
                    model: m.name,
                    marker: s.name.clone(),
                    value: s.in_link_m,
                });
            }
            m.markers.push(Marker {
                name: s.name.clone(),
                link: link_at[l],
                in_link_m: Point3::from(s.in_link_m),
            });
        }
        m.paths = (0..m.links.len())
            .map(|l| {
                let mut path = Vec::new();
                let mut at = l;
                while let Some(j) = m.links[at].joint {
                    path.push(j);
                    at = m.joints[j].parent;
                }
                path.reverse();
                path
            })
            .collect();
        Ok(m)
    }

    /// The joints from the root to `link`, root first.
    pub fn path(&self, link: usize) -> &[usize] {
        &self.paths[link]
    }

    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// The joints as a file would describe them (links by name): to build the model again
    /// with other markers.
    pub fn joint_specs(&self) -> Vec<JointSpec> {
        self.joints
            .iter()
            .map(|j| JointSpec {
                name: j.name.clone(),
                parent: self.links[j.parent].name.clone(),
                child: self.links[j.child].name.clone(),
                parent_from_joint: j.parent_from_joint,
                kind: j.kind.clone(),
            })
            .collect()
    }

    /// Every joint at no motion.
    pub fn zero(&self) -> Vec<JointValue> {
        self.joints
            .iter()
            .map(|j| JointValue::zero(&j.kind))
            .collect()
    }

    /// Each link's pose in the world (`world_from_link`), given the root's and every joint's
    /// value (the model's forward kinematics).
    pub fn forward(
        &self,
        world_from_root: &Isometry3<f64>,
        values: &[JointValue],
        out: &mut Vec<Isometry3<f64>>,
    ) {
        out.clear();
        out.resize(self.links.len(), Isometry3::identity());
        out[0] = *world_from_root;
        for (j, joint) in self.joints.iter().enumerate() {
            let v = values.get(j).copied().unwrap_or(JointValue::Fixed);
            out[joint.child] = out[joint.parent] * joint.parent_from_joint * v.motion(&joint.kind);
        }
    }

    /// Every marker's place in the world for the given link poses.
    pub fn marker_positions(&self, world_from_link: &[Isometry3<f64>]) -> Vec<Point3<f64>> {
        self.markers
            .iter()
            .map(|m| world_from_link[m.link] * m.in_link_m)
            .collect()
    }
}

/// A URDF `origin`'s roll, pitch and yaw (fixed axes x, y, z) as a rotation.
pub fn rpy(roll: f64, pitch: f64, yaw: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(roll, pitch, yaw)
}

/// One degree of freedom's scripted motion: `centre + amplitude · sin(2π · hz · t + phase)`
/// (radians for angles, metres for slides; a ball joint's three degrees of freedom are the
/// components of its rotation vector).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Swing {
    pub centre: f64,
    pub amplitude: f64,
    pub hz: f64,
    pub phase_rad: f64,
}

impl Model {
    /// Degrees of freedom of all joints, in tree order.
    pub fn dof(&self) -> usize {
        self.joints.iter().map(|j| j.kind.dof()).sum()
    }

    /// Every joint's value at `t_s` from one swing per degree of freedom in tree order (missing
    /// ones at zero), within each joint's limits: the synthetic scenes' truth.
    pub fn swing_values(&self, swings: &[Swing], t_s: f64) -> Vec<JointValue> {
        let mut k = 0;
        let mut next = || {
            let v = swings.get(k).map_or(0.0, |s| {
                s.centre + s.amplitude * (std::f64::consts::TAU * s.hz * t_s + s.phase_rad).sin()
            });
            k += 1;
            v
        };
        let clamp = |l: &Option<Limits>, v: f64| l.map_or(v, |l| l.clamp(v));
        self.joints
            .iter()
            .map(|j| match &j.kind {
                JointKind::Fixed => JointValue::Fixed,
                JointKind::Revolute { limits, .. } => JointValue::Angle(clamp(limits, next())),
                JointKind::Prismatic { limits, .. } => JointValue::Offset(clamp(limits, next())),
                JointKind::Universal { limits, .. } => {
                    let a = clamp(&limits[0], next());
                    let b = clamp(&limits[1], next());
                    JointValue::Angles([a, b])
                }
                JointKind::Spherical => {
                    let v = Vector3::new(next(), next(), next());
                    JointValue::Rotation(UnitQuaternion::from_scaled_axis(v))
                }
            })
            .collect()
    }
}
