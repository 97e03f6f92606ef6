//! Rendering a scene through a calibrated camera.
//!
//! Not a thesis algorithm: it stands in for the thesis's cameras and frame grabber (§4.1.2) so
//! that every result can be checked against truth. Each pixel near a target is supersampled
//! (`samples × samples` rays through the camera model of Eq. 2.4–2.8, distortion and non-square
//! pixels included); each ray takes the nearest surface it meets, so targets occlude each other
//! correctly; spheres are shaded by the light (Lambertian with an ambient part), flat markers by
//! the angle to the light. Then, in order: optional Gaussian defocus blur, Gaussian read noise
//! and shot noise, and quantisation to 8 or 16 bits.
//!
//! Ground truth per target is taken from the same rays before blur and noise: its visible
//! area in pixels and the centroid of its visible silhouette.

use crate::scene::{Background, Light, Scene, Shape, Target};
use nalgebra::{Isometry3, Matrix2, Point2, Point3, Vector2, Vector3};
use stereoscope_geometry::Camera;
use stereoscope_numeric::SplitMix64;
use stereoscope_vision::{GrayImage, Pixel, VisionError};

/// How to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Rays per pixel along each axis near targets (anti-aliasing).
    pub samples: u32,
    /// Defocus blur: Gaussian standard deviation in pixels (0: none).
    pub blur_sigma_px: f64,
    /// Read noise: Gaussian standard deviation in grey levels.
    pub noise_sigma: f64,
    /// Shot noise: electrons per grey level (`None`: none). The variance added is
    /// `value / gain` grey levels².
    pub shot_noise_gain: Option<f64>,
    /// Seed of the noise (mix in the frame number for a sequence).
    pub seed: u64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            samples: 4,
            blur_sigma_px: 0.0,
            noise_sigma: 0.0,
            shot_noise_gain: None,
            seed: 0,
        }
    }
}

/// What a camera saw of one target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetTruth {
    /// Any part of it in view and not hidden.
    pub visible: bool,
    /// Visible area, pixels.
    pub area_px: f64,
    /// Centroid of the visible silhouette, pixels.
    pub centroid_px: Point2<f64>,
}

/// A rendered frame with its truth (one entry per target, in scene order).
#[derive(Debug, Clone, PartialEq)]
pub struct Frame<P: Pixel> {
    pub image: GrayImage<P>,
    pub truth: Vec<TargetTruth>,
}

/// A surface a ray can hit.
#[derive(Debug, Clone, Copy)]
enum Primitive {
    Sphere {
        centre: Point3<f64>,
        radius: f64,
    },
    Disc {
        world_from_body: Isometry3<f64>,
        radius: f64,
    },
    Rectangle {
        world_from_body: Isometry3<f64>,
        half_x: f64,
        half_y: f64,
    },
}

/// A primitive before its image box is known: owner, contrast, bounding sphere.
struct Placed {
    prim: Primitive,
    owner: Option<usize>,
    contrast: f64,
    centre: Point3<f64>,
    radius: f64,
}

struct Item {
    prim: Primitive,
    /// Target index, or `None` for a distractor.
    owner: Option<usize>,
    contrast: f64,
    /// Image bounding box (inclusive), clipped.
    bbox: (u32, u32, u32, u32),
    /// Smaller than 2 px: always supersampled.
    small: bool,
}

/// Where a ray meets a primitive: distance along the ray and the shading factor.
fn intersect(
    p: &Primitive,
    o: &Point3<f64>,
    d: &Vector3<f64>,
    light: &Light,
    ambient: f64,
) -> Option<(f64, f64)> {
    match *p {
        Primitive::Sphere { centre, radius } => {
            let oc = o - centre;
            let b = oc.dot(d);
            let c = oc.norm_squared() - radius * radius;
            let disc = b * b - c;
            if disc < 0.0 {
                return None;
            }
            let t = -b - disc.sqrt();
            if t <= 0.0 {
                return None;
            }
            let n = (o + d * t - centre) / radius;
            let towards = light.towards(d);
            Some((t, ambient + (1.0 - ambient) * n.dot(&towards).max(0.0)))
        }
        Primitive::Disc {
            world_from_body,
            radius,
        } => {
            let (t, q, n) = plane_hit(&world_from_body, o, d)?;
            (q.x * q.x + q.y * q.y <= radius * radius).then(|| {
                (
                    t,
                    ambient + (1.0 - ambient) * n.dot(&light.towards(d)).abs(),
                )
            })
        }
        Primitive::Rectangle {
            world_from_body,
            half_x,
            half_y,
        } => {
            let (t, q, n) = plane_hit(&world_from_body, o, d)?;
            (q.x.abs() <= half_x && q.y.abs() <= half_y).then(|| {
                (
                    t,
                    ambient + (1.0 - ambient) * n.dot(&light.towards(d)).abs(),
                )
            })
        }
    }
}

