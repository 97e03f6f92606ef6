//! Which blob in one camera is which blob in another: cross-camera correspondence for several
//! objects seen by several calibrated cameras.
//!
//! Not in the thesis, which tracked one object per camera window. Here:
//!
//! 1. for each pair of cameras, the cost of pairing blob i of camera a with blob j of camera b
//!    is their symmetric epipolar distance in pixels (undistorted); pairs beyond
//!    `max_epipolar_px` are not allowed. With more than two cameras each allowed pair is also
//!    put to the others ([`Verdict`]): the point its two rays meet at is projected into every
//!    other camera whose image it falls in, and each of them *confirms* it (a free blob within
//!    `confirm_px`) or *denies* it (no blob at all within `absent_px`). Every such camera that
//!    does not confirm adds a share of `max_epipolar_px` to the cost, so the assignment
//!    prefers the pairs the other views agree with, and a new pair (not both of its blobs
//!    claimed by one followed object) that no other camera confirms and one denies is not
//!    allowed: in a dense scene many blobs lie on each epipolar line, and a pair of two of
//!    them whose rays meet where no marker is (a ghost) is seen through by the cameras that
//!    look there and find nothing;
//! 2. a global minimum-cost assignment (`stereoscope_vision::assign`) picks the pairs — not a
//!    greedy first match, which steals blobs at crossings;
//! 3. each pair is triangulated and rejected if its reprojection residual exceeds
//!    `max_residual_px` or it lies behind a camera (with more than two cameras, once, after
//!    step 4: until then the point is where its rays meet);
//! 4. the other cameras' free blobs are assigned to the new points by reprojection distance
//!    (a global assignment per camera, solved group by group over the pairs within reach,
//!    `stereoscope_numeric::assign::assign_sparse`, so its work follows the points, not
//!    points × blobs) and each point re-triangulated once with all its views.
//!
//! Cost, measured (`docs/performance.md`, "Dense scenes"): fusion takes 0.6 ms a set for 50
//! markers and 2.9 ms for 200 in 8 cameras on one core of the 2-vCPU Xeon.
//!
//! Works for the parallel rig (where epipolar lines are image rows) and any general rig.
//!
//! [`match_labelled`] also takes, per blob, the followed objects whose predicted position
//! projects onto it: two blobs that only other objects claim are never paired, nor joined to a
//! point (step 4). Two markers on one epipolar line then cannot pair crosswise into a ghost
//! while they are followed; where two objects' images meet in one view, a blob claimed by both
//! may pair with either.

use crate::camera::Camera;
use crate::triangulate::{Observation, Triangulated, triangulate};
use nalgebra::{Matrix3, Point2, Point3, Vector2, Vector3};
use stereoscope_numeric::assign::{Assigner, assign_sparse};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrespondConfig {
    /// Largest symmetric epipolar distance for a pair, pixels.
    pub max_epipolar_px: f64,
    /// Largest RMS reprojection residual of an accepted point, pixels.
    pub max_residual_px: f64,
    /// A third camera's free blob this near where a pair's point projects confirms the pair,
    /// pixels.
    pub confirm_px: f64,
    /// A third camera whose image a pair's point falls in, with no blob this near where it
    /// projects, denies the pair, pixels: wider than `confirm_px`, so that a marker whose image
    /// merged with another's there (its centroid pulled towards the other's) is not denied.
    pub absent_px: f64,
}

impl Default for CorrespondConfig {
    fn default() -> Self {
        CorrespondConfig {
            max_epipolar_px: 3.0,
            max_residual_px: 2.0,
            confirm_px: 4.0,
            absent_px: 8.0,
        }
    }
}

/// What the other cameras say of a pair of blobs: how many confirm it, how many could see its
/// point (it falls in their image, in front of them), how many deny it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Verdict {
    pub confirmed: usize,
    pub in_view: usize,
    pub denied: usize,
}

/// A camera's optical centre and each blob's ray direction (world; `None` where the pixel does
/// not undistort).
type CameraRays = (Point3<f64>, Vec<Option<Vector3<f64>>>);

