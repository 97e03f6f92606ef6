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
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Translation3, Vector3, Vector6};
use stereoscope_bodies::kabsch;

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

/// A joint's feature fixed in a link: a hinge's axis (a point on it and its direction) or a
/// ball joint's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Feature {
    Axis(Point3<f64>, Vector3<f64>),
    Centre(Point3<f64>),
}

impl Feature {
    fn point(&self) -> Point3<f64> {
        match self {
            Feature::Axis(p, _) | Feature::Centre(p) => *p,
        }
    }

    fn transformed(&self, by: &Isometry3<f64>) -> Feature {
        match self {
            Feature::Axis(p, d) => Feature::Axis(by * p, by * d),
            Feature::Centre(p) => Feature::Centre(by * p),
        }
    }
}

/// Two axes closer than this angle are parallel (their distance is the lines' distance).
const PARALLEL_RAD: f64 = 0.01;

/// Distance between two features (axis–axis along the common normal, axis–centre, centre–
/// centre) and, for two axes, the angle between them (0 to π/2).
fn feature_distance(a: &Feature, b: &Feature) -> (f64, Option<f64>) {
    let line_point = |p: &Point3<f64>, d: &Vector3<f64>, q: &Point3<f64>| (q - p).cross(d).norm();
    match (a, b) {
        (Feature::Centre(p), Feature::Centre(q)) => ((p - q).norm(), None),
        (Feature::Axis(p, d), Feature::Centre(q)) | (Feature::Centre(q), Feature::Axis(p, d)) => {
            (line_point(p, d, q), None)
        }
        (Feature::Axis(p, d), Feature::Axis(q, e)) => {
            let n = d.cross(e);
            let angle = n.norm().asin().clamp(0.0, std::f64::consts::FRAC_PI_2);
            let dist = if angle < PARALLEL_RAD {
                line_point(p, d, q)
            } else {
                ((q - p).dot(&n) / n.norm()).abs()
            };
            (dist, Some(angle))
        }
    }
}

/// A rigid cluster: its markers (each one or more tracks never seen together), their shape
/// about its centroid, its pose in every frame where 3 of its markers were seen.
struct Cluster {
    markers: Vec<Vec<usize>>,
    shape: Vec<Point3<f64>>,
    poses: Vec<Option<Isometry3<f64>>>,
    /// RMS of the markers used about the shape, metres.
    shape_rms_m: f64,
    /// Share of the markers' sightings left out as off their place.
    outliers: f64,
    /// The same, per marker.
    marker_outliers: Vec<f64>,
    /// Each marker's point in each frame (by its pieces' ids until [`by_shape`] finds them
    /// by the cluster's shape).
    seen: Vec<Vec<Option<Point3<f64>>>>,
}

fn observed(tracks: &[Track], marker: &[usize], f: usize) -> Option<Point3<f64>> {
    marker
        .iter()
        .find_map(|&t| tracks[t].points.get(f).copied().flatten())
}

/// A marker this far from where its cluster's other markers put it is not used in that frame
/// (an image merged with another's, an id passed to a neighbour), as a multiple of the
/// rigidity tolerance.
const OUTLIER_TOLERANCES: f64 = 4.0;

/// The pose of `shape` in frame `f` from the markers seen there, the worst marker left out
/// while one is farther than `outlier_m` and 3 remain; with which markers were used.
fn pose_in(
    tracks: &[Track],
    markers: &[Vec<usize>],
    shape: &[Point3<f64>],
    f: usize,
    outlier_m: f64,
) -> Option<(Isometry3<f64>, Vec<bool>)> {
    let mut used: Vec<bool> = markers
        .iter()
        .map(|m| observed(tracks, m, f).is_some())
        .collect();
    loop {
        let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = markers
            .iter()
            .zip(shape)
            .zip(&used)
            .filter(|(_, u)| **u)
            .filter_map(|((m, s), _)| observed(tracks, m, f).map(|o| (*s, o)))
            .unzip();
        if a.len() < 3 {
            return None;
        }
        let (pose, _) = kabsch(&a, &b, &vec![1.0; a.len()])?;
        let worst = (0..markers.len())
            .filter(|&k| used[k])
            .filter_map(|k| {
                Some((
                    k,
                    (pose * shape[k] - observed(tracks, &markers[k], f)?).norm(),
                ))
            })
            .max_by(|x, y| x.1.total_cmp(&y.1));
        match worst {
            Some((k, e)) if e > outlier_m && a.len() > 3 => used[k] = false,
            Some((_, e)) if e > outlier_m => return None,
            _ => return Some((pose, used)),
        }
    }
}

/// A track missing more frames than this is cut there: the id a marker had before the gap may
/// have been taken up by a neighbour after it.
const MAX_GAP_FRAMES: usize = 2;

/// A track is cut where it lands this far from where its last two points carried on would
/// put it, metres: an id passed to a neighbouring marker jumps by the markers' spacing.
const MAX_JUMP_M: f64 = 0.008;

