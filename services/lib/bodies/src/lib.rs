//! Rigid bodies of markers (issue: the VR feed). Not from the thesis, whose targets are single
//! blobs (its §5.2 two-ball target is a body of two markers); the method is the one every
//! motion-capture system uses (`../shared/DESIGN.md` §6):
//!
//! - a body is its markers' positions in its own frame and a tolerance; [`check_bodies`]
//!   refuses one with fewer than three markers (two: a pointer, whose roll is unobservable),
//!   collinear ones, or a layout that matches itself under a relabelling of its markers (a
//!   symmetric layout: its pose would flip) or matches another body;
//! - each frame, [`identify`] finds every body's markers among the triangulated points by their
//!   pairwise distances (each within the body's tolerance of the defined one), a marker may be
//!   missing while three are seen, and the bodies' candidate matches are chosen together so that
//!   no point serves two bodies and the most markers are explained (not body by body);
//! - [`kabsch`] gives `world_from_body` by the weighted least-squares rotation and translation
//!   (Kabsch/Umeyama without scale, SVD of the weighted cross-covariance) and the RMS residual,
//!   which rejects a wrong assignment.
//!
//! Units: metres throughout (the rig file's unit is converted by its loader).

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// The most markers a body may have (the relabelling search is over their permutations).
pub const MAX_MARKERS: usize = 8;

/// A body as defined: markers in its own frame, metres.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyDef {
    pub name: String,
    pub markers_m: Vec<Point3<f64>>,
    /// How far a measured inter-marker distance may be from the defined one, metres.
    pub tolerance_m: f64,
}

/// A definition that cannot be used, naming the body and what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BodyError {
    #[error("body {body:?}: {count} markers; a body needs 3 to {MAX_MARKERS} (2 for a pointer)")]
    MarkerCount { body: String, count: usize },
    #[error("body {body:?}: marker {marker} is not a finite position")]
    NotFinite { body: String, marker: usize },
    #[error("body {body:?}: tolerance {value} m must be above 0 and below 0.1 m")]
    Tolerance { body: String, value: f64 },
    #[error(
        "body {body:?}: markers {a} and {b} are {distance_m:.4} m apart, not more than twice the tolerance: they cannot be told apart"
    )]
    TooClose {
        body: String,
        a: usize,
        b: usize,
        distance_m: f64,
    },
    #[error(
        "body {body:?}: its markers lie on one line (within {spread_m:.4} m), so its roll about that line is unobservable; move one marker off the line"
    )]
    Collinear { body: String, spread_m: f64 },
    #[error("body names: {0:?} appears twice")]
    DuplicateName(String),
    #[error("{0}")]
    Ambiguous(Ambiguity),
}

/// Two ways of matching one layout: a body with itself under a relabelling (symmetric), or a
/// body's markers into another body's.
#[derive(Debug, Clone, PartialEq)]
pub struct Ambiguity {
    pub body: String,
    /// The other body, or `None` for a symmetric layout.
    pub other: Option<String>,
    /// `(marker of body, marker of other)` pairs of the matching.
    pub mapping: Vec<(usize, usize)>,
    /// The largest difference of a matched pair of distances, metres.
    pub worst_difference_m: f64,
    /// How much more that difference must grow before the two can be told apart, metres.
    pub needed_m: f64,
    /// The markers whose distance differs most.
    pub pair: (usize, usize),
}

impl std::fmt::Display for Ambiguity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pairs: Vec<String> = self
            .mapping
            .iter()
            .map(|(a, b)| format!("{a}→{b}"))
            .collect();
        match &self.other {
            None => write!(
                f,
                "body {:?} is symmetric: relabelling its markers ({}) keeps every distance within {:.1} mm, so its pose can flip; move marker {} or {} so that their distance changes by at least {:.1} mm",
                self.body,
                pairs.join(", "),
                self.worst_difference_m * 1e3,
                self.pair.0,
                self.pair.1,
                self.needed_m * 1e3
            ),
            Some(o) => write!(
                f,
                "body {:?} matches body {:?} (markers {}) with every distance within {:.1} mm, so one can be taken for the other; move marker {} or {} of {:?} so that their distance changes by at least {:.1} mm",
                self.body,
                o,
                pairs.join(", "),
                self.worst_difference_m * 1e3,
                self.pair.0,
                self.pair.1,
                self.body,
                self.needed_m * 1e3
            ),
        }
    }
}