/// A pair's point where its two rays meet, for finding the other cameras' blobs of it before
/// it is triangulated (`residuals_px` and `rms_px` are those of this point; a provisional
/// point is re-triangulated, and refused if that fit is off, by [`extend`]). `None` when the
/// rays do not meet in front of both cameras.
fn provisional(
    cams: &[Camera],
    rays: &[CameraRays],
    obs: &[Observation; 2],
    (a, i): (usize, usize),
    (b, j): (usize, usize),
) -> Option<Triangulated> {
    let p = meet(&rays[a].0, &rays[a].1[i]?, &rays[b].0, &rays[b].1[j]?)?;
    let residuals_px = obs
        .iter()
        .map(|o| cams[o.camera].project(&p).map(|q| (q - o.pixel).norm()))
        .collect::<Option<Vec<f64>>>()?;
    let rms_px = (residuals_px.iter().map(|r| r * r).sum::<f64>() / 2.0).sqrt();
    Some(Triangulated {
        point_world: p,
        rms_px,
        residuals_px,
        cameras: vec![a, b],
    })
}

/// One camera's blobs in order of x, for "which blobs lie within r of this pixel" in
/// O(log n + those near in x) rather than a pass over every blob.
#[derive(Debug, Clone, Default)]
pub struct ByX(Vec<(f64, usize)>);

impl ByX {
    /// The index of `pixels` (non-finite ones left out).
    pub fn new(pixels: &[Point2<f64>]) -> Self {
        let mut v: Vec<(f64, usize)> = pixels
            .iter()
            .enumerate()
            .filter(|(_, p)| p.x.is_finite() && p.y.is_finite())
            .map(|(j, p)| (p.x, j))
            .collect();
        v.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        ByX(v)
    }

    /// The blobs within `r` of `at`, as (index into `pixels`, distance); `pixels` is the slice
    /// the index was made of.
    pub fn near<'a>(
        &'a self,
        pixels: &'a [Point2<f64>],
        at: Point2<f64>,
        r: f64,
    ) -> impl Iterator<Item = (usize, f64)> + 'a {
        let start = self.0.partition_point(|e| e.0 < at.x - r);
        self.0[start..]
            .iter()
            .take_while(move |e| e.0 <= at.x + r)
            .filter_map(move |&(_, j)| {
                let d = (pixels[j] - at).norm();
                (d <= r).then_some((j, d))
            })
    }
}

/// The point nearest both rays (origins `oa`, `ob`, directions `da`, `db`), if it lies in
/// front of both cameras and the rays are not parallel: the midpoint of their common
/// perpendicular. A first guess for [`Verdict`], not a triangulation.
fn meet(
    oa: &Point3<f64>,
    da: &Vector3<f64>,
    ob: &Point3<f64>,
    db: &Vector3<f64>,
) -> Option<Point3<f64>> {
    let w = oa - ob;
    let (a, b, c) = (da.dot(da), da.dot(db), db.dot(db));
    let (d, e) = (da.dot(&w), db.dot(&w));
    let den = a * c - b * b;
    if !(den > 1e-12 * a * c) {
        return None;
    }
    let (s, t) = ((b * e - c * d) / den, (a * e - b * d) / den);
    if !(s > 0.0 && t > 0.0) {
        return None;
    }
    Some(Point3::from(
        0.5 * ((oa + da * s).coords + (ob + db * t).coords),
    ))
}

/// A point matched across cameras: which blob of each camera, and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct Match {
    /// `(camera, blob index)` pairs.
    pub blobs: Vec<(usize, usize)>,
    pub point: Triangulated,
}

/// The essential matrix taking camera a's normalised coordinates to epipolar lines in camera b:
/// `x_bᵀ · E · x_a = 0`.
pub fn essential(a: &Camera, b: &Camera) -> Matrix3<f64> {
    let b_from_a = b.cam_from_world * a.cam_from_world.inverse();
    let t = b_from_a.translation.vector;
    let tx = Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0);
    tx * b_from_a.rotation.to_rotation_matrix().matrix()
}

