//! A model's markers and measured geometry from a range-of-motion recording (`stereoscope
//! model define`, `docs/models.md` "Defining a model"): the thesis's "full kinematic
//! information about the robot, including link length and link direction" (§5.3), found from
//! the markers' motion instead of assumed.
//!
//! Given a skeleton (a model's links and joints, from URDF or the rig; its markers ignored), the
//! tracked markers of a take that moves every joint, and a take of the model standing still at
//! its zero pose:
//!
//! 1. **Links from motion**: markers whose distances to each other stay constant (standard
//!    deviation below a tolerance) are one rigid cluster; each cluster's shape is averaged and
//!    its pose found every frame (Kabsch).
//! 2. **Joints from motion**: for two clusters a, b the point fixed in both,
//!    `R_a·c_a + t_a = R_b·c_b + t_b` over all frames, is a linear least-squares problem in
//!    (c_a, c_b) — the SCoRE centre of a ball joint (Ehrig et al. 2006). For a hinge the
//!    system's least singular direction `(n_a, n_b)` is the axis, fixed in both links (SARA,
//!    Ehrig et al. 2007), and the rest of the solution a point on it.
//! 3. **Which cluster is which link**: every assignment of clusters to the skeleton's links
//!    (links bolted together by fixed joints count as one) is scored by the SCoRE/SARA
//!    residuals of the skeleton's joints; the few best are told apart by how well the
//!    skeleton's zero pose registers onto the joints measured in the zero-pose take.
//! 4. **Markers on links**: at the zero pose every link's frame is the skeleton's forward
//!    kinematics from the registered root, so each cluster's markers are placed in its link's
//!    frame.
//! 5. **Link lengths and directions**: on each link, the distance between its joints' axes or
//!    centres as measured (in the cluster's frame) and as the skeleton has them, and the
//!    angle between two hinge axes.
//!
//! Prismatic joints are not found (a slide has no fixed point). Units: metres and radians.

use crate::model::{JointKind, MarkerSpec, Model, ModelError};
mod clusters;
mod joints;

pub use clusters::split_at_gaps;
use clusters::*;
use joints::*;
use nalgebra::{Isometry3, Point3, Vector3};

/// One marker's track through the recording: its position in each frame, `None` where it was
/// not seen. Every track has one entry per frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    pub id: u32,
    pub points: Vec<Option<Point3<f64>>>,
}

/// The definition's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DefineOptions {
    /// Two markers are on one link when their distance varies by less than this (standard
    /// deviation, metres).
    pub rigid_tolerance_m: f64,
    /// A track seen in fewer than this share of the frames is left out.
    pub min_share: f64,
}

impl Default for DefineOptions {
    fn default() -> Self {
        DefineOptions {
            rigid_tolerance_m: 0.0015,
            min_share: 0.02,
        }
    }
}

/// A group of markers that moved together in a recording (`moved_together`).
#[derive(Debug, Clone, PartialEq)]
pub struct MovedTogether {
    /// The tracks' ids (fusion's object ids), ascending.
    pub ids: Vec<u32>,
    /// Frames in which every one of them was seen.
    pub frames_together: usize,
    /// How far the group went from where it was first seen whole (its centroid), metres.
    pub travel_m: f64,
}

/// A group that went less far than this did not move: markers standing still keep their
/// distances as well as a body's do.
pub const MIN_TRAVEL_M: f64 = 0.05;