/// A ray against the body's z = 0 plane: distance, hit point in the body frame, plane normal in
/// the world.
fn plane_hit(
    world_from_body: &Isometry3<f64>,
    o: &Point3<f64>,
    d: &Vector3<f64>,
) -> Option<(f64, Point3<f64>, Vector3<f64>)> {
    let n = world_from_body.rotation * Vector3::z();
    let denom = n.dot(d);
    if denom.abs() < 1e-12 {
        return None;
    }
    let t = (world_from_body.translation.vector - o.coords).dot(&n) / denom;
    if t <= 0.0 {
        return None;
    }
    Some((t, world_from_body.inverse() * (o + d * t), n))
}

fn items(camera: &Camera, scene: &Scene) -> Vec<Item> {
    let mut prims: Vec<Placed> = Vec::new();
    for (i, t) in scene.targets.iter().enumerate() {
        push_target(&mut prims, i, t);
    }
    for d in &scene.distractors {
        let prim = Primitive::Sphere {
            centre: d.position_world,
            radius: d.radius_m,
        };
        prims.push(Placed {
            prim,
            owner: None,
            contrast: d.contrast,
            centre: d.position_world,
            radius: d.radius_m,
        });
    }
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let f = camera.intrinsics.fx.max(camera.intrinsics.fy);
    prims
        .into_iter()
        .filter_map(
            |Placed {
                 prim,
                 owner,
                 contrast,
                 centre,
                 radius,
             }| {
                let pc = camera.cam_from_world * centre;
                let (bbox, small) = if pc.z - radius <= 1e-6 {
                    // Straddling or behind the camera plane: test the whole image if any part is in
                    // front.
                    if pc.z + radius <= 0.0 {
                        return None;
                    }
                    ((0, 0, w - 1, h - 1), false)
                } else {
                    let c = camera.project_cam(&pc)?;
                    let r_px = f * radius / (pc.z - radius);
                    // Generous: distortion can move the edge by a few pixels.
                    let r = r_px * 1.3 + 3.0;
                    let (x0, x1, y0, y1) = (c.x - r, c.x + r, c.y - r, c.y + r);
                    if x1 < 0.0 || y1 < 0.0 || x0 > (w - 1) as f64 || y0 > (h - 1) as f64 {
                        return None;
                    }
                    let bbox = (
                        x0.max(0.0) as u32,
                        y0.max(0.0) as u32,
                        x1.min((w - 1) as f64) as u32,
                        y1.min((h - 1) as f64) as u32,
                    );
                    (bbox, r_px < 2.0)
                };
                Some(Item {
                    prim,
                    owner,
                    contrast,
                    bbox,
                    small,
                })
            },
        )
        .collect()
}

