//! A dot-grid calibration target: bright dots on a dark board, found with the moment engine.
//!
//! The thesis calibrated with a board of white grid lines 10 cm apart (§4.1.2, Figure 4.9);
//! a grid of bright dots is the same idea in the form the system already measures best: each
//! dot's centroid (grey-level moments, Eq. 3.1, `stereoscope_vision`) is an image point with
//! sub-pixel accuracy.
//!
//! The target: `cols × rows` dots `spacing` apart, row-major from the dot at `(0, 0)`, which is
//! larger than the others (`origin_scale` times the radius) so that the grid's orientation is
//! known. Seen from the front, the rows run to the right (+x) and down (+y) from the big dot,
//! like reading a page. Give `cols ≠ rows`: a square grid's labelling then relies on the front
//! view.
//!
//! Detection: blobs by the auto threshold; the dots are the blobs of similar size; the big dot
//! is the one largest against its neighbours; the grid's four corners are the sharpest turns of
//! the dots' convex hull; the corner labelling that makes every dot land on a lattice point
//! (by homography) wins; then every dot gets its lattice point, and the homography is refitted
//! on all of them and the assignment redone once. A dot that does not fit is an error, not a
//! guess.

use crate::calibrate::homography;
use crate::camera::Camera;
use crate::error::{DotGridProblem, GeometryError};
use nalgebra::{Isometry3, Matrix3, Point2, Point3, Vector3};
use stereoscope_vision::{
    ExtractConfig, Extractor, GrayImage, GrayView, Histogram, Pixel, ThresholdMethod, Weighting,
};

/// The target's layout.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DotGrid {
    pub cols: usize,
    pub rows: usize,
    /// Centre-to-centre distance, in the target's length unit.
    pub spacing: f64,
    /// Dot radius, same unit (for rendering).
    pub dot_radius: f64,
    /// The origin dot's radius over the others'.
    pub origin_scale: f64,
}

impl DotGrid {
    pub fn new(cols: usize, rows: usize, spacing: f64) -> Result<Self, GeometryError> {
        if cols < 2 || rows < 2 {
            return Err(DotGridProblem::TooSmall { cols, rows }.into());
        }
        if !(spacing.is_finite() && spacing > 0.0) {
            return Err(DotGridProblem::Spacing { spacing }.into());
        }
        Ok(DotGrid {
            cols,
            rows,
            spacing,
            dot_radius: spacing * 0.2,
            origin_scale: 1.5,
        })
    }