/// Every track cut into its pieces seen without a gap longer than `max_gap` frames or a jump
/// off its course longer than `max_jump_m`.
pub fn split_at_gaps(
    tracks: &[Track],
    frames: usize,
    max_gap: usize,
    max_jump_m: f64,
) -> Vec<Track> {
    let mut out = Vec::new();
    for t in tracks {
        let flush = |from: usize, to: usize, out: &mut Vec<Track>| {
            let mut points = vec![None; frames];
            points[from..=to].copy_from_slice(&t.points[from..=to]);
            out.push(Track { id: t.id, points });
        };
        let mut piece: Option<(usize, usize)> = None;
        for f in 0..frames {
            let Some(p) = t.points[f] else {
                continue;
            };
            let jumped = f >= 2
                && match (t.points[f - 1], t.points[f - 2]) {
                    (Some(a), Some(b)) => (p - (a + (a - b))).norm() > max_jump_m,
                    _ => false,
                };
            piece = match piece {
                Some((from, last)) if f - last <= max_gap + 1 && !jumped => Some((from, f)),
                Some((from, last)) => {
                    flush(from, last, &mut out);
                    Some((f, f))
                }
                None => Some((f, f)),
            };
        }
        if let Some((from, last)) = piece {
            flush(from, last, &mut out);
        }
    }
    out
}

/// Frames over which nothing moved: no track (but one in twenty) went further than `4 · tol_m` over the 10
/// frames about it. At such a time every pair of markers keeps its distance, so rigidity is
/// judged from the other frames only.
fn still_frames(tracks: &[Track], frames: usize, tol_m: f64) -> Vec<bool> {
    const SPAN: usize = 5;
    (0..frames)
        .map(|f| {
            let (a, b) = (f.saturating_sub(SPAN), (f + SPAN).min(frames - 1));
            let (mut seen, mut moved) = (0usize, 0usize);
            for t in tracks {
                if let (Some(p), Some(q)) = (t.points[a], t.points[b]) {
                    seen += 1;
                    if (p - q).norm() > 4.0 * tol_m {
                        moved += 1;
                    }
                }
            }
            // One track in twenty may jump (a ghost, an id passed on) in a still scene.
            seen > 0 && moved <= (seen / 20).max(1) - usize::from(seen < 20)
        })
        .collect()
}