fn dist(a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    (a - b).norm()
}

/// Checks each definition alone, then every body against itself relabelled and against every
/// other body: two layouts are ambiguous when a matching keeps every distance within twice the
/// tolerance (each measured distance may be off by the tolerance).
pub fn check_bodies(defs: &[BodyDef]) -> Result<(), BodyError> {
    let mut names = std::collections::HashSet::new();
    for d in defs {
        if !names.insert(d.name.as_str()) {
            return Err(BodyError::DuplicateName(d.name.clone()));
        }
        check_one(d)?;
    }
    for (i, a) in defs.iter().enumerate() {
        // A pointer's two ends always swap: its direction comes from elsewhere (the blob's
        // moments, or motion), and its roll is unobservable.
        if a.markers_m.len() > 2
            && let Some(x) = embedding(a, a, true)
        {
            return Err(BodyError::Ambiguous(x));
        }
        for b in defs.iter().skip(i + 1) {
            // The smaller (or equal) layout embedded in the larger.
            let (small, big) = if a.markers_m.len() <= b.markers_m.len() {
                (a, b)
            } else {
                (b, a)
            };
            if let Some(x) = embedding(small, big, false) {
                return Err(BodyError::Ambiguous(x));
            }
        }
    }
    Ok(())
}

fn check_one(d: &BodyDef) -> Result<(), BodyError> {
    let n = d.markers_m.len();
    let body = || d.name.clone();
    if !(2..=MAX_MARKERS).contains(&n) {
        return Err(BodyError::MarkerCount {
            body: body(),
            count: n,
        });
    }
    if let Some(marker) = d
        .markers_m
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(BodyError::NotFinite {
            body: body(),
            marker,
        });
    }
    if !(d.tolerance_m > 0.0 && d.tolerance_m < 0.1) {
        return Err(BodyError::Tolerance {
            body: body(),
            value: d.tolerance_m,
        });
    }
    for a in 0..n {
        for b in a + 1..n {
            let distance_m = dist(&d.markers_m[a], &d.markers_m[b]);
            if distance_m <= 2.0 * d.tolerance_m {
                return Err(BodyError::TooClose {
                    body: body(),
                    a,
                    b,
                    distance_m,
                });
            }
        }
    }
    if n >= 3 {
        // Spread off the line through the two farthest markers.
        let (mut a, mut b, mut best) = (0, 1, 0.0);
        for i in 0..n {
            for j in i + 1..n {
                let dd = dist(&d.markers_m[i], &d.markers_m[j]);
                if dd > best {
                    (a, b, best) = (i, j, dd);
                }
            }
        }
        let axis = (d.markers_m[b] - d.markers_m[a]) / best;
        let spread_m = d
            .markers_m
            .iter()
            .map(|p| {
                let v = p - d.markers_m[a];
                (v - axis * v.dot(&axis)).norm()
            })
            .fold(0.0, f64::max);
        if spread_m <= 2.0 * d.tolerance_m {
            return Err(BodyError::Collinear {
                body: body(),
                spread_m,
            });
        }
    }
    Ok(())
}