/// The markers that moved together in a recording (a body to define, `stereoscope body
/// define --session`): tracks whose distances stayed within `opts.rigid_tolerance_m` while
/// anything moved (the same grouping as a model's links, [`define_model`]), in groups of 3 or
/// more that travelled [`MIN_TRAVEL_M`] or further; the largest group first.
pub fn moved_together(tracks: &[Track], opts: &DefineOptions) -> Vec<MovedTogether> {
    let frames = tracks.first().map_or(0, |t| t.points.len());
    if frames == 0 || tracks.iter().any(|t| t.points.len() != frames) {
        return Vec::new();
    }
    let still = still_frames(tracks, frames, opts.rigid_tolerance_m);
    let keep: Vec<usize> = (0..tracks.len()).collect();
    let mut out: Vec<MovedTogether> = rigid_groups(tracks, &keep, opts.rigid_tolerance_m, &still)
        .into_iter()
        .filter_map(|g| {
            let centroids: Vec<Vector3<f64>> = (0..frames)
                .filter_map(|f| {
                    let ps: Option<Vec<Point3<f64>>> =
                        g.iter().map(|&t| tracks[t].points[f]).collect();
                    ps.map(|ps| ps.iter().map(|p| p.coords).sum::<Vector3<f64>>() / ps.len() as f64)
                })
                .collect();
            let first = centroids.first()?;
            let travel_m = centroids
                .iter()
                .map(|c| (c - first).norm())
                .fold(0.0, f64::max);
            let mut ids: Vec<u32> = g.iter().map(|&t| tracks[t].id).collect();
            ids.sort_unstable();
            (travel_m >= MIN_TRAVEL_M).then_some(MovedTogether {
                ids,
                frames_together: centroids.len(),
                travel_m,
            })
        })
        .collect();
    out.sort_by(|a, b| {
        b.ids
            .len()
            .cmp(&a.ids.len())
            .then(b.travel_m.total_cmp(&a.travel_m))
    });
    out
}

/// Why no model could be defined.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DefineError {
    #[error(
        "{frames} frames of motion and {home} at the zero pose: a definition needs 60 or more of motion and 3 or more at the zero pose"
    )]
    TooShort { frames: usize, home: usize },
    #[error(
        "the zero-pose take moved in {moving} of its {frames} frames: record it with the model standing still"
    )]
    HomeMoved { moving: usize, frames: usize },
    #[error(
        "model {model:?}: joint {joint:?} is {kind}; `model define` finds revolute, continuous, universal and spherical joints"
    )]
    Unsupported {
        model: String,
        joint: String,
        kind: &'static str,
    },
    #[error(
        "the recording shows {found} rigid clusters of 3 or more markers ({clusters}); model {model:?} has {links} links moving apart ({names}): every such link needs 3 markers that move with it, and every joint must move"
    )]
    Clusters {
        model: String,
        found: usize,
        clusters: String,
        links: usize,
        names: String,
    },
    #[error("model {model:?}: {links} links moving apart; `model define` assigns up to 9")]
    TooMany { model: String, links: usize },
    #[error(
        "cluster of markers {ids:?} is not rigid: its markers sit {rms_mm:.1} mm RMS off their mean shape and {outliers_pct:.0} % of their sightings are farther off (two links joined where markers keep their distance?)"
    )]
    NotRigid {
        ids: Vec<u32>,
        rms_mm: f64,
        outliers_pct: f64,
    },
    #[error(
        "no assignment of the clusters to model {model:?}'s links fits its joints: clusters {a} and {b} were never seen together in 20 frames"
    )]
    NoAssignment { model: String, a: usize, b: usize },
    #[error(
        "link {link:?} (markers {ids:?} in the motion take) was found by its markers' shape in fewer than 3 of the {home} frames of the zero-pose take"
    )]
    NoHome {
        link: String,
        ids: Vec<u32>,
        home: usize,
    },
    #[error(
        "model {model:?}: its joints' axes and centres do not fix the root's orientation (all parallel, or fewer than two)"
    )]
    NoOrientation { model: String },
    #[error("{0}")]
    Model(#[from] ModelError),
}

/// A joint as found.
#[derive(Debug, Clone, PartialEq)]
pub struct JointFound {
    pub name: String,
    pub kind: &'static str,
    /// RMS over frames of the distance between the centre (or the axis point) as carried by
    /// the parent link and as carried by the child link, metres.
    pub residual_m: f64,
    /// For a hinge: RMS angle between the axis as carried by each link, radians.
    pub axis_residual_rad: Option<f64>,
    /// Frames in which both links were posed.
    pub frames: usize,
    /// Where the registered skeleton's joint is from the measured one at the zero pose: the
    /// centre's distance, or the axis point's distance from the measured axis, metres.
    pub registration_m: f64,
    /// The angle between the registered skeleton's axis and the measured one, radians.
    pub registration_rad: Option<f64>,
}

/// A distance on one link between two of its joints, measured and in the skeleton.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkLength {
    pub link: String,
    pub from_joint: String,
    pub to_joint: String,
    /// Axis to axis (the common normal; parallel axes: their distance), axis to centre, or
    /// centre to centre, metres.
    pub measured_m: f64,
    pub model_m: f64,
    /// Between two hinge axes: the angle, radians (0 to π/2).
    pub measured_angle_rad: Option<f64>,
    pub model_angle_rad: Option<f64>,
}