/// Tracks grouped by constant distance, clusters of 3 or more: pairs joined most rigid first,
/// two groups only where nearly every pair across them seen together is rigid too (one pair
/// that keeps its distance across a joint — a marker near the axis — does not join two links).
fn rigid_groups(tracks: &[Track], keep: &[usize], tol_m: f64, still: &[bool]) -> Vec<Vec<usize>> {
    let n = keep.len();
    let mut spread: Vec<Option<f64>> = vec![None; n * n];
    let mut d = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            d.clear();
            // Only while the model moves: standing at its zero pose, every pair is rigid.
            for ((p, q), still) in tracks[keep[i]]
                .points
                .iter()
                .zip(&tracks[keep[j]].points)
                .zip(still)
            {
                if let (Some(p), Some(q), false) = (p, q, still) {
                    d.push((p - q).norm());
                }
            }
            // Seen together a second or more at 60 fps: over a shorter while a joint may
            // barely have moved.
            if d.len() < 60 {
                continue;
            }
            // Robust: the median absolute deviation as a standard deviation, so that a few
            // frames where a marker's image merged with another's do not part a link.
            d.sort_by(f64::total_cmp);
            let median = d[d.len() / 2];
            for x in d.iter_mut() {
                *x = (*x - median).abs();
            }
            d.sort_by(f64::total_cmp);
            let sd = 1.4826 * d[d.len() / 2];
            spread[i * n + j] = Some(sd);
            spread[j * n + i] = Some(sd);
        }
    }
    let mut edges: Vec<(f64, usize, usize)> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .filter_map(|(i, j)| spread[i * n + j].filter(|s| *s < tol_m).map(|s| (s, i, j)))
        .collect();
    edges.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut group: Vec<usize> = (0..n).collect();
    for (_, i, j) in edges {
        let (gi, gj) = (group[i], group[j]);
        if gi == gj {
            continue;
        }
        let (mut rigid, mut seen) = (0usize, 0usize);
        for a in (0..n).filter(|&a| group[a] == gi) {
            for b in (0..n).filter(|&b| group[b] == gj) {
                if let Some(s) = spread[a * n + b] {
                    seen += 1;
                    if s < 2.0 * tol_m {
                        rigid += 1;
                    }
                }
            }
        }
        if rigid * 4 >= seen * 3 {
            for g in group.iter_mut() {
                if *g == gj {
                    *g = gi;
                }
            }
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in 0..n {
        groups.entry(group[i]).or_default().push(keep[i]);
    }
    groups.into_values().filter(|g| g.len() >= 3).collect()
}

/// A group's shape: placed from the frame that shows most of it, each other marker placed
/// from a frame that shows it with 3 placed ones; then twice refined as the mean of every
/// frame's markers brought into the shape's frame. Tracks at one place never seen together
/// are one marker whose track broke.
fn build_cluster(
    tracks: &[Track],
    group: &[usize],
    frames: usize,
    merge_m: f64,
    outlier_m: f64,
    initial: Option<Vec<Option<Point3<f64>>>>,
) -> Cluster {
    let seen_at = |t: usize, f: usize| tracks[t].points[f].is_some();
    let best = (0..frames)
        .max_by_key(|&f| group.iter().filter(|&&t| seen_at(t, f)).count())
        .unwrap_or(0);
    let mut place: Vec<Option<Point3<f64>>> =
        initial.unwrap_or_else(|| group.iter().map(|&t| tracks[t].points[best]).collect());
    for _ in 0..group.len() {
        let missing: Vec<usize> = (0..group.len()).filter(|&k| place[k].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        for k in missing {
            for f in 0..frames {
                let Some(p) = tracks[group[k]].points[f] else {
                    continue;
                };
                let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = (0..group.len())
                    .filter_map(|i| Some((place[i]?, tracks[group[i]].points[f]?)))
                    .unzip();
                if a.len() >= 3
                    && let Some((world_from_shape, _)) = kabsch(&a, &b, &vec![1.0; a.len()])
                {
                    place[k] = Some(world_from_shape.inverse() * p);
                    break;
                }
            }
        }
    }
    let placed: Vec<(usize, Point3<f64>)> = place
        .iter()
        .enumerate()
        .filter_map(|(k, p)| p.map(|p| (k, p)))
        .collect();
    // Tracks at one place (within merge_m) never seen together are one marker.
    let mut markers: Vec<Vec<usize>> = Vec::new();
    let mut shape: Vec<Point3<f64>> = Vec::new();
    for (k, p) in placed {
        let t = group[k];
        let same = (0..markers.len()).find(|&i| {
            (shape[i] - p).norm() < merge_m
                && markers[i]
                    .iter()
                    .all(|&u| (0..frames).all(|f| !(seen_at(u, f) && seen_at(t, f))))
        });
        match same {
            Some(i) => markers[i].push(t),
            None => {
                markers.push(vec![t]);
                shape.push(p);
            }
        }
    }
    let mut poses = vec![None; frames];
    let mut rms = 0.0;
    let mut outliers = 0.0;
    let mut marker_seen = vec![0usize; markers.len()];
    let mut count = vec![0usize; markers.len()];
    for _ in 0..3 {
        let mut sum = vec![Vector3::zeros(); shape.len()];
        count.iter_mut().for_each(|x| *x = 0);
        let (mut sq, mut n, mut seen) = (0.0, 0usize, 0usize);
        marker_seen.iter_mut().for_each(|x| *x = 0);
        for (f, pose) in poses.iter_mut().enumerate() {
            let found = pose_in(tracks, &markers, &shape, f, outlier_m);
            let visible = markers
                .iter()
                .filter(|m| observed(tracks, m, f).is_some())
                .count();
            if visible >= 3 {
                seen += visible;
                for (k, m) in markers.iter().enumerate() {
                    if observed(tracks, m, f).is_some() {
                        marker_seen[k] += 1;
                    }
                }
            }
            *pose = found.as_ref().map(|(p, _)| *p);
            let Some((world_from_shape, used)) = found else {
                continue;
            };
            let shape_from_world = world_from_shape.inverse();
            for (k, m) in markers.iter().enumerate() {
                if let (true, Some(o)) = (used[k], observed(tracks, m, f)) {
                    let local = shape_from_world * o;
                    sq += (local - shape[k]).norm_squared();
                    n += 1;
                    sum[k] += local.coords;
                    count[k] += 1;
                }
            }
        }
        rms = (sq / n.max(1) as f64).sqrt();
        outliers = 1.0 - n as f64 / seen.max(1) as f64;
        for k in 0..shape.len() {
            if count[k] > 0 {
                shape[k] = Point3::from(sum[k] / count[k] as f64);
            }
        }
        let c = shape.iter().map(|p| p.coords).sum::<Vector3<f64>>() / shape.len() as f64;
        for p in &mut shape {
            *p -= c;
        }
    }
    for (f, pose) in poses.iter_mut().enumerate() {
        *pose = pose_in(tracks, &markers, &shape, f, outlier_m).map(|(p, _)| p);
    }
    let marker_outliers = marker_seen
        .iter()
        .zip(&count)
        .map(|(&s, &c)| {
            if s == 0 {
                0.0
            } else {
                1.0 - c as f64 / s as f64
            }
        })
        .collect();
    let seen = markers
        .iter()
        .map(|m| (0..frames).map(|f| observed(tracks, m, f)).collect())
        .collect();
    Cluster {
        markers,
        shape,
        poses,
        shape_rms_m: rms,
        outliers,
        marker_outliers,
        seen,
    }
}

/// Pieces on no cluster taken up by the cluster they ride on: brought into its frame wherever
/// it is posed, they stay at one place (robust spread under `tol_m`, over 20 frames or more).
/// A piece fits the cluster it spreads least in; pieces at one of its markers' places that
/// are never seen with it are that marker (its id changed), the others new markers.
#[allow(clippy::too_many_arguments)]
fn absorb(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    keep: &[usize],
    still: &[bool],
    frames: usize,
    tol_m: f64,
    merge_m: f64,
    outlier_m: f64,
) -> Vec<Cluster> {
    let used: std::collections::HashSet<usize> = clusters
        .iter()
        .flat_map(|c| c.markers.iter().flatten().copied())
        .collect();
    let mut taken: Vec<Vec<(usize, Point3<f64>)>> = vec![Vec::new(); clusters.len()];
    let mut local = Vec::new();
    for &t in keep.iter().filter(|t| !used.contains(t)) {
        let mut best: Option<(f64, usize, Point3<f64>)> = None;
        for (ci, c) in clusters.iter().enumerate() {
            local.clear();
            for f in (0..frames).filter(|&f| !still[f]) {
                if let (Some(pose), Some(p)) = (c.poses[f], tracks[t].points[f]) {
                    local.push(pose.inverse() * p);
                }
            }
            if local.len() < 20 {
                continue;
            }
            let median = |k: usize, v: &[Point3<f64>]| {
                let mut x: Vec<f64> = v.iter().map(|p| p[k]).collect();
                x.sort_by(f64::total_cmp);
                x[x.len() / 2]
            };
            let at = Point3::new(median(0, &local), median(1, &local), median(2, &local));
            let mut off: Vec<f64> = local.iter().map(|p| (p - at).norm()).collect();
            off.sort_by(f64::total_cmp);
            // The median distance from the median, as a per-axis deviation (χ with 3 degrees
            // of freedom has its median at 1.54 σ).
            let spread = off[off.len() / 2] / 1.54;
            if spread < tol_m && best.is_none_or(|b| spread < b.0) {
                best = Some((spread, ci, at));
            }
        }
        if let Some((_, ci, at)) = best {
            taken[ci].push((t, at));
        }
    }
    for (ci, new) in taken.into_iter().enumerate() {
        if new.is_empty() {
            continue;
        }
        let c = &clusters[ci];
        let (mut group, mut place) = (Vec::new(), Vec::new());
        for (m, s) in c.markers.iter().zip(&c.shape) {
            for &t in m {
                group.push(t);
                place.push(Some(*s));
            }
        }
        for (t, at) in new {
            group.push(t);
            place.push(Some(at));
        }
        clusters[ci] = build_cluster(tracks, &group, frames, merge_m, outlier_m, Some(place));
    }
    clusters
}

/// Every cluster found in every frame by its shape, whatever the ids (`stereoscope_bodies::
/// identify_near`, all clusters at once, no point used twice, continuity from the last
/// frame): a link whose markers' ids changed is found all the same. A first pass also looks,
/// in each cluster's frame, for points no cluster explains that stay at one place (a marker
/// whose pieces were all too short to group): new markers. Clusters of more than
/// `stereoscope_bodies::MAX_MARKERS` markers keep what their ids gave.
fn by_shape(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    still: &[bool],
    frames: usize,
    tol_m: f64,
    merge_m: f64,
) -> (Vec<Cluster>, Vec<bool>) {
    let mut used_track = vec![false; tracks.len()];
    for round in 0..2 {
        let ok: Vec<usize> = (0..clusters.len())
            .filter(|&c| (3..=stereoscope_bodies::MAX_MARKERS).contains(&clusters[c].shape.len()))
            .collect();
        let defs: Vec<stereoscope_bodies::BodyDef> = ok
            .iter()
            .map(|&c| stereoscope_bodies::BodyDef {
                name: format!("cluster {c}"),
                markers_m: clusters[c].shape.clone(),
                tolerance_m: 2.0 * tol_m,
            })
            .collect();
        let mut near: Vec<Option<Isometry3<f64>>> = vec![None; ok.len()];
        let mut loose: Vec<Vec<Point3<f64>>> = vec![Vec::new(); clusters.len()];
        let mut points = Vec::new();
        let mut owner = Vec::new();
        for f in 0..frames {
            points.clear();
            owner.clear();
            for (t, tr) in tracks.iter().enumerate() {
                if let Some(p) = tr.points[f] {
                    points.push(p);
                    owner.push(t);
                }
            }
            let found = stereoscope_bodies::identify_near(&defs, &points, &near);
            let mut explained = vec![false; points.len()];
            // A cluster not found by its shape (a symmetric one seen from nothing) keeps what
            // its ids gave.
            for m in &found {
                let c = ok[m.body];
                clusters[c].poses[f] = Some(m.world_from_body);
                for (k, i) in m.markers.iter().enumerate() {
                    clusters[c].seen[k][f] = i.map(|i| points[i]);
                }
            }
            for (b, &c) in ok.iter().enumerate() {
                near[b] = clusters[c].poses[f];
                for s in &clusters[c].seen {
                    if let Some(p) = s[f]
                        && let Some(i) = points.iter().position(|q| *q == p)
                    {
                        explained[i] = true;
                        used_track[owner[i]] = true;
                    }
                }
            }
            if round == 0 && !still[f] {
                for (c, cluster) in clusters.iter().enumerate() {
                    let Some(pose) = cluster.poses[f] else {
                        continue;
                    };
                    let inv = pose.inverse();
                    for (i, p) in points.iter().enumerate() {
                        let local = inv * p;
                        // Within a link's reach of its markers.
                        if !explained[i] && local.coords.norm() < 0.4 {
                            loose[c].push(local);
                        }
                    }
                }
            }
        }
        if round == 1 {
            break;
        }
        // New markers: places in a cluster's frame where loose points gather in 30 frames or
        // more (a quarter of its posed frames at least), clear of its markers.
        let mut grew = false;
        for (c, pts) in loose.iter().enumerate() {
            let posed = clusters[c].poses.iter().flatten().count();
            let need = 30.max(posed / 4);
            let mut left: Vec<Point3<f64>> = pts.clone();
            while clusters[c].shape.len() < stereoscope_bodies::MAX_MARKERS && left.len() >= need {
                // The densest point's neighbourhood.
                let mut best = (0usize, 0usize);
                for (i, p) in left.iter().enumerate().step_by((left.len() / 400).max(1)) {
                    let n = left.iter().filter(|q| (*q - p).norm() < merge_m).count();
                    if n > best.1 {
                        best = (i, n);
                    }
                }
                if best.1 < need {
                    break;
                }
                let centre = left[best.0];
                let close: Vec<Point3<f64>> = left
                    .iter()
                    .filter(|q| (*q - centre).norm() < merge_m)
                    .copied()
                    .collect();
                let mean = Point3::from(
                    close.iter().map(|p| p.coords).sum::<Vector3<f64>>() / close.len() as f64,
                );
                left.retain(|q| (q - centre).norm() >= merge_m);
                let clear = clusters[c]
                    .shape
                    .iter()
                    .all(|s| (s - mean).norm() > 2.0 * merge_m);
                if clear {
                    clusters[c].shape.push(mean);
                    clusters[c].markers.push(Vec::new());
                    clusters[c].seen.push(vec![None; frames]);
                    clusters[c].marker_outliers.push(0.0);
                    grew = true;
                }
            }
        }
        if !grew {
            break;
        }
    }
    // Markers found in under a quarter of the frames their cluster is posed in are dropped (a
    // neighbour's marker near a joint that seldom moved), then the shapes again from what was
    // found, and the poses from them.
    for c in clusters.iter_mut() {
        let posed = c.poses.iter().flatten().count().max(1);
        let keep: Vec<bool> = c
            .seen
            .iter()
            .map(|s| s.iter().flatten().count() * 4 >= posed)
            .collect();
        if keep.iter().filter(|k| **k).count() >= 3 {
            let mut k = 0;
            c.shape.retain(|_| {
                k += 1;
                keep[k - 1]
            });
            let mut k = 0;
            c.seen.retain(|_| {
                k += 1;
                keep[k - 1]
            });
            let mut k = 0;
            c.markers.retain(|_| {
                k += 1;
                keep[k - 1]
            });
        }
        for (k, s) in c.shape.iter_mut().enumerate() {
            let (mut sum, mut n) = (Vector3::zeros(), 0usize);
            for f in 0..frames {
                if let (Some(pose), Some(p)) = (c.poses[f], c.seen[k][f]) {
                    sum += (pose.inverse() * p).coords;
                    n += 1;
                }
            }
            if n > 0 {
                *s = Point3::from(sum / n as f64);
            }
        }
        for f in 0..frames {
            let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = c
                .shape
                .iter()
                .zip(&c.seen)
                .filter_map(|(s, seen)| seen[f].map(|p| (*s, p)))
                .unzip();
            c.poses[f] = if a.len() >= 3 {
                kabsch(&a, &b, &vec![1.0; a.len()]).map(|(p, _)| p)
            } else {
                None
            };
        }
    }
    (clusters, used_track)
}

/// Where `shape` lies among `points`: every way of putting three of its markers on three points
/// whose distances agree within `tol_m`, the rest of its markers then on their nearest points;
/// the way that puts the most markers within `tol_m` of a point, then with the least residual.
fn place_shape(
    shape: &[Point3<f64>],
    points: &[Point3<f64>],
    tol_m: f64,
) -> Option<Isometry3<f64>> {
    let (n, m) = (shape.len(), points.len());
    let d = |a: &Point3<f64>, b: &Point3<f64>| (a - b).norm();
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let (sij, sjk, sik) = (
                    d(&shape[i], &shape[j]),
                    d(&shape[j], &shape[k]),
                    d(&shape[i], &shape[k]),
                );
                for p in 0..m {
                    for q in 0..m {
                        if q == p || (d(&points[p], &points[q]) - sij).abs() > tol_m {
                            continue;
                        }
                        for r in 0..m {
                            if r == p
                                || r == q
                                || (d(&points[q], &points[r]) - sjk).abs() > tol_m
                                || (d(&points[p], &points[r]) - sik).abs() > tol_m
                            {
                                continue;
                            }
                            let from = [shape[i], shape[j], shape[k]];
                            let to = [points[p], points[q], points[r]];
                            let Some((pose, _)) = kabsch(&from, &to, &[1.0; 3]) else {
                                continue;
                            };
                            let (mut a, mut b) = (Vec::new(), Vec::new());
                            for s in shape {
                                let at = pose * s;
                                if let Some(near) = points
                                    .iter()
                                    .min_by(|x, y| d(x, &at).total_cmp(&d(y, &at)))
                                    .filter(|x| d(x, &at) < tol_m)
                                {
                                    a.push(*s);
                                    b.push(*near);
                                }
                            }
                            let Some((pose, rms)) = kabsch(&a, &b, &vec![1.0; a.len()]) else {
                                continue;
                            };
                            if best
                                .as_ref()
                                .is_none_or(|(c, e, _)| a.len() > *c || (a.len() == *c && rms < *e))
                            {
                                best = Some((a.len(), rms, pose));
                            }
                        }
                    }
                }
            }
        }
    }
    best.map(|(_, _, p)| p)
}