fn push_target(prims: &mut Vec<Placed>, i: usize, t: &Target) {
    let owner = Some(i);
    let centre = t.world_from_body * Point3::origin();
    match &t.shape {
        Shape::Disc { radius_m } => {
            let prim = Primitive::Disc {
                world_from_body: t.world_from_body,
                radius: *radius_m,
            };
            prims.push(Placed {
                prim,
                owner,
                contrast: t.contrast,
                centre,
                radius: *radius_m,
            });
        }
        Shape::Rectangle { half_x_m, half_y_m } => {
            let prim = Primitive::Rectangle {
                world_from_body: t.world_from_body,
                half_x: *half_x_m,
                half_y: *half_y_m,
            };
            let radius = (half_x_m * half_x_m + half_y_m * half_y_m).sqrt();
            prims.push(Placed {
                prim,
                owner,
                contrast: t.contrast,
                centre,
                radius,
            });
        }
        Shape::Dots { dots } => {
            for (offset, r) in dots {
                let world_from_dot = t.world_from_body * nalgebra::Translation3::from(*offset);
                let c = world_from_dot * Point3::origin();
                prims.push(Placed {
                    prim: Primitive::Disc {
                        world_from_body: world_from_dot,
                        radius: *r,
                    },
                    owner,
                    contrast: t.contrast,
                    centre: c,
                    radius: *r,
                });
            }
        }
        _ => {
            for (offset, r) in t.shape.spheres() {
                let c = t.world_from_body * Point3::from(offset);
                prims.push(Placed {
                    prim: Primitive::Sphere {
                        centre: c,
                        radius: r,
                    },
                    owner,
                    contrast: t.contrast,
                    centre: c,
                    radius: r,
                });
            }
        }
    }
}

/// Casts rays for one camera: the nearest item a ray through an image point meets.
struct Tracer<'a> {
    camera: &'a Camera,
    items: &'a [Item],
    world_from_cam: Isometry3<f64>,
    origin: Point3<f64>,
    light: Light,
    ambient: f64,
}

impl Tracer<'_> {
    /// The ray direction through `(u, v)`, undistorting exactly at `anchor` (a pixel centre
    /// with its normalised point and the inverse distortion Jacobian there) and linearly from
    /// it: within a pixel the second-order error is far below 1e-4 px.
    fn direction(
        &self,
        u: f64,
        v: f64,
        anchor: &(Point2<f64>, Vector2<f64>, Matrix2<f64>),
    ) -> Vector3<f64> {
        let intr = &self.camera.intrinsics;
        let dd = Vector2::new((u - anchor.0.x) / intr.fx, (v - anchor.0.y) / intr.fy);
        let n = anchor.1 + anchor.2 * dd;
        (self.world_from_cam.rotation * Vector3::new(n.x, n.y, 1.0)).normalize()
    }

    fn anchor(&self, x: f64, y: f64) -> Option<(Point2<f64>, Vector2<f64>, Matrix2<f64>)> {
        let p = Point2::new(x, y);
        let n = self.camera.normalised(p)?;
        let jinv = self.camera.distortion.jacobian(n).try_inverse()?;
        Some((p, n, jinv))
    }

    /// Index of the nearest item hit (among `candidates`) and its shading.
    fn trace(&self, d: &Vector3<f64>, candidates: &[usize]) -> Option<(usize, f64)> {
        let mut best: Option<(f64, usize, f64)> = None;
        for &i in candidates {
            if let Some((t, shade)) = intersect(
                &self.items[i].prim,
                &self.origin,
                d,
                &self.light,
                self.ambient,
            ) && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, i, shade));
            }
        }
        best.map(|(_, i, s)| (i, s))
    }
}