/// Distance in pixels of `x_b` from the epipolar line of `x_a`, and of `x_a` from the line of
/// `x_b`, averaged (normalised coordinates in, scaled by each camera's mean focal length).
fn symmetric_epipolar_px(
    e: &Matrix3<f64>,
    xa: Vector2<f64>,
    fa: f64,
    xb: Vector2<f64>,
    fb: f64,
) -> f64 {
    let (ha, hb) = (Vector3::new(xa.x, xa.y, 1.0), Vector3::new(xb.x, xb.y, 1.0));
    let lb = e * ha; // line in b
    let la = e.transpose() * hb; // line in a
    let num = hb.dot(&lb).abs();
    let db = num / lb.xy().norm().max(1e-300) * fb;
    let da = num / la.xy().norm().max(1e-300) * fa;
    0.5 * (da + db)
}

/// Which followed objects a blob may be (their predictions project onto it); empty: any.
pub type Claims = Vec<u32>;

/// What pairing two blobs (or a point and a blob) adds to the cost beside their distance, in
/// units of the largest distance allowed: 0 when both are unclaimed or they share an object;
/// 1 when only one is claimed (a followed object's blob taken by a newcomer, allowed but
/// last); `None` when they are claimed by different objects only.
fn claim_penalty(a: &[u32], b: &[u32]) -> Option<f64> {
    match (a.is_empty(), b.is_empty()) {
        (true, true) => Some(0.0),
        (false, false) => a.iter().any(|x| b.contains(x)).then_some(0.0),
        _ => Some(1.0),
    }
}

/// The claims of blob `j` of camera `c` (none when not given).
fn claims_of(labels: &[Vec<Claims>], c: usize, j: usize) -> &[u32] {
    labels
        .get(c)
        .and_then(|l| l.get(j))
        .map_or(&[], |v| v.as_slice())
}

/// A match's claims: the objects every claimed blob of it allows (empty when none is claimed).
fn match_claims(labels: &[Vec<Claims>], m: &Match) -> Claims {
    let mut out: Option<Claims> = None;
    for &(c, j) in &m.blobs {
        let l = claims_of(labels, c, j);
        if l.is_empty() {
            continue;
        }
        out = Some(match out {
            None => l.to_vec(),
            Some(o) => o.into_iter().filter(|x| l.contains(x)).collect(),
        });
    }
    out.unwrap_or_default()
}