/// Frames in which both clusters are posed.
fn co_posed(a: &Cluster, b: &Cluster) -> usize {
    a.poses
        .iter()
        .zip(&b.poses)
        .filter(|(x, y)| x.is_some() && y.is_some())
        .count()
}

/// Where `b`'s shape lies in `a`'s frame when three of its markers match three of `a`'s
/// (distances within `tol_m`) and every other marker of `b` either lands on one of `a`'s or
/// well apart from all: the same link seen under other ids at another time.
fn same_link(a: &Cluster, b: &Cluster, tol_m: f64) -> Option<Isometry3<f64>> {
    let (na, nb) = (a.shape.len(), b.shape.len());
    let d = |s: &[Point3<f64>], i: usize, j: usize| (s[i] - s[j]).norm();
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    for i in 0..nb {
        for j in 0..nb {
            for k in 0..nb {
                if i == j || j == k || i == k || !(i < j && j < k) {
                    continue;
                }
                for p in 0..na {
                    for q in 0..na {
                        for r in 0..na {
                            if p == q || q == r || p == r {
                                continue;
                            }
                            let ok = (d(&b.shape, i, j) - d(&a.shape, p, q)).abs() < tol_m
                                && (d(&b.shape, j, k) - d(&a.shape, q, r)).abs() < tol_m
                                && (d(&b.shape, i, k) - d(&a.shape, p, r)).abs() < tol_m;
                            if !ok {
                                continue;
                            }
                            let from = [b.shape[i], b.shape[j], b.shape[k]];
                            let to = [a.shape[p], a.shape[q], a.shape[r]];
                            let Some((a_from_b, _)) = kabsch(&from, &to, &[1.0; 3]) else {
                                continue;
                            };
                            let (mut matched, mut sq, mut fits) = (0usize, 0.0, true);
                            for s in &b.shape {
                                let at = a_from_b * s;
                                let near = a
                                    .shape
                                    .iter()
                                    .map(|x| (x - at).norm())
                                    .fold(f64::INFINITY, f64::min);
                                if near < tol_m {
                                    matched += 1;
                                    sq += near * near;
                                } else if near < 3.0 * tol_m {
                                    fits = false;
                                }
                            }
                            if fits
                                && matched >= 3
                                && best.as_ref().is_none_or(|(m, e, _)| {
                                    matched > *m || (matched == *m && sq < *e)
                                })
                            {
                                best = Some((matched, sq, a_from_b));
                            }
                        }
                    }
                }
            }
        }
    }
    best.map(|(_, _, p)| p)
}