/// Renders the scene as radiance (grey levels, floating point) with the truth.
///
/// Each pixel inside some item's box traces its centre and its four corners (corners shared
/// with the neighbours); when all five meet the same item (or none), the pixel is uniform and
/// takes the centre's value; otherwise — an edge — it is supersampled `samples × samples`.
/// Items smaller than 2 px are always supersampled, so they cannot slip between corners.
fn radiance(camera: &Camera, scene: &Scene, samples: u32) -> (Vec<f64>, Vec<TargetTruth>) {
    let (w, h) = (
        camera.intrinsics.width as usize,
        camera.intrinsics.height as usize,
    );
    let bg = |x: f64, y: f64| {
        scene.background.level
            + scene.background.gradient_per_px.0 * x
            + scene.background.gradient_per_px.1 * y
    };
    let mut img = vec![0.0; w * h];
    for (y, row) in img.chunks_exact_mut(w.max(1)).enumerate() {
        for (x, v) in row.iter_mut().enumerate() {
            *v = bg(x as f64, y as f64);
        }
    }
    let items = items(camera, scene);
    let n = samples.max(1);
    let inv = 1.0 / (n * n) as f64;
    let world_from_cam = camera.cam_from_world.inverse();
    let tracer = Tracer {
        camera,
        items: &items,
        world_from_cam,
        origin: world_from_cam * Point3::origin(),
        light: scene.light,
        ambient: scene.ambient,
    };
    // Truth accumulators: covered area, Σx, Σy (area-weighted).
    let mut acc = vec![(0.0f64, 0.0f64, 0.0f64); scene.targets.len()];
    let add_truth = |it: &Item, weight: f64, x: f64, y: f64, acc: &mut Vec<(f64, f64, f64)>| {
        if let Some(o) = it.owner {
            acc[o].0 += weight;
            acc[o].1 += weight * x;
            acc[o].2 += weight * y;
        }
    };
    const NONE: usize = usize::MAX;
    // Corner results for the rows above and below the current pixel row.
    let mut top = vec![NONE; w + 1];
    let mut bottom = vec![NONE; w + 1];
    let mut cand: Vec<usize> = Vec::with_capacity(items.len());
    for y in 0..h {
        // Items whose box meets this row (expanded by a pixel for the corners).
        let row_items: Vec<usize> = (0..items.len())
            .filter(|&i| {
                let b = items[i].bbox;
                (y as u32 + 1) >= b.1 && (y as u32) <= b.3 + 1
            })
            .collect();
        if row_items.is_empty() {
            continue;
        }
        let (xmin, xmax) = row_items.iter().fold((usize::MAX, 0usize), |(lo, hi), &i| {
            let b = items[i].bbox;
            (
                lo.min(b.0.saturating_sub(1) as usize),
                hi.max((b.2 as usize + 1).min(w - 1)),
            )
        });
        // Corners at v = y ± ½, u = x − ½ for x in xmin..=xmax+1.
        for (row, v) in [(&mut top, y as f64 - 0.5), (&mut bottom, y as f64 + 0.5)] {
            for cx in xmin..=xmax + 1 {
                let u = cx as f64 - 0.5;
                cand.clear();
                cand.extend(row_items.iter().copied().filter(|&i| {
                    let b = items[i].bbox;
                    u >= b.0 as f64 - 1.0
                        && u <= b.2 as f64 + 1.0
                        && v >= b.1 as f64 - 1.0
                        && v <= b.3 as f64 + 1.0
                }));
                row[cx] = match tracer.anchor(u, v) {
                    Some(a) if !cand.is_empty() => tracer
                        .trace(&tracer.direction(u, v, &a), &cand)
                        .map_or(NONE, |r| r.0),
                    _ => NONE,
                };
            }
        }
        for x in xmin..=xmax {
            cand.clear();
            cand.extend(row_items.iter().copied().filter(|&i| {
                let b = items[i].bbox;
                (x as u32) >= b.0 && (x as u32) <= b.2 && (y as u32) >= b.1 && (y as u32) <= b.3
            }));
            if cand.is_empty() {
                continue;
            }
            let (fx, fy) = (x as f64, y as f64);
            let Some(anchor) = tracer.anchor(fx, fy) else {
                continue;
            };
            let centre = tracer.trace(&tracer.direction(fx, fy, &anchor), &cand);
            let c_id = centre.map_or(NONE, |r| r.0);
            let corners = [top[x], top[x + 1], bottom[x], bottom[x + 1]];
            let forced = cand.iter().any(|&i| items[i].small);
            if !forced && corners.iter().all(|&k| k == c_id) {
                if let Some((i, shade)) = centre {
                    let it = &items[i];
                    img[y * w + x] = bg(fx, fy) + it.contrast * shade;
                    add_truth(it, 1.0, fx, fy, &mut acc);
                }
                continue;
            }
            let mut sum = 0.0;
            for sj in 0..n {
                for si in 0..n {
                    let (su, sv) = (
                        fx - 0.5 + (si as f64 + 0.5) / n as f64,
                        fy - 0.5 + (sj as f64 + 0.5) / n as f64,
                    );
                    let background = bg(su, sv);
                    match tracer.trace(&tracer.direction(su, sv, &anchor), &cand) {
                        Some((i, shade)) => {
                            let it = &items[i];
                            sum += background + it.contrast * shade;
                            add_truth(it, inv, su, sv, &mut acc);
                        }
                        None => sum += background,
                    }
                }
            }
            img[y * w + x] = sum * inv;
        }
        std::mem::swap(&mut top, &mut bottom);
    }
    let truth = acc
        .iter()
        .map(|&(area, sx, sy)| TargetTruth {
            visible: area > 0.0,
            area_px: area,
            centroid_px: if area > 0.0 {
                Point2::new(sx / area, sy / area)
            } else {
                Point2::new(f64::NAN, f64::NAN)
            },
        })
        .collect();
    (img, truth)
}

