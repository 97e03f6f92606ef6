//! A wand calibration's camera pairs (steps 2 and 3 of `wand`'s method): each pair's
//! relative pose from the essential matrix of the frames both cameras saw, refused when a
//! homography explains them as well (the wand kept in one plane), and for a one-marker wand
//! the scale that makes a new pair agree with the cameras placed already. Not a thesis
//! equation (module docs in `wand`).

use super::*;

fn hom(v: &Vector2<f64>) -> Vector3<f64> {
    Vector3::new(v.x, v.y, 1.0)
}

/// The eight-point essential matrix for `x2ᵀ E x1 = 0`, rank 2 with equal singular values.
fn essential_8pt(pairs: &[(Vector2<f64>, Vector2<f64>)]) -> Option<Matrix3<f64>> {
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for (a, b) in pairs {
        let row = SMatrix::<f64, 1, 9>::from_row_slice(&[
            b.x * a.x,
            b.x * a.y,
            b.x,
            b.y * a.x,
            b.y * a.y,
            b.y,
            a.x,
            a.y,
            1.0,
        ]);
        ata += row.transpose() * row;
    }
    let eig = ata.symmetric_eigen();
    let k = crate::index_of_min(eig.eigenvalues.iter().copied());
    let e = eig.eigenvectors.column(k);
    let m = Matrix3::from_row_slice(e.as_slice());
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = (svd.singular_values[0] + svd.singular_values[1]) / 2.0;
    Some(u * Matrix3::from_diagonal(&Vector3::new(s, s, 0.0)) * vt)
}

/// Sampson distance of a correspondence to `E`, in normalised units.
fn sampson(e: &Matrix3<f64>, a: &Vector2<f64>, b: &Vector2<f64>) -> f64 {
    let (x1, x2) = (hom(a), hom(b));
    let ex1 = e * x1;
    let etx2 = e.transpose() * x2;
    let num = x2.dot(&ex1);
    let den = ex1.x * ex1.x + ex1.y * ex1.y + etx2.x * etx2.x + etx2.y * etx2.y;
    if den <= 0.0 {
        return f64::INFINITY;
    }
    (num * num / den).sqrt()
}

/// Midpoint triangulation of normalised rays from camera 1 (at the origin) and camera 2
/// (`cam2_from_cam1`), in camera 1's frame; `None` for parallel rays.
fn triangulate_pair(
    cam2_from_cam1: &Isometry3<f64>,
    a: &Vector2<f64>,
    b: &Vector2<f64>,
) -> Option<Point3<f64>> {
    let c1_from_c2 = cam2_from_cam1.inverse();
    let d1 = hom(a).normalize();
    let o2 = c1_from_c2.translation.vector;
    let d2 = (c1_from_c2.rotation * hom(b)).normalize();
    // Closest points of o1 + s d1 and o2 + u d2.
    let w = -o2;
    let (aa, bb, cc) = (d1.dot(&d1), d1.dot(&d2), d2.dot(&d2));
    let (dd, ee) = (d1.dot(&w), d2.dot(&w));
    let den = aa * cc - bb * bb;
    if den.abs() < 1e-12 {
        return None;
    }
    let s = (bb * ee - cc * dd) / den;
    let u = (aa * ee - bb * dd) / den;
    Some(Point3::from((d1 * s + o2 + d2 * u) / 2.0))
}

/// The pose `cam2_from_cam1` (unit translation) of `E` that puts the most of `pairs` in front
/// of both cameras.
fn decompose(e: &Matrix3<f64>, pairs: &[(Vector2<f64>, Vector2<f64>)]) -> Option<Isometry3<f64>> {
    let svd = e.svd(true, true);
    let (mut u, mut vt) = (svd.u?, svd.v_t?);
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let t = u.column(2).into_owned();
    let mut best: Option<(usize, Isometry3<f64>)> = None;
    for r in [u * w * vt, u * w.transpose() * vt] {
        let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        for sign in [1.0, -1.0] {
            let pose = Isometry3::from_parts(Translation3::from(t * sign), rot);
            let front = pairs
                .iter()
                .filter_map(|(a, b)| triangulate_pair(&pose, a, b))
                .filter(|p| p.z > 0.0 && (pose * p).z > 0.0)
                .count();
            if best.as_ref().is_none_or(|b| front > b.0) {
                best = Some((front, pose));
            }
        }
    }
    best.map(|b| b.1)
}

/// One frame's wand images in two cameras (normalised).
type ViewPair<'a> = (&'a [Vector2<f64>], &'a [Vector2<f64>]);