/// Clusters of one link seen at different times (every marker's id changed while the link was
/// hidden) joined: never posed together, and their shapes match.
fn join_time_apart(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    frames: usize,
    tol_m: f64,
    merge_m: f64,
    outlier_m: f64,
) -> Vec<Cluster> {
    // Pairs tried and refused, by their first tracks.
    let mut refused: Vec<(usize, usize)> = Vec::new();
    let key = |c: &Cluster| c.markers.iter().flatten().copied().min().unwrap_or(0);
    'again: loop {
        for a in 0..clusters.len() {
            for b in 0..clusters.len() {
                if a == b
                    || co_posed(&clusters[a], &clusters[b]) >= 20
                    || refused.contains(&(key(&clusters[a]), key(&clusters[b])))
                {
                    continue;
                }
                // The larger (or the first) keeps its frame.
                if clusters[b].shape.len() > clusters[a].shape.len() {
                    continue;
                }
                let Some(a_from_b) = same_link(&clusters[a], &clusters[b], tol_m) else {
                    continue;
                };
                let (mut group, mut place) = (Vec::new(), Vec::new());
                for (m, s) in clusters[a].markers.iter().zip(&clusters[a].shape) {
                    for &t in m {
                        group.push(t);
                        place.push(Some(*s));
                    }
                }
                for (m, s) in clusters[b].markers.iter().zip(&clusters[b].shape) {
                    for &t in m {
                        group.push(t);
                        place.push(Some(a_from_b * s));
                    }
                }
                let joined = build_cluster(tracks, &group, frames, merge_m, outlier_m, Some(place));
                // Seen together now and then, they must still be one rigid shape.
                let before = clusters[a].shape_rms_m.max(clusters[b].shape_rms_m);
                if joined.shape_rms_m > 1.5 * before + 0.25 * tol_m {
                    refused.push((key(&clusters[a]), key(&clusters[b])));
                    continue;
                }
                let (hi, lo) = (a.max(b), a.min(b));
                clusters.remove(hi);
                clusters.remove(lo);
                clusters.push(joined);
                continue 'again;
            }
        }
        return clusters;
    }
}