/// A matching of `small`'s markers into distinct markers of `big` keeping every distance within
/// twice the larger tolerance (for `same`, a relabelling other than the identity).
fn embedding(small: &BodyDef, big: &BodyDef, same: bool) -> Option<Ambiguity> {
    let tol = 2.0 * small.tolerance_m.max(big.tolerance_m);
    let n = small.markers_m.len();
    let mut map = vec![usize::MAX; n];
    let mut used = vec![false; big.markers_m.len()];
    let mut found = None;
    search_embedding(small, big, tol, same, 0, &mut map, &mut used, &mut found);
    found.map(|map: Vec<usize>| {
        let mut worst = (0.0, (0, 1));
        for a in 0..n {
            for b in a + 1..n {
                let diff = (dist(&small.markers_m[a], &small.markers_m[b])
                    - dist(&big.markers_m[map[a]], &big.markers_m[map[b]]))
                .abs();
                if diff >= worst.0 {
                    worst = (diff, (a, b));
                }
            }
        }
        Ambiguity {
            body: small.name.clone(),
            other: (!same).then(|| big.name.clone()),
            mapping: map.iter().enumerate().map(|(a, &b)| (a, b)).collect(),
            worst_difference_m: worst.0,
            needed_m: (tol - worst.0).max(0.0),
            pair: worst.1,
        }
    })
}

#[allow(clippy::too_many_arguments)]
fn search_embedding(
    small: &BodyDef,
    big: &BodyDef,
    tol: f64,
    same: bool,
    k: usize,
    map: &mut [usize],
    used: &mut [bool],
    found: &mut Option<Vec<usize>>,
) {
    if found.is_some() {
        return;
    }
    if k == map.len() {
        if !same || map.iter().enumerate().any(|(a, &b)| a != b) {
            *found = Some(map.to_vec());
        }
        return;
    }
    for c in 0..big.markers_m.len() {
        if used[c] {
            continue;
        }
        let fits = (0..k).all(|j| {
            (dist(&small.markers_m[k], &small.markers_m[j])
                - dist(&big.markers_m[c], &big.markers_m[map[j]]))
            .abs()
                <= tol
        });
        if fits {
            map[k] = c;
            used[c] = true;
            search_embedding(small, big, tol, same, k + 1, map, used, found);
            used[c] = false;
            map[k] = usize::MAX;
        }
    }
}

/// `world_from_body` minimising `Σ wᵢ |R·bodyᵢ + t − worldᵢ|²` (Kabsch/Umeyama, no scale), and
/// the weighted RMS residual, metres. `None` with fewer than 3 points of positive weight, or
/// when they are collinear.
pub fn kabsch(
    body: &[Point3<f64>],
    world: &[Point3<f64>],
    weights: &[f64],
) -> Option<(Isometry3<f64>, f64)> {
    let n = body.len();
    if n != world.len() || n != weights.len() {
        return None;
    }
    let total: f64 = weights.iter().filter(|w| **w > 0.0).sum();
    if weights.iter().filter(|w| **w > 0.0).count() < 3 || total <= 0.0 {
        return None;
    }
    let mean = |pts: &[Point3<f64>]| {
        pts.iter()
            .zip(weights)
            .filter(|(_, w)| **w > 0.0)
            .fold(Vector3::zeros(), |acc, (p, w)| acc + p.coords * *w)
            / total
    };
    let (cb, cw) = (mean(body), mean(world));
    let mut h = Matrix3::zeros();
    for ((b, p), w) in body.iter().zip(world).zip(weights) {
        if *w > 0.0 {
            h += (b.coords - cb) * (p.coords - cw).transpose() * *w;
        }
    }
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // The second singular value is zero for collinear points: the rotation about them is free.
    if svd.singular_values[1] <= 1e-12 * svd.singular_values[0].max(1e-300) {
        return None;
    }
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r = v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    // V·diag(1, 1, ±1)·Uᵀ is orthonormal by construction: converted directly (an iterative
    // fit to the nearest rotation cost more than the rest of the pose).
    let rotation =
        UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    let t = cw - rotation * cb;
    let pose = Isometry3::from_parts(Translation3::from(t), rotation);
    let sq: f64 = body
        .iter()
        .zip(world)
        .zip(weights)
        .filter(|(_, w)| **w > 0.0)
        .map(|((b, p), w)| (pose * b - p).norm_squared() * w)
        .sum();
    Some((pose, (sq / total).sqrt()))
}