/// A camera's end markers' pixels, with the camera's index.
pub(super) type Ends = (usize, (Point2<f64>, Point2<f64>));

/// What a camera pair's frames gave.
pub(super) enum Pair {
    Posed(PairPose),
    /// A homography explains the frames as well as the essential matrix: the wand's samples
    /// lie in one plane (or the cameras are too close together for depth), so the pose is not
    /// determined.
    Planar,
}

/// Whether one homography carries the first view's wand markers onto the second's within
/// twice `inlier` for nine in ten of them (a least-squares fit: markers in one plane fit it at
/// the noise, markers with depth do not). The fit starts from the views' centres; each frame's
/// end markers are then paired by the fit and it is made again from them, twice.
fn planar(views: &[ViewPair], inlier: f64) -> bool {
    let transfer = |h: &Matrix3<f64>, p: &Vector2<f64>| {
        let q = h * hom(p);
        (q.z.abs() > 1e-12).then(|| Vector2::new(q.x / q.z, q.y / q.z))
    };
    let fit = |pairs: &[(Vector2<f64>, Vector2<f64>)]| {
        let a: Vec<Point2<f64>> = pairs.iter().map(|p| Point2::from(p.0)).collect();
        let b: Vec<Point2<f64>> = pairs.iter().map(|p| Point2::from(p.1)).collect();
        crate::calibrate::homography(&a, &b)
    };
    let centres: Vec<_> = views.iter().map(|(a, b)| (centre(a), centre(b))).collect();
    let Some(mut h) = fit(&centres) else {
        return false;
    };
    let mut pairs = centres;
    for _ in 0..2 {
        pairs = Vec::with_capacity(2 * views.len());
        for (va, vb) in views {
            if va.len() < 2 || vb.len() < 2 {
                pairs.push((centre(va), centre(vb)));
                continue;
            }
            let ((a0, a1), (b0, b1)) = (ends(va), ends(vb));
            let off = |p: &Vector2<f64>, q: &Vector2<f64>| {
                transfer(&h, p).map_or(f64::INFINITY, |t| (t - q).norm())
            };
            if off(&a0, &b0) + off(&a1, &b1) <= off(&a0, &b1) + off(&a1, &b0) {
                pairs.extend([(a0, b0), (a1, b1)]);
            } else {
                pairs.extend([(a0, b1), (a1, b0)]);
            }
        }
        match fit(&pairs) {
            Some(next) => h = next,
            None => return false,
        }
    }
    let fits = pairs
        .iter()
        .filter(|(p, q)| transfer(&h, p).is_some_and(|t| (t - q).norm() <= 2.0 * inlier))
        .count();
    fits * 10 >= pairs.len() * 9
}

/// A camera pair's relative pose with its inlier frame count.
pub(super) struct PairPose {
    pub(super) inliers: usize,
    pub(super) cam2_from_cam1: Isometry3<f64>,
}

/// The wand's markers' centre in one view (the mean of its blobs: the projection of the
/// markers' centroid to first order, enough for the first estimate).
fn centre(v: &[Vector2<f64>]) -> Vector2<f64> {
    v.iter().sum::<Vector2<f64>>() / v.len() as f64
}

/// The end markers of a view: the two blobs farthest apart (the wand is straight, so its end
/// markers' images are the extreme ones).
pub(super) fn ends(v: &[Vector2<f64>]) -> (Vector2<f64>, Vector2<f64>) {
    let mut best = (0, 1, -1.0);
    for i in 0..v.len() {
        for j in i + 1..v.len() {
            let d = (v[i] - v[j]).norm_squared();
            if d > best.2 {
                best = (i, j, d);
            }
        }
    }
    (v[best.0], v[best.1])
}