/// The normal equations of `R_a·c_a − R_b·c_b = t_b − t_a` over the frames both clusters are
/// posed in.
struct PairSystem {
    ata: Matrix6<f64>,
    atb: Vector6<f64>,
    btb: f64,
    frames: usize,
}

impl PairSystem {
    fn new(a: &Cluster, b: &Cluster) -> PairSystem {
        let mut s = PairSystem {
            ata: Matrix6::zeros(),
            atb: Vector6::zeros(),
            btb: 0.0,
            frames: 0,
        };
        for (pa, pb) in a.poses.iter().zip(&b.poses) {
            let (Some(pa), Some(pb)) = (pa, pb) else {
                continue;
            };
            let ra = pa.rotation.to_rotation_matrix().into_inner();
            let rb = pb.rotation.to_rotation_matrix().into_inner();
            let mut row = nalgebra::Matrix3x6::zeros();
            row.fixed_view_mut::<3, 3>(0, 0).copy_from(&ra);
            row.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rb));
            let rhs = pb.translation.vector - pa.translation.vector;
            s.ata += row.transpose() * row;
            s.atb += row.transpose() * rhs;
            s.btb += rhs.norm_squared();
            s.frames += 1;
        }
        s
    }

    /// The least-squares solution, leaving out the `drop` least singular directions, and its
    /// RMS residual per frame (metres).
    fn solve(&self, drop: usize) -> (Vector6<f64>, f64) {
        let eig = self.ata.symmetric_eigen();
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
        let top = eig.eigenvalues[order[0]].max(1e-300);
        let mut x = Vector6::zeros();
        for &k in order.iter().take(6 - drop) {
            let l = eig.eigenvalues[k];
            if l > 1e-12 * top {
                let v = eig.eigenvectors.column(k);
                x += v * (v.dot(&self.atb) / l);
            }
        }
        let sq = (x.dot(&(self.ata * x)) - 2.0 * x.dot(&self.atb) + self.btb).max(0.0);
        (x, (sq / self.frames.max(1) as f64).sqrt())
    }

    /// The hinge axis (direction in a, in b) and its RMS angle residual.
    fn axis(&self) -> (Vector3<f64>, Vector3<f64>, f64) {
        let eig = self.ata.symmetric_eigen();
        let k = (0..6)
            .min_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]))
            .unwrap_or(5);
        let v = eig.eigenvectors.column(k);
        let na = Vector3::new(v[0], v[1], v[2]);
        let nb = Vector3::new(v[3], v[4], v[5]);
        // |R_a·n_a − R_b·n_b|² with |n_a| = |n_b| = 1/√2 is half the squared chord.
        let residual = (2.0 * eig.eigenvalues[k].max(0.0) / self.frames.max(1) as f64).sqrt();
        (
            na.try_normalize(1e-12).unwrap_or_else(Vector3::z),
            nb.try_normalize(1e-12).unwrap_or_else(Vector3::z),
            residual,
        )
    }
}

