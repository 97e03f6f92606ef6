//! Which blob in one camera is which blob in another: cross-camera correspondence for several
//! objects seen by several calibrated cameras.
//!
//! Not in the thesis, which tracked one object per camera window. Here:
//!
//! 1. for each pair of cameras, the cost of pairing blob i of camera a with blob j of camera b
//!    is their symmetric epipolar distance in pixels (undistorted); pairs beyond
//!    `max_epipolar_px` are not allowed;
//! 2. a global minimum-cost assignment (`stereoscope_vision::assign`) picks the pairs — not a
//!    greedy first match, which steals blobs at crossings;
//! 3. each pair is triangulated and rejected if its reprojection residual exceeds
//!    `max_residual_px` or it lies behind a camera;
//! 4. the other cameras' blobs are assigned to the accepted points by reprojection distance
//!    (again a global assignment) and the points re-triangulated with all their views.
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
use nalgebra::{Matrix3, Point2, Vector2, Vector3};
use stereoscope_numeric::assign::Assigner;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrespondConfig {
    /// Largest symmetric epipolar distance for a pair, pixels.
    pub max_epipolar_px: f64,
    /// Largest RMS reprojection residual of an accepted point, pixels.
    pub max_residual_px: f64,
}

impl Default for CorrespondConfig {
    fn default() -> Self {
        CorrespondConfig {
            max_epipolar_px: 3.0,
            max_residual_px: 2.0,
        }
    }
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

/// Gives the other cameras' free blobs to the points they reproject onto (step 4).
#[allow(clippy::too_many_arguments)]
fn extend(
    cams: &[Camera],
    pixels: &[Vec<Point2<f64>>],
    labels: &[Vec<Claims>],
    cfg: &CorrespondConfig,
    used: &mut [Vec<bool>],
    out: &mut [Match],
    assigner: &mut Assigner,
    cost: &mut Vec<f64>,
) {
    let n = used.len();
    for c in 0..n {
        let free: Vec<usize> = (0..pixels[c].len()).filter(|&j| !used[c][j]).collect();
        let open: Vec<usize> = (0..out.len())
            .filter(|&m| !out[m].blobs.iter().any(|b| b.0 == c))
            .collect();
        if free.is_empty() || open.is_empty() {
            continue;
        }
        cost.clear();
        for &m in &open {
            let proj = cams[c].project(&out[m].point.point_world);
            let claims = match_claims(labels, &out[m]);
            for &j in &free {
                let d = proj.map_or(f64::INFINITY, |p| (p - pixels[c][j]).norm());
                let bound = cfg.max_residual_px * 2.0;
                let penalty = claim_penalty(&claims, claims_of(labels, c, j));
                cost.push(
                    if let Some(k) = penalty
                        && d <= bound
                    {
                        d + k * bound
                    } else {
                        f64::INFINITY
                    },
                );
            }
        }
        let pairs: Vec<(usize, usize)> = assigner
            .solve(cost, open.len(), free.len())
            .iter()
            .enumerate()
            .filter_map(|(r, k)| k.map(|k| (open[r], free[k])))
            .collect();
        for (m, j) in pairs {
            let mut blobs = out[m].blobs.clone();
            blobs.push((c, j));
            let obs: Vec<Observation> = blobs
                .iter()
                .map(|&(cc, jj)| Observation {
                    camera: cc,
                    pixel: pixels[cc][jj],
                })
                .collect();
            if let Ok(t) = triangulate(cams, &obs)
                && t.rms_px <= cfg.max_residual_px
            {
                used[c][j] = true;
                out[m] = Match { blobs, point: t };
            }
        }
    }
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
                    let penalty = claim_penalty(claims_of(labels, a, i), claims_of(labels, b, j));
                    cost.push(
                        if let Some(k) = penalty
                            && d <= cfg.max_epipolar_px
                        {
                            d + k * cfg.max_epipolar_px
                        } else {
                            f64::INFINITY
                        },
                    );
                }
            }
            let pairs: Vec<(usize, usize)> = assigner
                .solve(&cost, ia.len(), ib.len())
                .iter()
                .enumerate()
                .filter_map(|(r, c)| c.map(|c| (ia[r], ib[c])))
                .collect();
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
                let Ok(t) = triangulate(cams, &obs) else {
                    continue;
                };
                if t.rms_px > cfg.max_residual_px {
                    continue;
                }
                used[a][i] = true;
                used[b][j] = true;
                out.push(Match {
                    blobs: vec![(a, i), (b, j)],
                    point: t,
                });
            }
            // Other cameras' free blobs join these points before they can pair among
            // themselves into duplicates.
            extend(
                cams,
                pixels,
                labels,
                cfg,
                &mut used,
                &mut out,
                &mut assigner,
                &mut cost,
            );
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