/// The pose of a two-marker body (a pointer) from its two points, `world` in marker order:
/// the rotation is the shortest one taking the defined axis (marker 0 → 1) onto the measured
/// one, so its roll about the axis is not measured (zero twist by construction); the origin is
/// placed so both markers are off by the same amount along the axis. The residual is half the
/// length error.
pub fn pointer_pose(def: &BodyDef, world: &[Point3<f64>]) -> Option<(Isometry3<f64>, f64)> {
    let ([b0, b1], [w0, w1]) = (def.markers_m.as_slice(), world) else {
        return None;
    };
    let (axis_b, axis_w) = (b1 - b0, w1 - w0);
    let rotation = UnitQuaternion::rotation_between(&axis_b, &axis_w).or_else(|| {
        // Opposite axes: any half turn about an axis perpendicular to them.
        let perp = axis_b
            .cross(&Vector3::x())
            .try_normalize(1e-9)
            .or_else(|| axis_b.cross(&Vector3::y()).try_normalize(1e-9))?;
        Some(UnitQuaternion::from_axis_angle(
            &nalgebra::Unit::new_unchecked(perp),
            std::f64::consts::PI,
        ))
    })?;
    let mid_b = nalgebra::center(b0, b1);
    let mid_w = nalgebra::center(w0, w1);
    let t = mid_w.coords - rotation * mid_b.coords;
    let residual = (axis_w.norm() - axis_b.norm()).abs() / 2.0;
    Some((
        Isometry3::from_parts(Translation3::from(t), rotation),
        residual,
    ))
}

/// One body found in a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyMatch {
    /// Index into the definitions.
    pub body: usize,
    /// For each marker of the body, the index of the point it was found at (`None`: missing).
    pub markers: Vec<Option<usize>>,
    pub world_from_body: Isometry3<f64>,
    /// RMS distance of the seen markers from where the pose puts them, metres.
    pub residual_m: f64,
}

impl BodyMatch {
    pub fn seen(&self) -> usize {
        self.markers.iter().filter(|m| m.is_some()).count()
    }
}

/// A candidate match of one body: points per marker and the sum of squared distance errors.
#[derive(Debug, Clone)]
struct Candidate {
    markers: Vec<Option<usize>>,
    seen: usize,
    cost: f64,
    /// The points used, sorted, padded with `u32::MAX` (compared without allocating).
    set: [u32; MAX_MARKERS],
}

/// Candidates kept per body for the joint choice.
const CANDIDATES_PER_BODY: usize = 4;

/// Finds the bodies among `points` (world, metres). Each body's candidates are the ways to
/// give its markers distinct points with every pairwise distance within its tolerance (whole
/// if it can be; else any markers missing as long as three are seen; none for a pointer); the
/// choice
/// over all bodies together uses no point twice, explains the most markers and then has the
/// least squared distance error. A choice whose pose leaves a seen marker more than the
/// tolerance from its point is rejected (a wrong assignment). Bodies not found are absent.
pub fn identify(defs: &[BodyDef], points: &[Point3<f64>]) -> Vec<BodyMatch> {
    identify_near(defs, points, &[])
}