/// A joint's fit between the clusters of its parent and child link: its features in each
/// cluster's frame, its residual (metres) and the axis residual (radians) of a hinge.
#[derive(Clone)]
struct JointMeasure {
    in_a: Feature,
    in_b: Feature,
    residual_m: f64,
    axis_rad: Option<f64>,
    frames: usize,
}

/// The lever that weighs an axis residual against a centre residual, metres.
const AXIS_LEVER_M: f64 = 0.1;

fn measure(a: &Cluster, b: &Cluster, hinge: bool) -> JointMeasure {
    let s = PairSystem::new(a, b);
    if hinge {
        let (na, nb, axis_rad) = s.axis();
        let (x, r) = s.solve(1);
        JointMeasure {
            in_a: Feature::Axis(Point3::new(x[0], x[1], x[2]), na),
            in_b: Feature::Axis(Point3::new(x[3], x[4], x[5]), nb),
            residual_m: r,
            axis_rad: Some(axis_rad),
            frames: s.frames,
        }
    } else {
        let (x, r) = s.solve(0);
        JointMeasure {
            in_a: Feature::Centre(Point3::new(x[0], x[1], x[2])),
            in_b: Feature::Centre(Point3::new(x[3], x[4], x[5])),
            residual_m: r,
            axis_rad: None,
            frames: s.frames,
        }
    }
}

impl JointMeasure {
    fn cost(&self) -> f64 {
        let axis = self.axis_rad.unwrap_or(0.0) * AXIS_LEVER_M;
        (self.residual_m * self.residual_m + axis * axis).sqrt()
    }
}

/// The skeleton's links bolted together by fixed joints are one rigid body; its movable joints
/// join bodies. Bodies in tree order, each with its first (main) link.
struct Bodies {
    main_link: Vec<usize>,
    /// Movable joints: (joint index, parent body, child body).
    joints: Vec<(usize, usize, usize)>,
}

fn bodies(model: &Model) -> Bodies {
    let mut of_link = vec![usize::MAX; model.links.len()];
    let mut main_link = vec![0];
    of_link[0] = 0;
    let mut joints = Vec::new();
    for (j, joint) in model.joints.iter().enumerate() {
        let pb = of_link[joint.parent];
        if joint.kind == JointKind::Fixed {
            of_link[joint.child] = pb;
        } else {
            of_link[joint.child] = main_link.len();
            main_link.push(joint.child);
            joints.push((j, pb, of_link[joint.child]));
        }
    }
    Bodies { main_link, joints }
}

