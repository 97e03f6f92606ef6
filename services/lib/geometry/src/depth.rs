//! Depth from a blob's area with one camera.
//!
//! Thesis: Eq. 4.15–4.27 and `cal_coeffs`: the three-parameter model
//! `AREA = a / (D² + b·D + c)` solved exactly from three samples (Eq. 4.21–4.24, here as a 3×3
//! linear system, which is the same elimination), and the two-parameter model
//! `AREA = A / (D + B)²`. Here both are also fitted by least squares to any number of samples
//! (a linear start, then Gauss–Newton on the depth residuals, which is what the user cares
//! about), and the depth for a measured area takes the root of the quadratic that lies inside
//! the calibrated range — the thesis chose by the sign of one term, and its code clamped the
//! area to `MaxArea`, hiding outliers; here an area outside the range is flagged instead.
//! A sphere of radius r on the optical axis images to an area ∝ 1/(D² − r²): the
//! three-parameter form exactly, which is why it wins (thesis Table 4.2).
//!
//! Then `x, y` follow from the centroid's ray scaled to that depth (`point_from_depth`).
//! Depth `D` is the distance along the optical axis (camera z), in the samples' unit.
//!
//! Off the axis (not in the thesis, which measured on the axis only): the tangent cone of a
//! sphere of angular radius α whose centre's ray makes an angle θ with the optical axis cuts
//! the normalised image plane in an ellipse of area π·cos α·sin²α / (cos²α − sin²θ)^{3/2};
//! with sin α = r·cos θ / D that is, to order α², the on-axis area at the same depth divided by
//! cos θ. Lens distortion scales a small area by its Jacobian's determinant. So
//! [`on_axis_area`] multiplies a measured area by cos θ / det J before the model is read — at
//! the corner of the thesis's 320 × 240 view (θ ≈ 19°) the raw area reads the depth ≈ 3 % short.

use crate::camera::Camera;
use crate::error::GeometryError;
use nalgebra::{Matrix3, Point2, Point3, Vector3};

/// A fitted area-versus-depth model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AreaModel {
    /// `AREA = a / (D + b)²`.
    TwoParameter { a: f64, b: f64 },
    /// `AREA = a / (D² + b·D + c)`.
    ThreeParameter { a: f64, b: f64, c: f64 },
}

/// A depth read from an area.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthEstimate {
    pub depth: f64,
    /// Inside the calibrated range (with a 10 % margin). Outside, the value is the model's
    /// answer but the user should not trust it: the thesis clamped such areas silently.
    pub in_range: bool,
}

/// A model fitted to samples, with how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthFit {
    pub model: AreaModel,
    /// The calibrated depth range (smallest and largest sample depth).
    pub range: (f64, f64),
    /// Model depth − sample depth, per sample.
    pub residuals: Vec<f64>,
    pub rms: f64,
}

impl AreaModel {
    /// The area the model predicts at depth `d`.
    pub fn area_at(&self, d: f64) -> f64 {
        match *self {
            AreaModel::TwoParameter { a, b } => a / ((d + b) * (d + b)),
            AreaModel::ThreeParameter { a, b, c } => a / (d * d + b * d + c),
        }
    }