/// The markers of one link.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkMarkers {
    pub link: String,
    /// Each marker's share of the take's frames in which it was found.
    pub seen_share: Vec<f64>,
    /// The markers' RMS distance from their mean shape, metres.
    pub shape_rms_m: f64,
}

/// What the definition found.
#[derive(Debug, Clone, PartialEq)]
pub struct Defined {
    /// The skeleton with the markers found.
    pub model: Model,
    /// The markers, in their links' frames (names `<link>_<k>`).
    pub markers: Vec<MarkerSpec>,
    /// Per marker, its point in each frame of the take (found by its link's shape).
    pub observations: Vec<Vec<Option<Point3<f64>>>>,
    pub links: Vec<LinkMarkers>,
    pub joints: Vec<JointFound>,
    pub lengths: Vec<LinkLength>,
    /// The root's pose at the zero pose.
    pub world_from_root_home: Isometry3<f64>,
    /// Tracks left out (seen too seldom, or on no rigid cluster of 3).
    pub left_out: Vec<u32>,
}

/// The assignment chosen: its total cost, clusters per body, the root's pose at the zero
/// pose, the joints measured, and each joint's registration (distance, angle).
type Chosen = (
    f64,
    Vec<usize>,
    Isometry3<f64>,
    Vec<JointMeasure>,
    Vec<(f64, Option<f64>)>,
);