/// Wahba's problem: the rotation taking each `from` direction onto its `to`, weighted.
fn wahba(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
    let mut b = Matrix3::zeros();
    for (f, t) in from.iter().zip(to) {
        b += t * f.transpose();
    }
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    if svd.singular_values[1] < 1e-6 * svd.singular_values[0].max(1e-300) {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    Some(u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t)
}

/// A registration of the skeleton's zero pose: the root's pose, its cost (metres, directions
/// weighed by the lever) and each joint's (distance, angle).
struct Registration {
    world_from_root: Isometry3<f64>,
    cost_m: f64,
    each: Vec<(f64, Option<f64>)>,
}

/// The root's poses registering the skeleton's joint features at the zero pose (`model`, root
/// frame) onto the measured ones (world). Hinge directions are signless: every choice of signs
/// is tried, and every rotation as good as the best is returned (a leg's hip, knee and ankle
/// in a line fit turned half round the line as well; the joints' limits tell them apart).
fn register(model: &[Feature], measured: &[Feature]) -> Vec<Registration> {
    let hinges: Vec<usize> = (0..model.len())
        .filter(|&k| matches!(model[k], Feature::Axis(..)))
        .collect();
    let centres: Vec<usize> = (0..model.len())
        .filter(|&k| matches!(model[k], Feature::Centre(..)))
        .collect();
    if hinges.len() > 12 {
        return Vec::new();
    }
    let mut rotations: Vec<(f64, Matrix3<f64>)> = Vec::new();
    for signs in 0u32..(1 << hinges.len()) {
        let (mut from, mut to) = (Vec::new(), Vec::new());
        for (i, &k) in hinges.iter().enumerate() {
            if let (Feature::Axis(_, d), Feature::Axis(_, n)) = (model[k], measured[k]) {
                let s = if signs & (1 << i) != 0 { -1.0 } else { 1.0 };
                from.push(d);
                to.push(n * s);
            }
        }
        for (i, &k) in centres.iter().enumerate() {
            for &l in &centres[i + 1..] {
                let d = model[l].point() - model[k].point();
                let n = measured[l].point() - measured[k].point();
                // Weighed as the lever weighs directions: a centre pair's length is its weight.
                let w = d.norm().min(n.norm()) / AXIS_LEVER_M;
                if let (Some(d), Some(n)) = (d.try_normalize(1e-9), n.try_normalize(1e-9)) {
                    from.push(d * w);
                    to.push(n * w);
                }
            }
        }
        let Some(r) = wahba(&from, &to) else {
            continue;
        };
        let cost: f64 = from
            .iter()
            .zip(&to)
            .map(|(f, t)| (r * f - t).norm_squared())
            .sum();
        rotations.push((cost, r));
    }
    let best = rotations.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
    let mut kept: Vec<Matrix3<f64>> = Vec::new();
    for (c, r) in rotations {
        // As good as the best within noise (0.5° per direction), and not one kept already.
        if c <= best + 1e-4 * model.len() as f64 && kept.iter().all(|k| (k - r).norm() > 1e-3) {
            kept.push(r);
        }
    }
    kept.into_iter()
        .filter_map(|r| translate(model, measured, r))
        .collect()
}

/// The translation for rotation `r` by least squares (a centre onto its centre, an axis point
/// onto its line), and the registration's residuals.
fn translate(model: &[Feature], measured: &[Feature], r: Matrix3<f64>) -> Option<Registration> {
    let mut m = Matrix3::zeros();
    let mut v = Vector3::zeros();
    for (f, g) in model.iter().zip(measured) {
        let q = r * f.point().coords;
        let p = match g {
            Feature::Centre(_) => Matrix3::identity(),
            Feature::Axis(_, n) => Matrix3::identity() - n * n.transpose(),
        };
        m += p;
        v += p * (g.point().coords - q);
    }
    let t = m.try_inverse()? * v;
    let rot = nalgebra::Rotation3::from_matrix_unchecked(r);
    let pose = Isometry3::from_parts(
        Translation3::from(t),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    );
    let mut cost = 0.0;
    let mut each = Vec::new();
    for (f, g) in model.iter().zip(measured) {
        let placed = f.transformed(&pose);
        let (d, angle) = match (placed, g) {
            (Feature::Centre(p), Feature::Centre(c)) => ((p - c).norm(), None),
            (Feature::Axis(p, d), Feature::Axis(q, n)) => (
                (p - q).cross(n).norm(),
                Some(d.cross(n).norm().asin().abs()),
            ),
            _ => (f64::INFINITY, None),
        };
        let a = angle.unwrap_or(0.0) * AXIS_LEVER_M;
        cost += d * d + a * a;
        each.push((d, angle));
    }
    Some(Registration {
        world_from_root: pose,
        cost_m: (cost / model.len().max(1) as f64).sqrt(),
        each,
    })
}

/// The share of frames in which a hinge's angle (about `axis_world`, the registered skeleton's
/// axis at the zero pose; zero at the zero pose) lies outside `limits` by more than 3°.
fn outside_limits(
    parent: &Cluster,
    child: &Cluster,
    home: (&Isometry3<f64>, &Isometry3<f64>),
    axis_world: &Vector3<f64>,
    limits: crate::model::Limits,
) -> f64 {
    let axis = home.0.rotation.inverse() * axis_world;
    let rel_home = home.0.rotation.inverse() * home.1.rotation;
    let (mut out, mut n) = (0usize, 0usize);
    for (a, b) in parent.poses.iter().zip(&child.poses) {
        let (Some(a), Some(b)) = (a, b) else {
            continue;
        };
        let q = a.rotation.inverse() * b.rotation * rel_home.inverse();
        let angle = 2.0 * q.imag().dot(&axis).atan2(q.w);
        let angle =
            (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        let margin = 3f64.to_radians();
        if angle < limits.lower - margin || angle > limits.upper + margin {
            out += 1;
        }
        n += 1;
    }
    out as f64 / n.max(1) as f64
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