/// [`identify`] with each body's pose in the previous frame, where known (`near[b]`; missing
/// or `None`: unknown). A body seen only in part can fit its points in more than one way (three
/// markers forming a nearly isosceles triangle fit the definition's triangle turned over): the
/// way nearest its previous pose is taken, and without one such a body is not reported —
/// never a pose that may be turned round.
pub fn identify_near(
    defs: &[BodyDef],
    points: &[Point3<f64>],
    near: &[Option<Isometry3<f64>>],
) -> Vec<BodyMatch> {
    let m = points.len();
    let mut d = vec![0.0; m * m];
    for i in 0..m {
        for j in i + 1..m {
            let v = dist(&points[i], &points[j]);
            d[i * m + j] = v;
            d[j * m + i] = v;
        }
    }
    let pairs = PairIndex::new(defs, &d, m);
    let all: Vec<Vec<Candidate>> = defs
        .iter()
        .map(|def| body_candidates(def, &d, &pairs, m))
        .collect();
    // The joint choice is over point sets: the best few distinct sets of each body.
    let candidates: Vec<Vec<Candidate>> = all.iter().map(|c| distinct_sets(c)).collect();
    // Joint choice: depth-first over bodies, each taking one of its candidates or none.
    let mut best: (usize, f64, Vec<Option<usize>>) = (0, f64::INFINITY, vec![None; defs.len()]);
    let mut choice = vec![None; defs.len()];
    let mut used = vec![false; m];
    choose(&candidates, 0, &mut choice, &mut used, 0, 0.0, &mut best);
    let mut out = Vec::new();
    for (b, c) in best.2.iter().enumerate() {
        let Some(ci) = *c else { continue };
        let def = &defs[b];
        let set = candidates[b][ci].set;
        // Every way of giving that set of points to the body's markers.
        let ways: Vec<(Isometry3<f64>, f64, &Candidate)> = all[b]
            .iter()
            .filter(|c| c.set == set)
            .filter_map(|c| pose_of(def, c, points).map(|(p, r)| (p, r, c)))
            .collect();
        let prev = near.get(b).copied().flatten();
        // Beside its previous pose, a body cannot have turned further than this since: a way
        // that would have it so is a fit of the wrong markers (the right ones hidden or too
        // noisy to fit), and the body is left unseen this frame.
        let ways: Vec<_> = match prev {
            Some(p) => ways
                .into_iter()
                .filter(|w| w.0.rotation.angle_to(&p.rotation) <= MAX_TURN_RAD)
                .collect(),
            None => ways,
        };
        let chosen = match (ways.len(), prev) {
            (0, _) => continue,
            (1, _) => &ways[0],
            (_, Some(prev)) => {
                let turn = |p: &Isometry3<f64>| p.rotation.angle_to(&prev.rotation);
                let Some(w) = ways.iter().min_by(|a, b| turn(&a.0).total_cmp(&turn(&b.0))) else {
                    continue;
                };
                w
            }
            // A pointer's two ends look alike: its first sighting takes either (then it is
            // followed).
            (_, None) if def.markers_m.len() == 2 => &ways[0],
            // Several ways and nothing to tell them apart: not reported.
            (_, None) => continue,
        };
        out.push(BodyMatch {
            body: b,
            markers: chosen.2.markers.clone(),
            world_from_body: chosen.0,
            residual_m: chosen.1,
        });
    }
    out
}

/// The most a body may turn between its previous pose and this one (45°: 1350°/s at 30 Hz,
/// beyond a head's fastest turn).
pub const MAX_TURN_RAD: f64 = std::f64::consts::FRAC_PI_4;

/// The best candidate of each distinct point set, best first, at most
/// [`CANDIDATES_PER_BODY`].
fn distinct_sets(all: &[Candidate]) -> Vec<Candidate> {
    let mut out: Vec<Candidate> = Vec::new();
    for c in all {
        if !out.iter().any(|o| o.set == c.set) {
            out.push(c.clone());
            if out.len() == CANDIDATES_PER_BODY {
                break;
            }
        }
    }
    out
}

/// The pose a candidate gives, if every seen marker lands within the tolerance of its point
/// (a wrong assignment does not).
fn pose_of(
    def: &BodyDef,
    cand: &Candidate,
    points: &[Point3<f64>],
) -> Option<(Isometry3<f64>, f64)> {
    let (mut body_pts, mut world_pts) = (Vec::new(), Vec::new());
    for (k, p) in cand.markers.iter().enumerate() {
        if let Some(p) = p {
            body_pts.push(def.markers_m[k]);
            world_pts.push(points[*p]);
        }
    }
    let weights = vec![1.0; body_pts.len()];
    let (pose, residual_m) = if def.markers_m.len() == 2 {
        pointer_pose(def, &world_pts)
    } else {
        kabsch(&body_pts, &world_pts, &weights)
    }?;
    let worst = body_pts
        .iter()
        .zip(&world_pts)
        .map(|(b, w)| (pose * b - w).norm())
        .fold(0.0, f64::max);
    (worst <= def.tolerance_m).then_some((pose, residual_m))
}