pub(super) fn pair_pose(
    frames: &[Normalised],
    c1: usize,
    c2: usize,
    wand: &Wand,
    inlier: f64,
    cfg: &WandConfig,
) -> Option<Pair> {
    let shared: Vec<ViewPair> = frames
        .iter()
        .filter_map(|f| Some((f.views[c1].as_deref()?, f.views[c2].as_deref()?)))
        .collect();
    if shared.len() < 8 {
        return None;
    }
    let centres: Vec<(Vector2<f64>, Vector2<f64>)> =
        shared.iter().map(|(a, b)| (centre(a), centre(b))).collect();
    let mut rng = SplitMix64::new(cfg.seed ^ ((c1 as u64) << 32) ^ c2 as u64);
    let mut best: Option<(usize, Matrix3<f64>)> = None;
    let n = centres.len();
    for _ in 0..cfg.ransac_iterations {
        let mut sample = Vec::with_capacity(8);
        while sample.len() < 8 {
            let k = (rng.next_u64() % n as u64) as usize;
            if !sample.contains(&k) {
                sample.push(k);
            }
        }
        let pts: Vec<_> = sample.iter().map(|&k| centres[k]).collect();
        let Some(e) = essential_8pt(&pts) else {
            continue;
        };
        let count = centres
            .iter()
            .filter(|(a, b)| sampson(&e, a, b) <= inlier)
            .count();
        if best.as_ref().is_none_or(|b| count > b.0) {
            best = Some((count, e));
        }
    }
    let (_, e) = best?;
    let inliers: Vec<usize> = (0..n)
        .filter(|&k| sampson(&e, &centres[k].0, &centres[k].1) <= inlier)
        .collect();
    let pts: Vec<_> = inliers.iter().map(|&k| centres[k]).collect();
    let inlier_views: Vec<ViewPair> = inliers.iter().map(|&k| shared[k]).collect();
    let swapped: Vec<ViewPair> = inlier_views.iter().map(|(a, b)| (*b, *a)).collect();
    if planar(&inlier_views, inlier) || planar(&swapped, inlier) {
        return Some(Pair::Planar);
    }
    let e = essential_8pt(&pts)?;
    let mut pose = decompose(&e, &pts)?;
    if !wand.has_length() {
        // One marker: the translation stays a unit vector; the placement scales it.
        return Some(Pair::Posed(PairPose {
            inliers: inliers.len(),
            cam2_from_cam1: pose,
        }));
    }
    // Scale: the end markers triangulated (each view's pair of ends taken in the order that
    // fits the epipolar geometry better) should be the wand's length apart.
    let mut ratios: Vec<f64> = inliers
        .iter()
        .filter_map(|&k| {
            let (a0, a1) = ends(shared[k].0);
            let (b0, b1) = ends(shared[k].1);
            let (b0, b1) = if sampson(&e, &a0, &b0) + sampson(&e, &a1, &b1)
                <= sampson(&e, &a0, &b1) + sampson(&e, &a1, &b0)
            {
                (b0, b1)
            } else {
                (b1, b0)
            };
            let p = triangulate_pair(&pose, &a0, &b0)?;
            let q = triangulate_pair(&pose, &a1, &b1)?;
            let d = (p - q).norm();
            (d > 1e-9).then(|| wand.length_m() / d)
        })
        .collect();
    if ratios.is_empty() {
        return None;
    }
    ratios.sort_by(f64::total_cmp);
    let scale = ratios[ratios.len() / 2];
    pose.translation.vector *= scale;
    Some(Pair::Posed(PairPose {
        inliers: inliers.len(),
        cam2_from_cam1: pose,
    }))
}

/// For a one-marker wand: the length of the unit translation of `rel` (`to_from_from`, the
/// pair's relative pose) that agrees with the cameras placed already. The marker triangulated
/// from `from` and another placed camera (true relative scale) against the same marker
/// triangulated from the pair at a unit baseline, as distances from `from`; the median over
/// the frames the three cameras saw, `None` under 8 such frames.
pub(super) fn pair_scale(
    frames: &[Normalised],
    placed: &[Option<Isometry3<f64>>],
    from: usize,
    to: usize,
    rel: &Isometry3<f64>,
) -> Option<f64> {
    let from_pose = placed[from]?;
    let mut ratios = Vec::new();
    for f in frames {
        let (Some(vf), Some(vt)) = (f.views[from].as_deref(), f.views[to].as_deref()) else {
            continue;
        };
        let Some(unit) = triangulate_pair(rel, &vf[0], &vt[0]) else {
            continue;
        };
        let known = (0..placed.len())
            .filter(|&c| c != from && c != to)
            .find_map(|c| {
                let other_from_from = placed[c]? * from_pose.inverse();
                let vc = f.views[c].as_deref()?;
                triangulate_pair(&other_from_from, &vf[0], &vc[0])
            });
        let Some(known) = known else { continue };
        let d = unit.coords.norm();
        if d > 1e-12 && unit.z > 0.0 && known.z > 0.0 {
            ratios.push(known.coords.norm() / d);
        }
    }
    if ratios.len() < 8 {
        return None;
    }
    ratios.sort_by(f64::total_cmp);
    Some(ratios[ratios.len() / 2])
}