/// Gives the other cameras' free blobs to the points they reproject onto (step 4), camera by
/// camera, one global assignment each. A blob within `max_residual_px` of the point joins it
/// at once (its residual cannot lift the point's RMS above the bound); one farther (up to twice
/// that) joins only if the point re-triangulated with it stays within the bound. Each point
/// that gained views is re-triangulated once at the end; should its RMS then exceed the bound,
/// the views it gained leave it, worst first, until it does not. Every point comes in
/// provisional (where its pair's rays meet) and is triangulated here; one whose fit on its
/// pair alone is off is refused (`false` in the result).
#[allow(clippy::too_many_arguments)]
fn extend(
    cams: &[Camera],
    pixels: &[Vec<Point2<f64>>],
    labels: &[Vec<Claims>],
    cfg: &CorrespondConfig,
    by_x: &[ByX],
    used: &mut [Vec<bool>],
    out: &mut [Match],
    assigner: &mut Assigner,
) -> Vec<bool> {
    let n = used.len();
    let bound = cfg.max_residual_px * 2.0;
    let views = |blobs: &[(usize, usize)]| -> Vec<Observation> {
        blobs
            .iter()
            .map(|&(c, j)| Observation {
                camera: c,
                pixel: pixels[c][j],
            })
            .collect()
    };
    // How many views each point had before this pass.
    let before: Vec<usize> = out.iter().map(|m| m.blobs.len()).collect();
    let mut keep = vec![true; out.len()];
    for c in 0..n {
        let open: Vec<usize> = (0..out.len())
            .filter(|&m| !out[m].blobs.iter().any(|b| b.0 == c))
            .collect();
        if open.is_empty() {
            continue;
        }
        // The allowed (point, blob) pairs: free blobs within the bound of where the point
        // projects, found by x.
        let mut allowed: Vec<(usize, usize, f64)> = Vec::new();
        let mut dist: Vec<(usize, usize, f64)> = Vec::new();
        for (r, &m) in open.iter().enumerate() {
            let Some(proj) = cams[c].project(&out[m].point.point_world) else {
                continue;
            };
            let claims = match_claims(labels, &out[m]);
            for (j, d) in by_x[c].near(&pixels[c], proj, bound) {
                if used[c][j] {
                    continue;
                }
                if let Some(k) = claim_penalty(&claims, claims_of(labels, c, j)) {
                    allowed.push((r, j, d + k * bound));
                    dist.push((r, j, d));
                }
            }
        }
        if allowed.is_empty() {
            continue;
        }
        let chosen = assign_sparse(&allowed, open.len(), pixels[c].len(), assigner);
        let pairs: Vec<(usize, usize, f64)> = dist
            .into_iter()
            .filter(|&(r, j, _)| chosen[r] == Some(j))
            .map(|(r, j, d)| (open[r], j, d))
            .collect();
        for (m, j, d) in pairs {
            if d <= cfg.max_residual_px {
                out[m].blobs.push((c, j));
                used[c][j] = true;
                continue;
            }
            let mut blobs = out[m].blobs.clone();
            blobs.push((c, j));
            if let Ok(t) = triangulate(cams, &views(&blobs))
                && t.rms_px <= cfg.max_residual_px
            {
                used[c][j] = true;
                out[m] = Match { blobs, point: t };
            }
        }
    }
    for m in 0..out.len() {
        loop {
            match triangulate(cams, &views(&out[m].blobs)) {
                Ok(t) if t.rms_px <= cfg.max_residual_px => {
                    out[m].point = t;
                    break;
                }
                fitted => {
                    // The worst of the views gained in this pass leaves (its blob freed);
                    // with none left, the point stays as it was before them.
                    let gained = before[m]..out[m].blobs.len();
                    let worst = match &fitted {
                        Ok(t) => gained
                            .clone()
                            .max_by(|&x, &y| t.residuals_px[x].total_cmp(&t.residuals_px[y])),
                        Err(_) => gained.clone().last(),
                    };
                    let Some(k) = worst else {
                        keep[m] = false;
                        break;
                    };
                    let (c, j) = out[m].blobs.remove(k);
                    used[c][j] = false;
                }
            }
        }
    }
    keep
}

/// Matches the blobs (`pixels[camera][blob]`) of several cameras into 3D points.
pub fn match_blobs(
    cams: &[Camera],
    pixels: &[Vec<Point2<f64>>],
    cfg: &CorrespondConfig,
) -> Vec<Match> {
    match_labelled(cams, pixels, &[], cfg)
}