/// Separable Gaussian blur in place (edges repeat the border pixel), for an image that is the
/// background plane `background` except near the targets. Blurring is linear, so the result is
/// the blur of the plane — in closed form: along each axis the plane's slope times the kernel's
/// mean of the clamped coordinate — plus the blur of the image minus the plane, which is zero
/// away from the targets: only the pixels within the kernel's reach of a target are convolved.
/// (Convolving the whole frame took half of a synthetic camera's time at 640 × 480 and
/// saturated two cores with four cameras at 30 fps in the test build.)
fn blur(img: &mut [f64], w: usize, h: usize, sigma: f64, background: &Background) {
    if !(sigma > 0.0) || w == 0 || h == 0 || img.len() != w * h {
        return;
    }
    let r = (3.0 * sigma).ceil() as usize;
    let k: Vec<f64> = (0..=2 * r)
        .map(|i| (-((i as f64 - r as f64).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / norm).collect();
    let (level, (gx, gy)) = (background.level, background.gradient_per_px);
    // The kernel's mean of the clamped coordinate along an axis of `n` pixels.
    let clamped_mean = |n: usize| -> Vec<f64> {
        (0..n)
            .map(|c| {
                k.iter()
                    .enumerate()
                    .map(|(i, kv)| kv * (c + i).saturating_sub(r).min(n - 1) as f64)
                    .sum()
            })
            .collect()
    };
    let (mean_x, mean_y) = (clamped_mean(w), clamped_mean(h));
    // What differs from the plane.
    for (y, row) in img.chunks_exact_mut(w).enumerate() {
        for (x, v) in row.iter_mut().enumerate() {
            *v -= level + gx * x as f64 + gy * y as f64;
        }
    }
    // The span `lo..=hi` of `values` that the kernel reaches from a non-zero value.
    let reach = |values: &[f64]| -> Option<(usize, usize)> {
        let a = values.iter().position(|&v| v != 0.0)?;
        let b = values.iter().rposition(|&v| v != 0.0)?;
        Some((a.saturating_sub(r), (b + r).min(values.len() - 1)))
    };
    // Rows, each only where the kernel reaches a non-zero value (the row padded by repeating
    // its end values); `rows[y]` is where row y's result is kept in `tmp` (a frame-sized buffer
    // per frame cost page faults), and its span.
    let mut line = vec![0.0; w + 2 * r];
    let mut tmp: Vec<f64> = Vec::new();
    let mut rows: Vec<Option<(usize, usize, usize)>> = vec![None; h];
    for (y, kept) in rows.iter_mut().enumerate() {
        let row = &mut img[y * w..(y + 1) * w];
        let Some((lo, hi)) = reach(row) else {
            continue;
        };
        line[..r].fill(row[0]);
        line[r..r + w].copy_from_slice(row);
        line[r + w..].fill(row[w - 1]);
        let at = tmp.len();
        tmp.extend((lo..=hi).map(|c| {
            k.iter()
                .zip(&line[c..c + 2 * r + 1])
                .map(|(a, b)| a * b)
                .sum::<f64>()
        }));
        row.fill(0.0);
        *kept = Some((at, lo, hi));
    }
    // Columns, a row at a time (a column's pixels are a row apart in memory): output row `y`
    // is the kernel-weighted sum of rows y − r ..= y + r (clamped), each over its span.
    for y in 0..h {
        let source = |j: usize| (y + j).saturating_sub(r).min(h - 1);
        for (j, kj) in k.iter().enumerate() {
            if let Some((at, lo, hi)) = rows[source(j)] {
                let out = &mut img[y * w + lo..=y * w + hi];
                for (o, t) in out.iter_mut().zip(&tmp[at..=at + hi - lo]) {
                    *o += kj * t;
                }
            }
        }
    }
    // Plus the blurred plane.
    for (y, row) in img.chunks_exact_mut(w).enumerate() {
        let plane_y = level + gy * mean_y[y];
        for (v, mx) in row.iter_mut().zip(&mean_x) {
            *v += plane_y + gx * mx;
        }
    }
}

/// Standard normal deviates by inverse transform through a table of 4096 quantiles with linear
/// interpolation between them (one 64-bit draw per deviate): Box–Muller's logarithm and
/// trigonometry cost more than the rest of the rendering. Tails are cut at ±3.7σ; the table is
/// rescaled so the variance is exactly 1.
struct FastNormal {
    table: Vec<f64>,
}

impl FastNormal {
    fn get() -> &'static FastNormal {
        static TABLE: std::sync::OnceLock<FastNormal> = std::sync::OnceLock::new();
        TABLE.get_or_init(|| {
            // Φ(x) through erf (Abramowitz & Stegun 7.1.26 is too coarse in the tails; use the
            // complementary series below and Newton steps on it).
            fn phi(x: f64) -> f64 {
                0.5 * erfc(-x / std::f64::consts::SQRT_2)
            }
            fn erfc(x: f64) -> f64 {
                // Numerical Recipes' erfc (Chebyshev), relative error < 1.2e-7.
                let z = x.abs();
                let t = 1.0 / (1.0 + 0.5 * z);
                // Horner's rule from the highest coefficient down (as a loop: rustfmt took
                // 30 s over the nested form).
                const C: [f64; 9] = [
                    1.00002368,
                    0.37409196,
                    0.09678418,
                    -0.18628806,
                    0.27886807,
                    -1.13520398,
                    1.48851587,
                    -0.82215223,
                    0.17087277,
                ];
                let poly = C.iter().rev().skip(1).fold(C[8], |acc, &c| c + t * acc);
                let r = t * (-z * z - 1.26551223 + t * poly).exp();
                if x >= 0.0 { r } else { 2.0 - r }
            }
            let n = 4097usize;
            let mut table = Vec::with_capacity(n);
            for i in 0..n {
                let p = (i as f64 + 0.5) / (n as f64 + 1.0);
                let mut x: f64 = 0.0;
                for _ in 0..60 {
                    let density = (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt();
                    let step = (phi(x) - p) / density.max(1e-300);
                    x -= step.clamp(-1.0, 1.0);
                    if step.abs() < 1e-12 {
                        break;
                    }
                }
                table.push(x);
            }
            // Variance of the interpolated distribution: mean over cells of the variance of a
            // uniform between neighbours.
            let cells = n - 1;
            let var: f64 = (0..cells)
                .map(|i| {
                    let (a, b) = (table[i], table[i + 1]);
                    (a * a + a * b + b * b) / 3.0
                })
                .sum::<f64>()
                / cells as f64;
            let s = 1.0 / var.sqrt();
            FastNormal {
                table: table.into_iter().map(|v| v * s).collect(),
            }
        })
    }

    #[inline]
    fn sample(&self, rng: &mut SplitMix64) -> f64 {
        let bits = rng.next_u64();
        let i = (bits >> 52) as usize; // 0..4096
        let frac = (bits & ((1u64 << 52) - 1)) as f64 / (1u64 << 52) as f64;
        let (a, b) = (self.table[i], self.table[i + 1]);
        a + (b - a) * frac
    }
}

fn finish<P: Pixel>(
    camera: &Camera,
    mut img: Vec<f64>,
    background: &Background,
    opts: &RenderOptions,
    max: u32,
) -> Result<GrayImage<P>, VisionError> {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    blur(
        &mut img,
        w as usize,
        h as usize,
        opts.blur_sigma_px,
        background,
    );
    let mut rng = SplitMix64::new(opts.seed ^ 0x5DEE_CE66_D1CE_4E5B);
    let mut out = GrayImage::filled(w, h, P::default())?;
    let normal = FastNormal::get();
    let read_var = opts.noise_sigma * opts.noise_sigma;
    let gain = opts.shot_noise_gain.filter(|g| *g > 0.0);
    let read_sd = read_var.sqrt();
    let top = max as f64;
    for (d, v) in out.as_mut_slice().iter_mut().zip(img) {
        let sd = match gain {
            Some(g) => (read_var + v.max(0.0) / g).sqrt(),
            None => read_sd,
        };
        let noisy = if sd > 0.0 {
            v + sd * normal.sample(&mut rng)
        } else {
            v
        };
        // Round half up by truncation (no libm call): values are clamped to [0, max] first.
        *d = P::from_u32_saturating((noisy.clamp(0.0, top) + 0.5) as u32);
    }
    Ok(out)
}

/// Renders an 8-bit frame.
pub fn render_u8(
    camera: &Camera,
    scene: &Scene,
    opts: &RenderOptions,
) -> Result<Frame<u8>, VisionError> {
    let (img, truth) = radiance(camera, scene, opts.samples);
    Ok(Frame {
        image: finish(camera, img, &scene.background, opts, 255)?,
        truth,
    })
}

/// Renders a 16-bit frame with the scene's grey levels multiplied by `scale` (e.g. 256 for a
/// Y16 camera with the same exposure) and clamped at 65535.
pub fn render_u16(
    camera: &Camera,
    scene: &Scene,
    opts: &RenderOptions,
    scale: f64,
) -> Result<Frame<u16>, VisionError> {
    let (img, truth) = radiance(camera, scene, opts.samples);
    let img: Vec<f64> = img.into_iter().map(|v| v * scale).collect();
    let opts16 = RenderOptions {
        noise_sigma: opts.noise_sigma * scale,
        ..*opts
    };
    Ok(Frame {
        image: finish(camera, img, &scene.background, &opts16, 65535)?,
        truth,
    })
}

#[cfg(test)]
mod blur_tests {
    use super::*;

    /// The blur by definition: every output pixel the kernel-weighted sum over its 2D
    /// neighbourhood, coordinates clamped to the frame.
    fn blur_by_definition(img: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
        let r = (3.0 * sigma).ceil() as isize;
        let g = |d: isize| (-((d * d) as f64) / (2.0 * sigma * sigma)).exp();
        let norm: f64 = (-r..=r).map(g).sum();
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut out = vec![0.0; w * h];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut s = 0.0;
                for dy in -r..=r {
                    for dx in -r..=r {
                        s += g(dx) * g(dy) * img[clamp(y + dy, h) * w + clamp(x + dx, w)];
                    }
                }
                out[y as usize * w + x as usize] = s / (norm * norm);
            }
        }
        out
    }

    /// Targets in the middle, on every border and in a corner, on a sloping background:
    /// the blur computed near the targets only equals the blur of the whole frame.
    #[test]
    fn blurring_near_the_targets_only_is_the_whole_frames_blur() {
        let (w, h) = (61, 47);
        for (gradient, sigma) in [((0.0, 0.0), 0.6), ((0.3, -0.2), 1.3), ((-0.05, 0.4), 2.0)] {
            let background = Background {
                level: 20.0,
                gradient_per_px: gradient,
            };
            let mut img: Vec<f64> = (0..w * h)
                .map(|i| 20.0 + gradient.0 * (i % w) as f64 + gradient.1 * (i / w) as f64)
                .collect();
            let mut rng = SplitMix64::new(7);
            for (x0, y0, bw, bh) in [(20, 15, 6, 5), (0, 30, 3, 4), (58, 0, 3, 3), (40, 44, 5, 3)] {
                for y in y0..y0 + bh {
                    for x in x0..x0 + bw {
                        img[y * w + x] += rng.range(50.0, 150.0);
                    }
                }
            }
            let expected = blur_by_definition(&img, w, h, sigma);
            blur(&mut img, w, h, sigma, &background);
            for (i, (a, b)) in img.iter().zip(&expected).enumerate() {
                assert!(
                    (a - b).abs() < 1e-9,
                    "pixel ({}, {}) with gradient {gradient:?}, sigma {sigma}: {a} vs {b}",
                    i % w,
                    i / w
                );
            }
        }
    }
}