    /// The depth for an area, choosing the root inside `range` (module docs).
    pub fn depth_from_area(
        &self,
        area: f64,
        range: (f64, f64),
    ) -> Result<DepthEstimate, GeometryError> {
        if !(area.is_finite() && area > 0.0) {
            return Err(GeometryError::DepthModel(format!(
                "area {area} must be a finite number above zero"
            )));
        }
        let (lo, hi) = (range.0.min(range.1), range.0.max(range.1));
        let margin = 0.1 * (hi - lo).max(f64::EPSILON);
        let inside = |d: f64| d >= lo - margin && d <= hi + margin;
        let candidates: Vec<f64> = match *self {
            AreaModel::TwoParameter { a, b } => {
                if a <= 0.0 {
                    return Err(GeometryError::DepthModel(format!(
                        "two-parameter model has a = {a} ≤ 0"
                    )));
                }
                vec![(a / area).sqrt() - b, -(a / area).sqrt() - b]
            }
            AreaModel::ThreeParameter { a, b, c } => {
                // D² + bD + (c − a/AREA) = 0
                let k = c - a / area;
                let disc = b * b - 4.0 * k;
                if disc < 0.0 {
                    return Err(GeometryError::DepthModel(format!(
                        "area {area} px has no depth under the model (discriminant {disc:.3e})"
                    )));
                }
                let s = disc.sqrt();
                vec![(-b + s) / 2.0, (-b - s) / 2.0]
            }
        };
        let mid = 0.5 * (lo + hi);
        let best = candidates
            .iter()
            .copied()
            .filter(|d| d.is_finite())
            .min_by(|x, y| {
                let key = |d: f64| (!inside(d), (d - mid).abs());
                key(*x)
                    .partial_cmp(&key(*y))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })
            .ok_or_else(|| {
                GeometryError::DepthModel(format!("area {area} px gives no finite depth"))
            })?;
        Ok(DepthEstimate {
            depth: best,
            in_range: inside(best),
        })
    }
}

fn check_samples(
    samples: &[(f64, f64)],
    needed: usize,
    what: &str,
) -> Result<(f64, f64), GeometryError> {
    if samples.len() < needed {
        return Err(GeometryError::TooFewPoints {
            what: what.into(),
            needed,
            got: samples.len(),
        });
    }
    for (i, &(area, d)) in samples.iter().enumerate() {
        if !(area.is_finite() && area > 0.0) {
            return Err(GeometryError::DepthModel(format!(
                "sample {i}: area {area} must be a finite number above zero"
            )));
        }
        if !(d.is_finite() && d > 0.0) {
            return Err(GeometryError::DepthModel(format!(
                "sample {i}: distance {d} must be a finite number above zero"
            )));
        }
    }
    let lo = samples.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
    let hi = samples
        .iter()
        .map(|s| s.1)
        .fold(f64::NEG_INFINITY, f64::max);
    let distinct = {
        let mut ds: Vec<f64> = samples.iter().map(|s| s.1).collect();
        ds.sort_by(f64::total_cmp);
        ds.dedup();
        ds.len()
    };
    if distinct < needed {
        return Err(GeometryError::DepthModel(format!(
            "{what} needs {needed} different distances, the samples have {distinct}"
        )));
    }
    Ok((lo, hi))
}

/// Eq. 4.18–4.24: the three parameters from exactly three samples `(area, depth)`.
pub fn exact_three_parameter(samples: [(f64, f64); 3]) -> Result<AreaModel, GeometryError> {
    check_samples(&samples, 3, "the exact three-parameter solve")?;
    // A_i·D_i² + A_i·D_i·b + A_i·c = a  →  [1, −A_i·D_i, −A_i]·(a, b, c) = A_i·D_i²
    let m = Matrix3::from_fn(|r, col| {
        let (a, d) = samples[r];
        [1.0, -a * d, -a][col]
    });
    let rhs = Vector3::from_fn(|r, _| samples[r].0 * samples[r].1 * samples[r].1);
    let x = m.lu().solve(&rhs).ok_or_else(|| {
        GeometryError::DepthModel("the three samples are degenerate (singular system)".into())
    })?;
    Ok(AreaModel::ThreeParameter {
        a: x[0],
        b: x[1],
        c: x[2],
    })
}

/// Depth residuals of a model over samples, or `None` if some area has no depth.
fn depth_residuals(
    model: &AreaModel,
    samples: &[(f64, f64)],
    range: (f64, f64),
) -> Option<Vec<f64>> {
    samples
        .iter()
        .map(|&(area, d)| model.depth_from_area(area, range).ok().map(|e| e.depth - d))
        .collect()
}