/// [`match_blobs`] with each blob's claims (`labels[camera][blob]`; missing: unclaimed): a
/// pair whose blobs are claimed by different objects only is not allowed.
pub fn match_labelled(
    cams: &[Camera],
    pixels: &[Vec<Point2<f64>>],
    labels: &[Vec<Claims>],
    cfg: &CorrespondConfig,
) -> Vec<Match> {
    let n = cams.len().min(pixels.len());
    let norm: Vec<Vec<Option<Vector2<f64>>>> = (0..n)
        .map(|c| pixels[c].iter().map(|p| cams[c].normalised(*p)).collect())
        .collect();
    let focal = |c: usize| 0.5 * (cams[c].intrinsics.fx + cams[c].intrinsics.fy);
    let mut used: Vec<Vec<bool>> = (0..n).map(|c| vec![false; pixels[c].len()]).collect();
    // For the other cameras' verdicts (more than two cameras only): each blob's ray, each
    // camera's blobs by x.
    let by_x: Vec<ByX> = (0..n).map(|c| ByX::new(&pixels[c])).collect();
    let rays: Vec<CameraRays> = if n > 2 {
        (0..n)
            .map(|c| {
                let world_from_cam = cams[c].cam_from_world.inverse();
                let dirs = norm[c]
                    .iter()
                    .map(|x| x.map(|x| world_from_cam.rotation * Vector3::new(x.x, x.y, 1.0)))
                    .collect();
                (world_from_cam * Point3::origin(), dirs)
            })
            .collect()
    } else {
        Vec::new()
    };
    let verdict = |a: usize, i: usize, b: usize, j: usize, used: &[Vec<bool>]| -> Verdict {
        let (Some(da), Some(db)) = (rays[a].1[i], rays[b].1[j]) else {
            return Verdict::default();
        };
        let Some(p) = meet(&rays[a].0, &da, &rays[b].0, &db) else {
            return Verdict::default();
        };
        let mut v = Verdict::default();
        for c in (0..n).filter(|&c| c != a && c != b) {
            let Some(px) = cams[c].project(&p) else {
                continue;
            };
            let (w, h) = (
                cams[c].intrinsics.width as f64,
                cams[c].intrinsics.height as f64,
            );
            if !(px.x >= 0.0 && px.y >= 0.0 && px.x < w && px.y < h) {
                continue;
            }
            v.in_view += 1;
            let (mut any, mut free) = (false, false);
            for (k, d) in by_x[c].near(&pixels[c], px, cfg.absent_px.max(cfg.confirm_px)) {
                any |= d <= cfg.absent_px;
                free |= d <= cfg.confirm_px && !used[c][k];
            }
            v.confirmed += usize::from(free);
            v.denied += usize::from(!any);
        }
        v
    };
    let mut out: Vec<Match> = Vec::new();
    let mut assigner = Assigner::default();
    let mut cost = Vec::new();
    for a in 0..n {
        for b in a + 1..n {
            let e = essential(&cams[a], &cams[b]);
            let (ia, ib): (Vec<usize>, Vec<usize>) = (
                (0..pixels[a].len())
                    .filter(|&i| !used[a][i] && norm[a][i].is_some())
                    .collect(),
                (0..pixels[b].len())
                    .filter(|&j| !used[b][j] && norm[b][j].is_some())
                    .collect(),
            );
            if ia.is_empty() || ib.is_empty() {
                continue;
            }
            cost.clear();
            for &i in &ia {
                for &j in &ib {
                    let (Some(xa), Some(xb)) = (norm[a][i], norm[b][j]) else {
                        cost.push(f64::INFINITY);
                        continue;
                    };
                    let d = symmetric_epipolar_px(&e, xa, focal(a), xb, focal(b));
                    let (ca, cb) = (claims_of(labels, a, i), claims_of(labels, b, j));
                    let penalty = claim_penalty(ca, cb);
                    let Some(k) = penalty.filter(|_| d <= cfg.max_epipolar_px) else {
                        cost.push(f64::INFINITY);
                        continue;
                    };
                    let mut c = d + k * cfg.max_epipolar_px;
                    if n > 2 {
                        let v = verdict(a, i, b, j, &used);
                        // One followed object's blobs in both: it, continued, though the
                        // other cameras lose it (hidden, merged). Otherwise a pair no other
                        // camera confirms and one denies is refused. (Refusing more denials
                        // than confirmations lost 1.3 % more of the markers three cameras
                        // saw in the dense sweep: a camera's worker finds a marker new to
                        // its view a few frames late.)
                        let continuing = !ca.is_empty() && !cb.is_empty();
                        if !continuing && v.confirmed == 0 && v.denied > 0 {
                            cost.push(f64::INFINITY);
                            continue;
                        }
                        if v.in_view > 0 {
                            c += cfg.max_epipolar_px * (v.in_view - v.confirmed) as f64
                                / v.in_view as f64;
                        }
                    }
                    cost.push(c);
                }
            }
            let pairs: Vec<(usize, usize)> = assigner
                .solve(&cost, ia.len(), ib.len())
                .iter()
                .enumerate()
                .filter_map(|(r, c)| c.map(|c| (ia[r], ib[c])))
                .collect();
            let first_new = out.len();
            for (i, j) in pairs {
                let obs = [
                    Observation {
                        camera: a,
                        pixel: pixels[a][i],
                    },
                    Observation {
                        camera: b,
                        pixel: pixels[b][j],
                    },
                ];
                // With more cameras the point is re-triangulated once it has them all
                // (`extend`): here, where the two rays meet is enough to look for them.
                let t = match (n > 2)
                    .then(|| provisional(cams, &rays, &obs, (a, i), (b, j)))
                    .flatten()
                {
                    Some(t) => t,
                    None => match triangulate(cams, &obs) {
                        Ok(t) if t.rms_px <= cfg.max_residual_px => t,
                        _ => continue,
                    },
                };
                used[a][i] = true;
                used[b][j] = true;
                out.push(Match {
                    blobs: vec![(a, i), (b, j)],
                    point: t,
                });
            }
            // Other cameras' free blobs join these points before they can pair among
            // themselves into duplicates.
            let keep = extend(
                cams,
                pixels,
                labels,
                cfg,
                &by_x,
                &mut used,
                &mut out[first_new..],
                &mut assigner,
            );
            let mut k = 0;
            out.retain(|m| {
                k += 1;
                if k <= first_new || keep[k - 1 - first_new] {
                    return true;
                }
                for &(c, j) in &m.blobs {
                    used[c][j] = false;
                }
                false
            });
        }
    }
    for m in &mut out {
        m.blobs.sort_unstable();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Distortion, Intrinsics};
    use crate::transform::look_at;
    use nalgebra::{Isometry3, Point3};
    use stereoscope_numeric::SplitMix64;

    fn general_rig() -> Vec<Camera> {
        (0..4)
            .map(|i| {
                let a = i as f64 * 1.3;
                let w = look_at(
                    Point3::new(2.5 * a.cos(), 2.5 * a.sin(), 2.0),
                    Point3::new(0.0, 0.0, 0.3),
                    Vector3::z(),
                )
                .unwrap();
                Camera::new(
                    Intrinsics::new(700.0, 700.0, 320.0, 240.0, 640, 480).unwrap(),
                    Distortion {
                        k1: -0.05,
                        ..Default::default()
                    },
                    w.inverse(),
                )
                .unwrap()
            })
            .collect()
    }

    fn parallel_rig() -> Vec<Camera> {
        let intr = Intrinsics::new(581.0, 500.0, 159.5, 119.5, 320, 240).unwrap();
        // Looking straight down from 2.775 m; camera 1 20 cm along x and 2.5 cm higher.
        let down = |x: f64, z: f64| {
            look_at(
                Point3::new(x, 0.0, z),
                Point3::new(x, 0.0, 0.0),
                Vector3::y(),
            )
            .unwrap()
            .inverse()
        };
        vec![
            Camera::new(intr, Distortion::default(), down(0.0, 2.775)).unwrap(),
            Camera::new(intr, Distortion::default(), down(0.2, 2.8)).unwrap(),
        ]
    }

    fn scene(
        cams: &[Camera],
        points: &[Point3<f64>],
        noise: f64,
        seed: u64,
    ) -> (Vec<Vec<Point2<f64>>>, Vec<Vec<usize>>) {
        let mut rng = SplitMix64::new(seed);
        let mut pixels = Vec::new();
        let mut truth = Vec::new();
        for c in cams {
            // Shuffle the blob order per camera.
            let mut order: Vec<usize> = (0..points.len()).collect();
            for i in (1..order.len()).rev() {
                order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
            }
            let px: Vec<Point2<f64>> = order
                .iter()
                .map(|&k| {
                    let p = c.project(&points[k]).unwrap();
                    Point2::new(p.x + noise * rng.normal(), p.y + noise * rng.normal())
                })
                .collect();
            pixels.push(px);
            truth.push(order);
        }
        (pixels, truth)
    }

    fn check(cams: &[Camera], points: &[Point3<f64>], seed: u64, noise: f64, all_cams: bool) {
        let (pixels, order) = scene(cams, points, noise, seed);
        let matches = match_blobs(cams, &pixels, &CorrespondConfig::default());
        assert_eq!(matches.len(), points.len(), "seed {seed}");
        for m in &matches {
            // Every blob of a match is the same true point.
            let ids: Vec<usize> = m.blobs.iter().map(|&(c, j)| order[c][j]).collect();
            assert!(
                ids.windows(2).all(|w| w[0] == w[1]),
                "seed {seed}: mixed {ids:?}"
            );
            assert!((m.point.point_world - points[ids[0]]).norm() < 0.02);
            if all_cams {
                assert_eq!(m.blobs.len(), cams.len());
            }
        }
    }

    #[test]
    fn several_objects_in_a_general_rig() {
        let cams = general_rig();
        let mut rng = SplitMix64::new(9);
        for seed in 0..10 {
            let points: Vec<Point3<f64>> = (0..6)
                .map(|_| {
                    Point3::new(
                        rng.range(-0.6, 0.6),
                        rng.range(-0.6, 0.6),
                        rng.range(0.0, 0.8),
                    )
                })
                .collect();
            check(&cams, &points, seed, 0.2, true);
        }
    }

    #[test]
    fn several_objects_in_the_parallel_rig() {
        let cams = parallel_rig();
        // Three targets on different rows (on one image row the parallel rig is ambiguous).
        let points = [
            Point3::new(0.1, 0.3, 0.5),
            Point3::new(-0.2, -0.1, 0.2),
            Point3::new(0.3, 0.05, 1.0),
        ];
        // 0.05 px: with a 20 cm baseline at 2.7 m, 0.2 px of disparity noise is 2 cm of depth.
        check(&cams, &points, 1, 0.05, true);
    }

    #[test]
    fn claimed_blobs_pair_only_within_their_object() {
        let cams = parallel_rig();
        // Two markers on one image row in both views, at different depths: pairing them
        // crosswise fits the rows as well (two ghosts).
        let a = Point3::new(-0.05, 0.1, 0.5);
        let b = Point3::new(0.1, 0.1 * (2.775 - 0.9) / (2.775 - 0.5), 0.9);
        let px = |c: usize, p: &Point3<f64>| cams[c].project(p).unwrap();
        // The crosswise pairs are made the cheaper ones: the markers' rows 0.4 px apart in
        // camera 0, and camera 1's blobs each on the other marker's row.
        let a0 = px(0, &a);
        let mut b0 = px(0, &b);
        b0.y = a0.y + 0.4;
        let (mut a1, mut b1) = (px(1, &a), px(1, &b));
        a1.y = b0.y;
        b1.y = a0.y;
        let pixels = vec![vec![a0, b0], vec![a1, b1]];
        let cfg = CorrespondConfig::default();
        let near = |m: &[Match], p: &Point3<f64>| {
            m.iter()
                .any(|m| (m.point.point_world - p).norm() < 0.01 && m.blobs.len() == 2)
        };
        // Unlabelled, the rows alone pair them crosswise.
        let m = match_blobs(&cams, &pixels, &cfg);
        assert!(m.len() == 2 && !near(&m, &a) && !near(&m, &b), "{m:?}");
        // Claimed by the objects whose predictions project onto them: each marker's blobs
        // pair with each other, whatever the rows say.
        let labels = vec![vec![vec![1], vec![2]], vec![vec![1], vec![2]]];
        let m = match_labelled(&cams, &pixels, &labels, &cfg);
        assert_eq!(m.len(), 2);
        assert!(near(&m, &a) && near(&m, &b), "{m:?}");
        // A blob claimed by both (two images meeting) pairs with either; an unclaimed blob
        // pairs with a claimed one only when nothing better is left.
        let labels = vec![vec![vec![1, 2], vec![2]], vec![vec![1], vec![]]];
        let m = match_labelled(&cams, &pixels, &labels, &cfg);
        assert!(near(&m, &a) && near(&m, &b), "{m:?}");
        // Claimed by different objects only: never paired.
        let labels = vec![vec![vec![1]], vec![vec![2]]];
        let m = match_labelled(&cams, &[vec![a0], vec![a1]], &labels, &cfg);
        assert!(m.is_empty(), "{m:?}");
    }

    #[test]
    fn a_blob_without_a_partner_is_left_out() {
        let cams = general_rig();
        let points = [Point3::new(0.0, 0.0, 0.3), Point3::new(0.4, -0.3, 0.6)];
        let (mut pixels, _) = scene(&cams, &points, 0.1, 3);
        pixels[0].push(Point2::new(5.0, 5.0)); // a reflection only camera 0 sees
        let matches = match_blobs(&cams, &pixels, &CorrespondConfig::default());
        assert_eq!(matches.len(), 2);
        assert!(matches.iter().all(|m| !m.blobs.contains(&(0, 2))));
        let _ = Isometry3::<f64>::identity();
    }
}