fn choose(
    candidates: &[Vec<Candidate>],
    b: usize,
    choice: &mut Vec<Option<usize>>,
    used: &mut [bool],
    seen: usize,
    cost: f64,
    best: &mut (usize, f64, Vec<Option<usize>>),
) {
    if b == candidates.len() {
        if seen > best.0 || (seen == best.0 && cost < best.1) {
            *best = (seen, cost, choice.clone());
        }
        return;
    }
    // Bound: even taking every remaining body's best cannot beat the best so far.
    let rest: usize = candidates[b..]
        .iter()
        .map(|c| c.first().map_or(0, |x| x.seen))
        .sum();
    if seen + rest < best.0 {
        return;
    }
    for (i, c) in candidates[b].iter().enumerate() {
        if c.markers.iter().flatten().any(|p| used[*p]) {
            continue;
        }
        for p in c.markers.iter().flatten() {
            used[*p] = true;
        }
        choice[b] = Some(i);
        choose(
            candidates,
            b + 1,
            choice,
            used,
            seen + c.seen,
            cost + c.cost,
            best,
        );
        choice[b] = None;
        for p in c.markers.iter().flatten() {
            used[*p] = false;
        }
    }
    choose(candidates, b + 1, choice, used, seen, cost, best);
}

/// The frame's point pairs no farther apart than any body's longest distance (plus its
/// tolerance), bucketed by distance (bucket width: the largest tolerance): the pairs that can
/// be a body's first two markers are then a bucket or three, not every pair of points.
struct PairIndex {
    width_m: f64,
    /// Bucket b's pairs are `pairs[start[b]..start[b + 1]]`.
    start: Vec<usize>,
    pairs: Vec<(u32, u32)>,
}

impl PairIndex {
    fn new(defs: &[BodyDef], d: &[f64], m: usize) -> Self {
        let tol = defs.iter().map(|x| x.tolerance_m).fold(0.0, f64::max);
        let reach = defs
            .iter()
            .flat_map(|x| {
                x.markers_m
                    .iter()
                    .flat_map(move |a| x.markers_m.iter().map(move |b| dist(a, b) + x.tolerance_m))
            })
            .fold(0.0, f64::max);
        // At most 4096 buckets, however small the tolerance.
        let width_m = tol.max(reach / 4096.0).max(1e-9);
        let buckets = (reach / width_m) as usize + 1;
        let bucket = |v: f64| (v / width_m) as usize;
        let mut count = vec![0usize; buckets + 1];
        for i in 0..m {
            for j in i + 1..m {
                let v = d[i * m + j];
                if v <= reach {
                    count[bucket(v) + 1] += 1;
                }
            }
        }
        for b in 0..buckets {
            count[b + 1] += count[b];
        }
        let start = count.clone();
        let mut pairs = vec![(0u32, 0u32); count[buckets]];
        for i in 0..m {
            for j in i + 1..m {
                let v = d[i * m + j];
                if v <= reach {
                    let slot = &mut count[bucket(v)];
                    pairs[*slot] = (i as u32, j as u32);
                    *slot += 1;
                }
            }
        }
        PairIndex {
            width_m,
            start,
            pairs,
        }
    }