    /// Target coordinates of dot `i` (row-major), z = 0.
    pub fn point(&self, i: usize) -> Point3<f64> {
        Point3::new(
            (i % self.cols) as f64 * self.spacing,
            (i / self.cols) as f64 * self.spacing,
            0.0,
        )
    }

    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Renders what `camera` sees of the target at `cam_from_target`: dots of `level` on
/// `background`, anti-aliased by `samples × samples` supersampling near the dots' edges.
pub fn render(
    camera: &Camera,
    cam_from_target: &Isometry3<f64>,
    grid: &DotGrid,
    background: f64,
    level: f64,
    samples: u32,
) -> Result<GrayImage<u8>, GeometryError> {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let mut img = GrayImage::filled(w, h, background.round().clamp(0.0, 255.0) as u8)?;
    let target_from_cam = cam_from_target.inverse();
    let origin = target_from_cam * Point3::origin();
    // Where a pixel's ray meets the target plane, in target coordinates.
    let hit = |u: f64, v: f64| -> Option<Point2<f64>> {
        let n = camera.normalised(Point2::new(u, v))?;
        let d = target_from_cam.rotation * Vector3::new(n.x, n.y, 1.0);
        if d.z.abs() < 1e-12 {
            return None;
        }
        let t = -origin.z / d.z;
        (t > 0.0).then(|| Point2::new(origin.x + t * d.x, origin.y + t * d.y))
    };
    // Signed distance outside the nearest dot, target units.
    let outside = |p: Point2<f64>| -> f64 {
        let (i, j) = ((p.x / grid.spacing).round(), (p.y / grid.spacing).round());
        let (i, j) = (
            i.clamp(0.0, grid.cols as f64 - 1.0),
            j.clamp(0.0, grid.rows as f64 - 1.0),
        );
        let r = if i == 0.0 && j == 0.0 {
            grid.dot_radius * grid.origin_scale
        } else {
            grid.dot_radius
        };
        ((p.x - i * grid.spacing).powi(2) + (p.y - j * grid.spacing).powi(2)).sqrt() - r
    };
    let n = samples.max(1);
    for y in 0..h {
        for x in 0..w {
            let (Some(c), Some(right), Some(down)) = (
                hit(x as f64, y as f64),
                hit(x as f64 + 1.0, y as f64),
                hit(x as f64, y as f64 + 1.0),
            ) else {
                continue;
            };
            let footprint = (right - c).norm().max((down - c).norm());
            let d = outside(c);
            let coverage = if d > footprint {
                continue;
            } else if d < -footprint {
                1.0
            } else {
                let mut hits = 0;
                for sj in 0..n {
                    for si in 0..n {
                        let (su, sv) = (
                            x as f64 - 0.5 + (si as f64 + 0.5) / n as f64,
                            y as f64 - 0.5 + (sj as f64 + 0.5) / n as f64,
                        );
                        if hit(su, sv).is_some_and(|p| outside(p) <= 0.0) {
                            hits += 1;
                        }
                    }
                }
                hits as f64 / (n * n) as f64
            };
            let v = background + coverage * (level - background);
            img.set(x, y, v.round().clamp(0.0, 255.0) as u8);
        }
    }
    Ok(img)
}

fn convex_hull(pts: &[Point2<f64>]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..pts.len()).collect();
    idx.sort_by(|&a, &b| {
        pts[a]
            .x
            .total_cmp(&pts[b].x)
            .then(pts[a].y.total_cmp(&pts[b].y))
    });
    let cross = |o: usize, a: usize, b: usize| (pts[a] - pts[o]).perp(&(pts[b] - pts[o]));
    let mut hull: Vec<usize> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &usize>> = if pass == 0 {
            Box::new(idx.iter())
        } else {
            Box::new(idx.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0
            {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

fn apply_h(h: &Matrix3<f64>, p: Point2<f64>) -> Point2<f64> {
    let v = h * Vector3::new(p.x, p.y, 1.0);
    Point2::new(v.x / v.z, v.y / v.z)
}

/// For a homography from lattice `(i, j)` to pixels, each dot's lattice index, if one-to-one
/// and every dot within `tol` (fraction of the local lattice step) of its point.
fn assign_lattice(
    h: &Matrix3<f64>,
    dots: &[Point2<f64>],
    grid: &DotGrid,
) -> Option<(Vec<usize>, f64)> {
    let hinv = h.try_inverse()?;
    let mut taken = vec![usize::MAX; grid.len()];
    let mut out = vec![0; dots.len()];
    let mut worst: f64 = 0.0;
    for (k, d) in dots.iter().enumerate() {
        let g = apply_h(&hinv, *d);
        let (i, j) = (g.x.round(), g.y.round());
        if i < 0.0 || j < 0.0 || i >= grid.cols as f64 || j >= grid.rows as f64 {
            return None;
        }
        let off = ((g.x - i).powi(2) + (g.y - j).powi(2)).sqrt();
        worst = worst.max(off);
        let idx = j as usize * grid.cols + i as usize;
        if taken[idx] != usize::MAX {
            return None;
        }
        taken[idx] = k;
        out[k] = idx;
    }
    (worst < 0.3).then_some((out, worst))
}

/// Finds the grid's dots in an image: `(dot index, centroid pixel)` for every dot, in index
/// order.
pub fn detect<P: Pixel>(
    img: GrayView<'_, P>,
    grid: &DotGrid,
) -> Result<Vec<(usize, Point2<f64>)>, GeometryError> {
    let hist = Histogram::of(&img);
    let threshold = hist.threshold::<P>(ThresholdMethod::Auto)?;
    let background = hist.mode()?.min(threshold.saturating_sub(1));
    let mut ex = Extractor::new(ExtractConfig {
        min_area_px: 4,
        max_blobs: 4 * grid.len() + 64,
        weighting: Weighting::Intensity { background },
        ..Default::default()
    });
    let blobs = ex.extract(img, threshold, &[])?;
    let mut areas: Vec<u64> = blobs.iter().map(|b| b.area_px()).collect();
    areas.sort_unstable();
    let median = areas.get(areas.len() / 2).copied().unwrap_or(0) as f64;
    let dots: Vec<(Point2<f64>, f64)> = blobs
        .iter()
        .filter(|b| {
            let a = b.area_px() as f64;
            a >= median / 6.0
                && a <= median * 8.0
                && !b
                    .flags
                    .contains(stereoscope_vision::BlobFlags::TOUCHES_BORDER)
        })
        .map(|b| {
            let (x, y) = b.best_centroid_px();
            (Point2::new(x, y), b.area_px() as f64)
        })
        .collect();
    if dots.len() != grid.len() {
        return Err(DotGridProblem::DotCount {
            found: dots.len(),
            cols: grid.cols,
            rows: grid.rows,
            threshold,
        }
        .into());
    }
    let pts: Vec<Point2<f64>> = dots.iter().map(|d| d.0).collect();
    // The big dot: largest area against its four nearest neighbours.
    let origin = (0..pts.len())
        .map(|i| {
            let mut near: Vec<(f64, usize)> = (0..pts.len())
                .filter(|&j| j != i)
                .map(|j| ((pts[j] - pts[i]).norm(), j))
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            let local = near.iter().take(4).map(|&(_, j)| dots[j].1).sum::<f64>()
                / near.len().clamp(1, 4) as f64;
            (dots[i].1 / local.max(1e-9), i)
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .ok_or(DotGridProblem::NoOriginDot { best_ratio: 0.0 })?;
    if origin.0 < 1.4 {
        return Err(DotGridProblem::NoOriginDot {
            best_ratio: origin.0,
        }
        .into());
    }
    let origin = origin.1;
    // Corners: the four sharpest turns of the hull.
    let hull = convex_hull(&pts);
    if hull.len() < 4 {
        return Err(DotGridProblem::NoArea.into());
    }
    let turn = |k: usize| {
        let (a, b, c) = (
            pts[hull[(k + hull.len() - 1) % hull.len()]],
            pts[hull[k]],
            pts[hull[(k + 1) % hull.len()]],
        );
        let (u, v) = ((b - a).normalize(), (c - b).normalize());
        u.perp(&v).atan2(u.dot(&v)).abs()
    };
    let mut order: Vec<usize> = (0..hull.len()).collect();
    order.sort_by(|&a, &b| turn(b).total_cmp(&turn(a)));
    let mut corner_pos: Vec<usize> = order[..4].to_vec();
    corner_pos.sort_unstable(); // hull order
    let corners: Vec<usize> = corner_pos.iter().map(|&k| hull[k]).collect();
    let start = corners
        .iter()
        .position(|&c| c == origin)
        .or_else(|| {
            // The origin dot should be a corner; take the corner nearest to it.
            corners
                .iter()
                .enumerate()
                .min_by(|a, b| {
                    (pts[*a.1] - pts[origin])
                        .norm()
                        .total_cmp(&(pts[*b.1] - pts[origin]).norm())
                })
                .map(|(i, _)| i)
        })
        .ok_or(DotGridProblem::NoCorner)?;
    let c: Vec<Point2<f64>> = (0..4).map(|k| pts[corners[(start + k) % 4]]).collect();
    let (cm, rm) = ((grid.cols - 1) as f64, (grid.rows - 1) as f64);
    let lattice = [
        [
            Point2::new(0.0, 0.0),
            Point2::new(cm, 0.0),
            Point2::new(cm, rm),
            Point2::new(0.0, rm),
        ],
        [
            Point2::new(0.0, 0.0),
            Point2::new(0.0, rm),
            Point2::new(cm, rm),
            Point2::new(cm, 0.0),
        ],
    ];
    let mut best: Option<(Vec<usize>, f64, Matrix3<f64>)> = None;
    for (option, lat) in lattice.iter().enumerate() {
        let Some(hm) = homography(lat, &c) else {
            continue;
        };
        // Square grids: keep the front view's handedness (x right, y down on screen).
        if grid.cols == grid.rows {
            let o = apply_h(&hm, Point2::new(0.0, 0.0));
            let (ex, ey) = (
                apply_h(&hm, Point2::new(1.0, 0.0)) - o,
                apply_h(&hm, Point2::new(0.0, 1.0)) - o,
            );
            if ex.perp(&ey) < 0.0 {
                continue;
            }
        }
        let _ = option;
        if let Some((labels, worst)) = assign_lattice(&hm, &pts, grid)
            && best.as_ref().is_none_or(|b| worst < b.1)
        {
            best = Some((labels, worst, hm));
        }
    }
    let (mut labels, _, _) = best.ok_or(DotGridProblem::NotAGrid)?;
    // Refit on every dot (absorbs mild lens distortion) and assign again.
    let lat_all: Vec<Point2<f64>> = labels
        .iter()
        .map(|&i| Point2::new((i % grid.cols) as f64, (i / grid.cols) as f64))
        .collect();
    if let Some(h2) = homography(&lat_all, &pts)
        && let Some((l2, _)) = assign_lattice(&h2, &pts, grid)
    {
        labels = l2;
    }
    if labels[origin] != 0 {
        return Err(DotGridProblem::OriginNotAtCorner.into());
    }
    let mut out: Vec<(usize, Point2<f64>)> = labels.into_iter().zip(pts).collect();
    out.sort_by_key(|p| p.0);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::{DistortionModel, calibrate_camera};
    use crate::camera::{Distortion, Intrinsics};
    use crate::transform::look_at;
    use stereoscope_numeric::SplitMix64;
    use stereoscope_vision::raster::add_gaussian_noise;

    fn camera() -> Camera {
        let intr = Intrinsics::new(700.0, 690.0, 322.0, 241.0, 640, 480).unwrap();
        Camera::new(
            intr,
            Distortion {
                k1: -0.12,
                k2: 0.03,
                ..Default::default()
            },
            Isometry3::identity(),
        )
        .unwrap()
    }

    fn view(grid: &DotGrid, rng: &mut SplitMix64) -> Isometry3<f64> {
        let centre = Point3::new(
            (grid.cols - 1) as f64 * grid.spacing / 2.0,
            (grid.rows - 1) as f64 * grid.spacing / 2.0,
            0.0,
        );
        let pos = centre
            + Vector3::new(
                rng.range(-0.25, 0.25),
                rng.range(-0.2, 0.2),
                -rng.range(0.9, 1.2),
            );
        let up = Vector3::new(rng.range(-0.2, 0.2), -1.0, 0.0);
        look_at(pos, centre, up).unwrap().inverse()
    }

    #[test]
    fn detects_every_dot_in_order_and_calibrates_from_them() {
        let grid = DotGrid::new(8, 6, 0.05).unwrap();
        let cam = camera();
        let mut rng = SplitMix64::new(21);
        let mut views = Vec::new();
        for k in 0..6 {
            let pose = view(&grid, &mut rng);
            let mut img = render(&cam, &pose, &grid, 15.0, 200.0, 6).unwrap();
            add_gaussian_noise(&mut img, 2.0, &mut rng);
            let found = detect(img.view(), &grid).unwrap_or_else(|e| panic!("view {k}: {e}"));
            assert_eq!(found.len(), grid.len());
            let c = Camera {
                cam_from_world: pose,
                ..cam
            };
            for &(i, px) in &found {
                let truth = c.project(&grid.point(i)).unwrap();
                assert!(
                    (px - truth).norm() < 0.3,
                    "view {k} dot {i}: {px:?} vs {truth:?}"
                );
            }
            views.push(
                found
                    .iter()
                    .map(|&(i, px)| (grid.point(i), px))
                    .collect::<Vec<_>>(),
            );
        }
        let cal = calibrate_camera(640, 480, &views, DistortionModel::Radial).unwrap();
        let fx = cal.cameras[0].intrinsics.fx;
        assert!(
            (fx - 700.0).abs() / 700.0 < 0.01,
            "fx {fx}, rms {}",
            cal.rms_px
        );
        assert!(cal.rms_px < 0.2, "rms {}", cal.rms_px);
    }

    #[test]
    fn wrong_grid_or_missing_dots_are_errors() {
        let grid = DotGrid::new(8, 6, 0.05).unwrap();
        let cam = camera();
        let mut rng = SplitMix64::new(4);
        let pose = view(&grid, &mut rng);
        let img = render(&cam, &pose, &grid, 15.0, 200.0, 4).unwrap();
        let other = DotGrid::new(7, 6, 0.05).unwrap();
        let err = detect(img.view(), &other).unwrap_err();
        assert!(
            matches!(
                err,
                GeometryError::DotGrid(DotGridProblem::DotCount {
                    found: 48,
                    cols: 7,
                    rows: 6,
                    ..
                })
            ),
            "{err:?}"
        );
        assert!(
            err.to_string()
                .contains("found 48 dots, the 7 × 6 grid has 42"),
            "{err}"
        );
        let blank = GrayImage::filled(640, 480, 15u8).unwrap();
        assert!(detect(blank.view(), &grid).is_err());
        assert!(matches!(
            DotGrid::new(1, 5, 0.1),
            Err(GeometryError::DotGrid(DotGridProblem::TooSmall {
                cols: 1,
                rows: 5
            }))
        ));
        assert!(matches!(
            DotGrid::new(3, 5, -0.1),
            Err(GeometryError::DotGrid(DotGridProblem::Spacing { .. }))
        ));
    }
}