/// Defines `skeleton`'s markers (and measures its geometry) from `tracks` of a take that moves
/// every joint, and `home`, a take of it standing still at its zero pose (the same cameras,
/// the same place).
pub fn define_model(
    skeleton: &Model,
    tracks: &[Track],
    home: &[Track],
    opts: &DefineOptions,
) -> Result<Defined, DefineError> {
    let frames = tracks.iter().map(|t| t.points.len()).min().unwrap_or(0);
    let home_frames = home.iter().map(|t| t.points.len()).min().unwrap_or(0);
    if frames < 60 || home_frames < 3 {
        return Err(DefineError::TooShort {
            frames,
            home: home_frames,
        });
    }
    let home_still = still_frames(home, home_frames, opts.rigid_tolerance_m);
    let moving = home_still.iter().filter(|s| !**s).count();
    if moving * 5 > home_frames {
        return Err(DefineError::HomeMoved {
            moving,
            frames: home_frames,
        });
    }
    for j in &skeleton.joints {
        if matches!(j.kind, JointKind::Prismatic { .. }) {
            return Err(DefineError::Unsupported {
                model: skeleton.name.clone(),
                joint: j.name.clone(),
                kind: j.kind.name(),
            });
        }
    }
    let bodies = bodies(skeleton);
    let nb = bodies.main_link.len();
    if nb > 9 {
        return Err(DefineError::TooMany {
            model: skeleton.name.clone(),
            links: nb,
        });
    }
    let tracks = &split_at_gaps(tracks, frames, MAX_GAP_FRAMES, MAX_JUMP_M);
    let need = (frames as f64 * opts.min_share).ceil() as usize;
    let keep: Vec<usize> = (0..tracks.len())
        .filter(|&t| tracks[t].points[..frames].iter().flatten().count() >= need.max(20))
        .collect();
    let still = still_frames(tracks, frames, opts.rigid_tolerance_m);
    let groups = rigid_groups(tracks, &keep, opts.rigid_tolerance_m, &still);
    let merge_m = 4.0 * opts.rigid_tolerance_m.max(0.001);
    let outlier_m = OUTLIER_TOLERANCES * opts.rigid_tolerance_m;
    let clusters: Vec<Cluster> = groups
        .iter()
        .filter_map(|g| {
            // A piece off its place in most frames its cluster is posed in is not of it (an
            // id that passed between links): left out, and the rest built again.
            let mut group = g.clone();
            for _ in 0..4 {
                let c = build_cluster(tracks, &group, frames, merge_m, outlier_m, None);
                let bad: Vec<usize> = c
                    .markers
                    .iter()
                    .zip(&c.marker_outliers)
                    .filter(|(_, o)| **o > 0.5)
                    .flat_map(|(m, _)| m.iter().copied())
                    .collect();
                if c.markers.len() < 3 {
                    return None;
                }
                if bad.is_empty() {
                    return Some(c);
                }
                group.retain(|t| !bad.contains(t));
                if group.len() < 3 {
                    return None;
                }
            }
            Some(build_cluster(
                tracks, &group, frames, merge_m, outlier_m, None,
            ))
        })
        .collect();
    let absorb_loose = |clusters| {
        absorb(
            tracks,
            clusters,
            &keep,
            &still,
            frames,
            opts.rigid_tolerance_m,
            merge_m,
            outlier_m,
        )
    };
    let clusters = absorb_loose(clusters);
    let clusters = join_time_apart(
        tracks,
        clusters,
        frames,
        2.0 * opts.rigid_tolerance_m,
        merge_m,
        outlier_m,
    );
    let clusters = absorb_loose(clusters);
    for c in &clusters {
        if c.shape_rms_m > 3.0 * opts.rigid_tolerance_m || c.outliers > 0.25 {
            return Err(DefineError::NotRigid {
                ids: c.markers.iter().flatten().map(|&t| tracks[t].id).collect(),
                rms_mm: c.shape_rms_m * 1e3,
                outliers_pct: c.outliers * 100.0,
            });
        }
    }
    let (clusters, used_track) = by_shape(
        tracks,
        clusters,
        &still,
        frames,
        opts.rigid_tolerance_m,
        merge_m,
    );
    let ids_of = |c: &Cluster| -> Vec<u32> {
        c.markers
            .iter()
            .map(|m| m.iter().map(|&t| tracks[t].id).min().unwrap_or(0))
            .collect()
    };
    if clusters.len() != nb {
        return Err(DefineError::Clusters {
            model: skeleton.name.clone(),
            found: clusters.len(),
            clusters: clusters
                .iter()
                .map(|c| format!("{:?}", ids_of(c)))
                .collect::<Vec<_>>()
                .join(", "),
            links: nb,
            names: bodies
                .main_link
                .iter()
                .map(|&l| skeleton.links[l].name.clone())
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    // Each movable joint's cost for every ordered pair of clusters.
    let hinge_of = |j: usize| matches!(skeleton.joints[j].kind, JointKind::Revolute { .. });
    let mut cost = vec![vec![[f64::INFINITY; 2]; nb]; nb];
    for a in 0..nb {
        for b in 0..nb {
            if a == b {
                continue;
            }
            for (h, slot) in [false, true].into_iter().zip(0..2) {
                let m = measure(&clusters[a], &clusters[b], h);
                if m.frames >= 20 {
                    cost[a][b][slot] = m.cost();
                }
            }
        }
    }
    // Every assignment of clusters to bodies, by the joints' summed cost; keep the best few.
    let mut candidates: Vec<(f64, Vec<usize>)> = Vec::new();
    let mut assign = vec![usize::MAX; nb];
    let mut used = vec![false; nb];
    search(
        &bodies,
        &cost,
        &hinge_of,
        0,
        0.0,
        &mut assign,
        &mut used,
        &mut candidates,
    );
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
    let Some(best_cost) = candidates.first().map(|c| c.0) else {
        return Err(DefineError::NoAssignment {
            model: skeleton.name.clone(),
            a: 0,
            b: 1,
        });
    };
    if !best_cost.is_finite() {
        return Err(DefineError::NoAssignment {
            model: skeleton.name.clone(),
            a: 0,
            b: 1,
        });
    }
    // The skeleton at its zero pose, in the root's frame.
    let mut root_from_link = Vec::new();
    skeleton.forward(
        &Isometry3::identity(),
        &skeleton.zero(),
        &mut root_from_link,
    );
    let model_feature = |j: usize| -> Feature {
        let joint = &skeleton.joints[j];
        let frame = root_from_link[joint.parent] * joint.parent_from_joint;
        match &joint.kind {
            JointKind::Revolute { axis, .. } => {
                Feature::Axis(frame * Point3::origin(), frame * axis.into_inner())
            }
            _ => Feature::Centre(frame * Point3::origin()),
        }
    };
    let model_features: Vec<Feature> = bodies
        .joints
        .iter()
        .map(|&(j, _, _)| model_feature(j))
        .collect();
    // Each cluster's pose at the zero pose: the home take stands still, so each of its tracks is
    // averaged to one point, and each cluster's shape is placed on those points (the placing
    // of most markers within tolerance, then least residual; a mirror-image labelling leaves
    // a large residual, so a symmetric-looking cluster is placed right).
    let home_points: Vec<Point3<f64>> = home
        .iter()
        .filter_map(|t| {
            let seen: Vec<Point3<f64>> =
                t.points[..home_frames].iter().flatten().copied().collect();
            (seen.len() * 2 >= home_frames).then(|| {
                Point3::from(
                    seen.iter().map(|p| p.coords).sum::<Vector3<f64>>() / seen.len() as f64,
                )
            })
        })
        .collect();
    let home_poses: Vec<Option<Isometry3<f64>>> = clusters
        .iter()
        .map(|c| place_shape(&c.shape, &home_points, 2.0 * opts.rigid_tolerance_m))
        .collect();
    let home = home_poses;
    let mut chosen: Option<Chosen> = None;
    for (c, assignment) in candidates.iter().take(16) {
        if *c > 2.0 * best_cost + 0.002 {
            break;
        }
        let mut measures = Vec::new();
        let mut measured = Vec::new();
        let mut all_home = true;
        for &(j, pb, cb) in &bodies.joints {
            let (a, b) = (assignment[pb], assignment[cb]);
            let m = measure(&clusters[a], &clusters[b], hinge_of(j));
            match home[a] {
                Some(h) => measured.push(m.in_a.transformed(&h)),
                None => all_home = false,
            }
            measures.push(m);
        }
        if !all_home || assignment.iter().any(|&c| home[c].is_none()) {
            continue;
        }
        for reg in register(&model_features, &measured) {
            // A registration that puts a hinge outside its limits for much of the take is the
            // skeleton turned the wrong way: 1 cm for every hinge always outside.
            let mut penalty = 0.0;
            for (k, &(j, pb, cb)) in bodies.joints.iter().enumerate() {
                let (a, b) = (assignment[pb], assignment[cb]);
                if let (
                    JointKind::Revolute {
                        limits: Some(l), ..
                    },
                    Feature::Axis(_, d),
                    Some(ha),
                    Some(hb),
                ) = (
                    &skeleton.joints[j].kind,
                    model_features[k],
                    &home[a],
                    &home[b],
                ) {
                    let axis = reg.world_from_root * d;
                    penalty +=
                        0.01 * outside_limits(&clusters[a], &clusters[b], (ha, hb), &axis, *l);
                }
            }
            let total = c + reg.cost_m + penalty;
            if chosen.as_ref().is_none_or(|x| total < x.0) {
                chosen = Some((
                    total,
                    assignment.clone(),
                    reg.world_from_root,
                    measures.clone(),
                    reg.each.clone(),
                ));
            }
        }
    }
    let Some((_, assignment, world_from_root, measures, each)) = chosen else {
        // Which link has no pose at the zero pose, or no orientation.
        let assignment = &candidates[0].1;
        for (body, &c) in assignment.iter().enumerate() {
            if home[c].is_none() {
                return Err(DefineError::NoHome {
                    link: skeleton.links[bodies.main_link[body]].name.clone(),
                    ids: ids_of(&clusters[c]),
                    home: home_frames,
                });
            }
        }
        return Err(DefineError::NoOrientation {
            model: skeleton.name.clone(),
        });
    };
    // Markers in their links' frames.
    let mut markers = Vec::new();
    let mut observations = Vec::new();
    let mut links = Vec::new();
    for (body, &c) in assignment.iter().enumerate() {
        let link = bodies.main_link[body];
        let name = &skeleton.links[link].name;
        let cluster = &clusters[c];
        let Some(home_pose) = home[c] else {
            continue;
        };
        let link_from_cluster = (world_from_root * root_from_link[link]).inverse() * home_pose;
        for (k, (seen, s)) in cluster.seen.iter().zip(&cluster.shape).enumerate() {
            let p = link_from_cluster * s;
            markers.push(MarkerSpec {
                name: format!("{name}_{k}"),
                link: name.clone(),
                in_link_m: [p.x, p.y, p.z],
            });
            observations.push(seen.clone());
        }
        links.push(LinkMarkers {
            link: name.clone(),
            seen_share: cluster
                .seen
                .iter()
                .map(|s| s.iter().flatten().count() as f64 / frames as f64)
                .collect(),
            shape_rms_m: cluster.shape_rms_m,
        });
    }
    let joints: Vec<JointFound> = bodies
        .joints
        .iter()
        .zip(&measures)
        .zip(&each)
        .map(|((&(j, _, _), m), (d, angle))| JointFound {
            name: skeleton.joints[j].name.clone(),
            kind: skeleton.joints[j].kind.name(),
            residual_m: m.residual_m,
            axis_residual_rad: m.axis_rad,
            frames: m.frames,
            registration_m: *d,
            registration_rad: *angle,
        })
        .collect();
    // Lengths: on each body, between its proximal joint and each distal one (the root: between
    // its distal joints), in the cluster's frame and in the skeleton's.
    let mut lengths = Vec::new();
    for body in 0..nb {
        let link = bodies.main_link[body];
        let link_from_root = root_from_link[link].inverse();
        let touching: Vec<(usize, Feature, Feature)> = bodies
            .joints
            .iter()
            .zip(&measures)
            .enumerate()
            .filter_map(|(k, (&(j, pb, cb), m))| {
                let on_cluster = if pb == body {
                    m.in_a
                } else if cb == body {
                    m.in_b
                } else {
                    return None;
                };
                Some((
                    j,
                    on_cluster,
                    model_features[k].transformed(&link_from_root),
                ))
            })
            .collect();
        for i in 0..touching.len() {
            for k in i + 1..touching.len() {
                let proximal = skeleton.joints[touching[i].0].child == link;
                if body != 0 && !proximal {
                    continue;
                }
                let (measured_m, measured_angle_rad) =
                    feature_distance(&touching[i].1, &touching[k].1);
                let (model_m, model_angle_rad) = feature_distance(&touching[i].2, &touching[k].2);
                lengths.push(LinkLength {
                    link: skeleton.links[link].name.clone(),
                    from_joint: skeleton.joints[touching[i].0].name.clone(),
                    to_joint: skeleton.joints[touching[k].0].name.clone(),
                    measured_m,
                    model_m,
                    measured_angle_rad,
                    model_angle_rad,
                });
            }
        }
    }
    let mut left_out: Vec<u32> = (0..tracks.len())
        .filter(|&t| !used_track[t] && tracks[t].points.iter().flatten().count() >= 20)
        .map(|t| tracks[t].id)
        .collect();
    left_out.sort_unstable();
    left_out.dedup();
    let links_names: Vec<String> = skeleton.links.iter().map(|l| l.name.clone()).collect();
    let model = Model::new(
        &skeleton.name,
        &links_names,
        &skeleton.joint_specs(),
        &markers,
        skeleton.base.clone(),
    )?;
    Ok(Defined {
        model,
        markers,
        observations,
        links,
        joints,
        lengths,
        world_from_root_home: world_from_root,
        left_out,
    })
}

/// Depth-first over bodies in tree order: body `k` takes every free cluster; the joint to its
/// parent body adds its cost.
#[allow(clippy::too_many_arguments)]
fn search(
    bodies: &Bodies,
    cost: &[Vec<[f64; 2]>],
    hinge_of: &dyn Fn(usize) -> bool,
    k: usize,
    so_far: f64,
    assign: &mut Vec<usize>,
    used: &mut Vec<bool>,
    out: &mut Vec<(f64, Vec<usize>)>,
) {
    let nb = assign.len();
    if k == nb {
        out.push((so_far, assign.clone()));
        return;
    }
    // Prune what cannot be among the best few: more than twice the best complete one so far.
    let bound = out
        .iter()
        .map(|c| c.0)
        .fold(f64::INFINITY, f64::min)
        .mul_add(2.0, 0.002);
    for c in 0..nb {
        if used[c] {
            continue;
        }
        let add = bodies
            .joints
            .iter()
            .find(|&&(_, _, child)| child == k)
            .map_or(0.0, |&(j, parent, _)| {
                cost[assign[parent]][c][usize::from(hinge_of(j))]
            });
        let total = so_far + add;
        if !total.is_finite() || total > bound {
            continue;
        }
        assign[k] = c;
        used[c] = true;
        search(bodies, cost, hinge_of, k + 1, total, assign, used, out);
        used[c] = false;
        assign[k] = usize::MAX;
    }
}