    /// The pairs whose distance may lie in `[lo, hi]` (a superset: check each).
    fn within(&self, lo: f64, hi: f64) -> &[(u32, u32)] {
        let last = self.start.len() - 2;
        let b0 = ((lo.max(0.0) / self.width_m) as usize).min(last + 1);
        let b1 = ((hi.max(0.0) / self.width_m) as usize).min(last);
        if b0 > b1 {
            return &[];
        }
        &self.pairs[self.start[b0]..self.start[b1 + 1]]
    }
}

fn body_candidates(def: &BodyDef, d: &[f64], pairs: &PairIndex, m: usize) -> Vec<Candidate> {
    let n = def.markers_m.len();
    // Every marker of a pointer; three of any larger body (a pose needs three).
    let min_seen = n.min(3);
    let mut dd = vec![0.0; n * n];
    for a in 0..n {
        for b in 0..n {
            dd[a * n + b] = dist(&def.markers_m[a], &def.markers_m[b]);
        }
    }
    let mut out: Vec<Candidate> = Vec::new();
    let mut map = vec![None; n];
    let mut used = vec![false; m];
    // Whole first (no branch for a missing marker: the usual frame, and far fewer branches);
    // only a body not found whole is searched again with markers allowed to be missing.
    for need in [n, min_seen] {
        let ctx = Ctx {
            n,
            m,
            d,
            pairs,
            dd: &dd,
            tol: def.tolerance_m,
            min_seen: need,
        };
        search_body(&ctx, 0, 0, 0.0, &mut map, &mut used, &mut out);
        if !out.is_empty() {
            break;
        }
    }
    out.sort_by(|a, b| b.seen.cmp(&a.seen).then(a.cost.total_cmp(&b.cost)));
    out
}

struct Ctx<'a> {
    n: usize,
    m: usize,
    d: &'a [f64],
    pairs: &'a PairIndex,
    dd: &'a [f64],
    tol: f64,
    min_seen: usize,
}

/// Hard cap on the candidates a body's search collects before keeping the best few.
const MAX_CANDIDATES: usize = 256;

fn search_body(
    c: &Ctx<'_>,
    k: usize,
    seen: usize,
    cost: f64,
    map: &mut [Option<usize>],
    used: &mut [bool],
    out: &mut Vec<Candidate>,
) {
    if out.len() >= MAX_CANDIDATES {
        return;
    }
    if k == c.n {
        if seen >= c.min_seen {
            let mut set = [u32::MAX; MAX_MARKERS];
            for (slot, p) in set.iter_mut().zip(map.iter().flatten()) {
                *slot = *p as u32;
            }
            set.sort_unstable();
            out.push(Candidate {
                markers: map.to_vec(),
                seen,
                cost,
                set,
            });
        }
        return;
    }
    // Not enough markers left to reach the minimum.
    if seen + (c.n - k) < c.min_seen {
        return;
    }
    // The whole body wanted: its first two markers from the pairs at about their distance.
    if k == 0 && c.n >= 2 && c.min_seen == c.n {
        let want = c.dd[1];
        for &(i, j) in c.pairs.within(want - c.tol, want + c.tol) {
            let e = c.d[i as usize * c.m + j as usize] - want;
            if e.abs() > c.tol {
                continue;
            }
            for (p0, p1) in [(i as usize, j as usize), (j as usize, i as usize)] {
                map[0] = Some(p0);
                map[1] = Some(p1);
                used[p0] = true;
                used[p1] = true;
                search_body(c, 2, 2, e * e, map, used, out);
                used[p0] = false;
                used[p1] = false;
                map[0] = None;
                map[1] = None;
            }
        }
        return;
    }
    for p in 0..c.m {
        if used[p] {
            continue;
        }
        let mut add = 0.0;
        let mut fits = true;
        for (j, q) in map.iter().enumerate().take(k) {
            if let Some(q) = q {
                let e = c.d[p * c.m + q] - c.dd[k * c.n + j];
                if e.abs() > c.tol {
                    fits = false;
                    break;
                }
                add += e * e;
            }
        }
        if fits {
            map[k] = Some(p);
            used[p] = true;
            search_body(c, k + 1, seen + 1, cost + add, map, used, out);
            used[p] = false;
            map[k] = None;
        }
    }
    // This marker missing.
    search_body(c, k + 1, seen, cost, map, used, out);
}