fn params(m: &AreaModel) -> Vec<f64> {
    match *m {
        AreaModel::TwoParameter { a, b } => vec![a, b],
        AreaModel::ThreeParameter { a, b, c } => vec![a, b, c],
    }
}

fn with_params(m: &AreaModel, p: &[f64]) -> AreaModel {
    match m {
        AreaModel::TwoParameter { .. } => AreaModel::TwoParameter { a: p[0], b: p[1] },
        AreaModel::ThreeParameter { .. } => AreaModel::ThreeParameter {
            a: p[0],
            b: p[1],
            c: p[2],
        },
    }
}

/// Levenberg–Marquardt on the depth residuals, numeric Jacobian (2–3 parameters).
fn refine(model: AreaModel, samples: &[(f64, f64)], range: (f64, f64)) -> AreaModel {
    let mut p = params(&model);
    let n = p.len();
    let ssr = |p: &[f64]| {
        depth_residuals(&with_params(&model, p), samples, range)
            .map(|r| r.iter().map(|v| v * v).sum::<f64>())
    };
    let Some(mut cost) = ssr(&p) else {
        return model;
    };
    let mut lambda = 1e-3;
    for _ in 0..100 {
        let Some(r0) = depth_residuals(&with_params(&model, &p), samples, range) else {
            break;
        };
        let mut j = nalgebra::DMatrix::<f64>::zeros(samples.len(), n);
        let mut ok = true;
        for k in 0..n {
            let h = 1e-6 * p[k].abs().max(1e-6);
            let mut q = p.clone();
            q[k] += h;
            match depth_residuals(&with_params(&model, &q), samples, range) {
                Some(r1) => {
                    for i in 0..samples.len() {
                        j[(i, k)] = (r1[i] - r0[i]) / h;
                    }
                }
                None => ok = false,
            }
        }
        if !ok {
            break;
        }
        let jt = j.transpose();
        let h = &jt * &j;
        let g = &jt * nalgebra::DVector::from_vec(r0);
        let mut improved = false;
        for _ in 0..12 {
            let mut hl = h.clone();
            for k in 0..n {
                hl[(k, k)] *= 1.0 + lambda;
            }
            let Some(step) = hl.lu().solve(&g) else { break };
            let q: Vec<f64> = p.iter().zip(step.iter()).map(|(a, s)| a - s).collect();
            if let Some(c) = ssr(&q)
                && c < cost
            {
                let rel = (cost - c) / cost.max(1e-300);
                p = q;
                cost = c;
                lambda = (lambda * 0.3).max(1e-12);
                improved = rel > 1e-12;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    with_params(&model, &p)
}

fn finish(
    model: AreaModel,
    samples: &[(f64, f64)],
    range: (f64, f64),
) -> Result<DepthFit, GeometryError> {
    let residuals = depth_residuals(&model, samples, range).ok_or_else(|| {
        GeometryError::DepthModel("the fitted model gives no depth for some sample".into())
    })?;
    let rms = (residuals.iter().map(|r| r * r).sum::<f64>() / residuals.len() as f64).sqrt();
    Ok(DepthFit {
        model,
        range,
        residuals,
        rms,
    })
}

/// Least-squares fit of `AREA = a/(D + b)²` to `(area, depth)` samples (at least 2).
pub fn fit_two_parameter(samples: &[(f64, f64)]) -> Result<DepthFit, GeometryError> {
    let range = check_samples(samples, 2, "the two-parameter fit")?;
    // 1/√AREA = D/√a + b/√a: a straight line in D.
    let n = samples.len() as f64;
    let (mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0);
    for &(area, d) in samples {
        let y = 1.0 / area.sqrt();
        sx += d;
        sy += y;
        sxx += d * d;
        sxy += d * y;
    }
    let slope = (n * sxy - sx * sy) / (n * sxx - sx * sx);
    let icept = (sy - slope * sx) / n;
    if !(slope.is_finite() && slope > 0.0) {
        return Err(GeometryError::DepthModel(format!(
            "area does not fall with distance (slope of 1/√area is {slope:.3e})"
        )));
    }
    let start = AreaModel::TwoParameter {
        a: 1.0 / (slope * slope),
        b: icept / slope,
    };
    finish(refine(start, samples, range), samples, range)
}

/// Least-squares fit of `AREA = a/(D² + b·D + c)` to `(area, depth)` samples (at least 3).
pub fn fit_three_parameter(samples: &[(f64, f64)]) -> Result<DepthFit, GeometryError> {
    let range = check_samples(samples, 3, "the three-parameter fit")?;
    // Linear start: [1, −A·D, −A]·(a, b, c) = A·D², rows scaled by 1/(A·D²) so every sample
    // counts alike.
    let mut m = nalgebra::DMatrix::<f64>::zeros(samples.len(), 3);
    let mut rhs = nalgebra::DVector::<f64>::zeros(samples.len());
    for (i, &(area, d)) in samples.iter().enumerate() {
        let w = 1.0 / (area * d * d);
        m[(i, 0)] = w;
        m[(i, 1)] = -area * d * w;
        m[(i, 2)] = -area * w;
        rhs[i] = 1.0;
    }
    let x = m.svd(true, true).solve(&rhs, 1e-12).map_err(|e| {
        GeometryError::DepthModel(format!("three-parameter least squares failed: {e}"))
    })?;
    let start = AreaModel::ThreeParameter {
        a: x[0],
        b: x[1],
        c: x[2],
    };
    finish(refine(start, samples, range), samples, range)
}

/// The area a blob of `area_px` pixels centred at `pixel` would have on the optical axis at the
/// same depth — what the area models are fitted to (module header: × cos θ / det J).
pub fn on_axis_area(
    camera: &Camera,
    pixel: Point2<f64>,
    area_px: f64,
) -> Result<f64, GeometryError> {
    let n = camera.normalised(pixel).ok_or_else(|| {
        GeometryError::Degenerate(format!("pixel {pixel:?} cannot be undistorted"))
    })?;
    let cos_theta = 1.0 / (1.0 + n.norm_squared()).sqrt();
    let det = camera.distortion.jacobian(n).determinant();
    if !(det.is_finite() && det > 0.0) {
        return Err(GeometryError::Degenerate(format!(
            "the lens distortion folds the image at pixel {pixel:?}"
        )));
    }
    Ok(area_px * cos_theta / det)
}

/// The 3D point in world coordinates for a blob centroid at `pixel` whose depth along the
/// camera's optical axis is `depth`: the centroid's ray scaled to that depth.
pub fn point_from_depth(
    camera: &Camera,
    pixel: Point2<f64>,
    depth: f64,
) -> Result<Point3<f64>, GeometryError> {
    if !(depth.is_finite() && depth > 0.0) {
        return Err(GeometryError::DepthModel(format!(
            "depth {depth} must be a finite number above zero"
        )));
    }
    let n = camera.normalised(pixel).ok_or_else(|| {
        GeometryError::Degenerate(format!("pixel {pixel:?} cannot be undistorted"))
    })?;
    let p_cam = Point3::new(n.x * depth, n.y * depth, depth);
    Ok(camera.cam_from_world.inverse() * p_cam)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Areas of a sphere of radius r on the axis: ∝ 1/(D² − r²), i.e. a=k, b=0, c=−r².
    fn sphere_samples(k: f64, r: f64, depths: &[f64]) -> Vec<(f64, f64)> {
        depths.iter().map(|&d| (k / (d * d - r * r), d)).collect()
    }

    #[test]
    fn exact_solve_recovers_three_parameters() {
        let truth = AreaModel::ThreeParameter {
            a: 5.0e5,
            b: 12.0,
            c: -300.0,
        };
        let s: Vec<(f64, f64)> = [80.0, 150.0, 260.0]
            .iter()
            .map(|&d| (truth.area_at(d), d))
            .collect();
        let m = exact_three_parameter([s[0], s[1], s[2]]).unwrap();
        let AreaModel::ThreeParameter { a, b, c } = m else {
            panic!()
        };
        assert!(
            (a - 5.0e5).abs() < 1e-3 && (b - 12.0).abs() < 1e-8 && (c + 300.0).abs() < 1e-6,
            "{m:?}"
        );
        for d in [90.0, 200.0, 250.0] {
            let e = m.depth_from_area(truth.area_at(d), (80.0, 260.0)).unwrap();
            assert!((e.depth - d).abs() < 1e-8 && e.in_range);
        }
    }

    #[test]
    fn three_parameters_fit_a_sphere_exactly_and_two_do_not() {
        let depths: Vec<f64> = (0..21).map(|i| 75.0 + 10.0 * i as f64).collect();
        let s = sphere_samples(2.0e6, 2.0, &depths);
        let three = fit_three_parameter(&s).unwrap();
        let two = fit_two_parameter(&s).unwrap();
        assert!(three.rms < 1e-6, "three {}", three.rms);
        assert!(
            two.rms > 10.0 * three.rms.max(1e-9),
            "two {} three {}",
            two.rms,
            three.rms
        );
        // Noisy areas: both still close.
        let mut rng = stereoscope_numeric::SplitMix64::new(5);
        let noisy: Vec<(f64, f64)> = s
            .iter()
            .map(|&(a, d)| (a * (1.0 + 0.005 * rng.normal()), d))
            .collect();
        let fit = fit_three_parameter(&noisy).unwrap();
        // 0.5 % area noise is 0.25 % of depth: about 0.5 at these distances.
        assert!(fit.rms < 1.0, "{}", fit.rms);
        assert_eq!(fit.residuals.len(), noisy.len());
    }

    #[test]
    fn root_inside_the_range_and_outliers_flagged() {
        let m = AreaModel::ThreeParameter {
            a: 1.0e6,
            b: 0.0,
            c: -4.0,
        };
        let e = m.depth_from_area(m.area_at(150.0), (100.0, 200.0)).unwrap();
        assert!((e.depth - 150.0).abs() < 1e-9 && e.in_range);
        // Far outside the calibrated range: answered but flagged (the thesis clamped).
        let e = m.depth_from_area(m.area_at(20.0), (100.0, 200.0)).unwrap();
        assert!(!e.in_range && (e.depth - 20.0).abs() < 1e-6);
        assert!(m.depth_from_area(0.0, (100.0, 200.0)).is_err());
        assert!(m.depth_from_area(f64::NAN, (100.0, 200.0)).is_err());
        let two = AreaModel::TwoParameter { a: 4.0e6, b: 3.0 };
        let e = two
            .depth_from_area(two.area_at(120.0), (100.0, 200.0))
            .unwrap();
        assert!((e.depth - 120.0).abs() < 1e-9);
    }

    #[test]
    fn degenerate_samples_are_named() {
        assert!(matches!(
            fit_three_parameter(&[(1.0, 2.0), (2.0, 3.0)]),
            Err(GeometryError::TooFewPoints {
                needed: 3,
                got: 2,
                ..
            })
        ));
        assert!(
            fit_two_parameter(&[(1.0, 2.0), (-2.0, 3.0)])
                .unwrap_err()
                .to_string()
                .contains("sample 1: area -2")
        );
        assert!(
            fit_two_parameter(&[(1.0, 2.0), (2.0, f64::NAN)])
                .unwrap_err()
                .to_string()
                .contains("distance NaN")
        );
        assert!(
            fit_three_parameter(&[(1.0, 2.0), (2.0, 2.0), (3.0, 2.0)])
                .unwrap_err()
                .to_string()
                .contains("different distances")
        );
        assert!(
            fit_two_parameter(&[(1.0, 2.0), (2.0, 3.0)])
                .unwrap_err()
                .to_string()
                .contains("does not fall")
        );
    }

    #[test]
    fn point_from_depth_lies_on_the_centroid_ray() {
        use crate::camera::{Distortion, Intrinsics};
        let intr = Intrinsics::new(600.0, 520.0, 160.0, 120.0, 320, 240).unwrap();
        let w = crate::transform::look_at(
            Point3::new(0.0, 0.0, 2.0),
            Point3::origin(),
            nalgebra::Vector3::y(),
        )
        .unwrap();
        let cam = Camera::new(intr, Distortion::default(), w.inverse()).unwrap();
        let truth = Point3::new(0.3, -0.2, 0.1);
        let px = cam.project(&truth).unwrap();
        let depth = (cam.cam_from_world * truth).z;
        let p = point_from_depth(&cam, px, depth).unwrap();
        assert!((p - truth).norm() < 1e-12);
    }

    /// A sphere's image area counted by casting rays through a fine sub-pixel grid (no use of
    /// the formula under test): off the axis and through a distorting lens, `on_axis_area`
    /// brings it back to the on-axis area π r² fx fy / (D² − r²) at the same depth.
    #[test]
    fn off_axis_areas_come_back_to_the_on_axis_model() {
        use crate::camera::{Distortion, Intrinsics};
        let intr = Intrinsics::new(581.4, 500.0, 160.0, 120.0, 320, 240).unwrap();
        // A pinhole, then a barrel lens (whose shrinking corners happen to cancel most of the
        // off-axis growth: both effects must be modelled).
        for (lens, dist) in [
            ("pinhole", Distortion::default()),
            (
                "barrel",
                Distortion {
                    k1: -0.12,
                    k2: 0.03,
                    ..Default::default()
                },
            ),
        ] {
            let cam = Camera::new(intr, dist, nalgebra::Isometry3::identity()).unwrap();
            let (r, depth) = (2.0, 180.0);
            let on_axis =
                std::f64::consts::PI * r * r * intr.fx * intr.fy / (depth * depth - r * r);
            let step = 0.04;
            let mut worst_raw: f64 = 0.0;
            for pixel in [
                (160.0, 120.0),
                (300.0, 120.0),
                (160.0, 225.0),
                (10.0, 12.0),
                (305.0, 228.0),
            ] {
                let pixel = Point2::new(pixel.0, pixel.1);
                let n = cam.normalised(pixel).unwrap();
                let centre = Vector3::new(n.x * depth, n.y * depth, depth);
                // Rays through a grid over the blob's neighbourhood.
                let half = 1.6 * r / depth * intr.fx;
                let mut hits = 0u64;
                let count = (2.0 * half / step) as i64;
                for j in 0..count {
                    for i in 0..count {
                        let q = Point2::new(
                            pixel.x - half + (i as f64 + 0.5) * step,
                            pixel.y - half + (j as f64 + 0.5) * step,
                        );
                        let m = cam.normalised(q).unwrap();
                        let ray = Vector3::new(m.x, m.y, 1.0).normalize();
                        let along = ray.dot(&centre);
                        if centre.norm_squared() - along * along <= r * r {
                            hits += 1;
                        }
                    }
                }
                let area = hits as f64 * step * step;
                let corrected = on_axis_area(&cam, pixel, area).unwrap();
                assert!(
                    (corrected / on_axis - 1.0).abs() < 2e-3,
                    "{lens} {pixel:?}: {corrected} px vs {on_axis} px on the axis (raw {area})"
                );
                worst_raw = worst_raw.max((area / on_axis - 1.0).abs());
            }
            // The correction matters: uncorrected, a pinhole's corner area is several per cent off.
            if lens == "pinhole" {
                assert!(worst_raw > 0.03, "{worst_raw}");
            }
        }
    }
}