pub mod filter;
pub mod gaps;
pub mod pivot;
pub mod tracker;

#[cfg(test)]
mod tests;

/// One camera's sighting of one marker, for [`refine_reprojection`]: the marker in the body's
/// frame, the camera's projection of a world point to pixels, and the pixel measured.
pub struct Sighting<'a> {
    pub marker_body: Point3<f64>,
    pub project: &'a dyn Fn(&Point3<f64>) -> Option<nalgebra::Point2<f64>>,
    pub pixel: nalgebra::Point2<f64>,
}

impl std::fmt::Debug for Sighting<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Sighting({} at {})", self.marker_body, self.pixel)
    }
}

/// `world_from_body` refined so that the markers it places project onto the pixels the
/// cameras measured (Levenberg–Marquardt on the 6 pose parameters, numerical Jacobian): the
/// cameras' own errors — small across the image, large along a ray in depth — weigh each
/// direction as they should, where Kabsch on triangulated points weighs every direction alike.
/// Returns the pose and the RMS reprojection error in pixels; `None` with fewer than 4
/// sightings (8 residuals for 6 unknowns) or when a marker falls behind a camera. Stops when a
/// step no longer lowers the squared error by more than 1e-12 of it.
pub fn refine_reprojection(
    pose: &Isometry3<f64>,
    sightings: &[Sighting<'_>],
    iterations: usize,
) -> Option<(Isometry3<f64>, f64)> {
    use nalgebra::{Matrix6, Vector2, Vector6};
    if sightings.len() < 4 {
        return None;
    }
    let step = |p: &Isometry3<f64>, d: &Vector6<f64>| {
        Isometry3::from_parts(
            Translation3::from(p.translation.vector + Vector3::new(d[3], d[4], d[5])),
            UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])) * p.rotation,
        )
    };
    let residual = |p: &Isometry3<f64>, s: &Sighting<'_>| -> Option<Vector2<f64>> {
        let q = (s.project)(&(p * s.marker_body))?;
        Some(Vector2::new(q.x - s.pixel.x, q.y - s.pixel.y))
    };
    let cost_of = |p: &Isometry3<f64>| -> Option<f64> {
        sightings
            .iter()
            .map(|s| residual(p, s).map(|r| r.norm_squared()))
            .sum()
    };
    // The six nudged poses of the numerical Jacobian.
    const H: f64 = 1e-6;
    let mut pose = *pose;
    let mut cost = cost_of(&pose)?;
    let mut lambda = 1e-3;
    for _ in 0..iterations {
        let nudged: [Isometry3<f64>; 6] = std::array::from_fn(|k| {
            let mut d = Vector6::zeros();
            d[k] = H;
            step(&pose, &d)
        });
        // Normal equations, accumulated sighting by sighting (no matrix of all residuals).
        let (mut h, mut g) = (Matrix6::zeros(), Vector6::zeros());
        for s in sightings {
            let r = residual(&pose, s)?;
            let mut j = nalgebra::Matrix2x6::zeros();
            for (k, n) in nudged.iter().enumerate() {
                j.set_column(k, &((residual(n, s)? - r) / H));
            }
            h += j.transpose() * j;
            g += j.transpose() * r;
        }
        let mut improved = false;
        for _ in 0..8 {
            let mut a = h;
            for k in 0..6 {
                a[(k, k)] += lambda * (1.0 + h[(k, k)]);
            }
            let Some(d) = a.lu().solve(&(-g)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = step(&pose, &d);
            if let Some(c) = cost_of(&candidate)
                && c < cost
            {
                let gain = cost - c;
                pose = candidate;
                cost = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = gain > 1e-12 * (1.0 + cost);
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    Some((pose, (cost / sightings.len() as f64).sqrt()))
}
