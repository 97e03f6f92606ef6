//! Anti-aliased 2D shapes, backgrounds and noise: images with known truth for tests,
//! benchmarks and examples. Not a thesis algorithm; the truth it renders is what the thesis's
//! moment equations (Eq. 3.33–3.44) are checked against.
//!
//! Geometry (`docs/conventions.md`): pixel `(x, y)` covers `[x−½, x+½] × [y−½, y+½]`. With a
//! pixel aspect ratio PAR (pixel width / pixel height), a shape is described in physical units
//! of one pixel *height*: the pixel centre `(x, y)` lies at `(PAR·x, y)`. Angles are degrees
//! counter-clockwise as seen on screen from the x axis.
//!
//! Each pixel's coverage is estimated by supersampling (`n × n` sample points); pixels whose
//! centre is far inside or outside the shape skip the supersampling.

use crate::image::{GrayImage, Pixel};
use stereoscope_numeric::SplitMix64;

/// A filled ellipse (a disc when the semi-axes are equal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ellipse {
    /// Centre in pixel coordinates.
    pub cx_px: f64,
    pub cy_px: f64,
    /// Semi-axes in units of pixel height.
    pub semi_major: f64,
    pub semi_minor: f64,
    /// Major-axis angle, degrees CCW on screen.
    pub angle_deg: f64,
}

impl Ellipse {
    pub fn disc(cx_px: f64, cy_px: f64, radius: f64) -> Self {
        Ellipse {
            cx_px,
            cy_px,
            semi_major: radius,
            semi_minor: radius,
            angle_deg: 0.0,
        }
    }

    /// Implicit value at pixel coordinates: < 1 inside.
    fn implicit(&self, x: f64, y: f64, par: f64, cos: f64, sin: f64) -> f64 {
        let dx = (x - self.cx_px) * par;
        let dy_up = -(y - self.cy_px);
        let u = dx * cos + dy_up * sin;
        let v = -dx * sin + dy_up * cos;
        (u / self.semi_major).powi(2) + (v / self.semi_minor).powi(2)
    }

    /// Area in square pixels (as counted in pixels of the image).
    pub fn area_px(&self, par: f64) -> f64 {
        std::f64::consts::PI * self.semi_major * self.semi_minor / par
    }
}

/// Paints `shape` over `img` with intensity `level` blended by coverage:
/// `pixel = max(pixel, background + coverage·(level − background))` where `background` is the
/// value the shape is drawn over. Returns nothing; pixels outside the image are skipped.
pub fn draw_ellipse<P: Pixel>(
    img: &mut GrayImage<P>,
    e: &Ellipse,
    par: f64,
    background: f64,
    level: f64,
    samples: u32,
) {
    let (cos, sin) = (
        e.angle_deg.to_radians().cos(),
        e.angle_deg.to_radians().sin(),
    );
    let r = e.semi_major.max(e.semi_minor);
    let x_lo = ((e.cx_px - r / par - 1.0).floor().max(0.0)) as u32;
    let x_hi = ((e.cx_px + r / par + 1.0)
        .ceil()
        .min(img.width() as f64 - 1.0))
    .max(0.0) as u32;
    let y_lo = ((e.cy_px - r - 1.0).floor().max(0.0)) as u32;
    let y_hi = ((e.cy_px + r + 1.0).ceil().min(img.height() as f64 - 1.0)).max(0.0) as u32;
    if e.cx_px + r / par + 1.0 < 0.0 || e.cy_px + r + 1.0 < 0.0 {
        return;
    }
    let n = samples.max(1);
    // A pixel's corners are within √(PAR²+1)/2 of its centre; in implicit units that is at
    // most that distance over the minor semi-axis.
    let reach = (par * par + 1.0).sqrt() / 2.0 / e.semi_minor;
    let (inner, outer) = ((1.0 - reach).max(0.0).powi(2), (1.0 + reach).powi(2));
    for y in y_lo..=y_hi {
        for x in x_lo..=x_hi {
            let q = e.implicit(x as f64, y as f64, par, cos, sin);
            let coverage = if q <= inner {
                1.0
            } else if q >= outer {
                continue;
            } else {
                let mut hits = 0u32;
                for j in 0..n {
                    for i in 0..n {
                        let sx = x as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                        let sy = y as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                        if e.implicit(sx, sy, par, cos, sin) <= 1.0 {
                            hits += 1;
                        }
                    }
                }
                hits as f64 / (n * n) as f64
            };
            let v = background + coverage * (level - background);
            let old = img.get(x, y).map_or(0.0, |p| p.value() as f64);
            if v > old {
                img.set(x, y, P::from_u32_saturating(v.round().max(0.0) as u32));
            }
        }
    }
}

/// Fills the image with a background `level` plus a horizontal gradient of `gradient_per_px`
/// grey levels per pixel (uneven light).
pub fn fill_background<P: Pixel>(img: &mut GrayImage<P>, level: f64, gradient_per_px: f64) {
    let w = img.width();
    for y in 0..img.height() {
        let row = img.row_mut(y);
        for (x, p) in row.iter_mut().enumerate().take(w as usize) {
            let v = level + gradient_per_px * x as f64;
            *p = P::from_u32_saturating(v.round().max(0.0) as u32);
        }
    }
}

/// Adds Gaussian noise of standard deviation `sigma` grey levels, clamped to the pixel range.
pub fn add_gaussian_noise<P: Pixel>(img: &mut GrayImage<P>, sigma: f64, rng: &mut SplitMix64) {
    if sigma <= 0.0 {
        return;
    }
    for p in img.as_mut_slice() {
        let v = p.value() as f64 + sigma * rng.normal();
        *p = P::from_u32_saturating(v.round().max(0.0) as u32);
    }
}

/// A scene of `count` non-overlapping random ellipses on a dark background, for benchmarks:
/// returns the image and the ellipses drawn.
pub fn random_scene(
    width: u32,
    height: u32,
    count: usize,
    radius_range: (f64, f64),
    noise_sigma: f64,
    seed: u64,
) -> Result<(GrayImage<u8>, Vec<Ellipse>), crate::VisionError> {
    let mut img = GrayImage::filled(width, height, 0u8)?;
    fill_background(&mut img, 20.0, 0.0);
    let mut rng = SplitMix64::new(seed);
    let mut placed: Vec<Ellipse> = Vec::with_capacity(count);
    let mut attempts = 0;
    while placed.len() < count && attempts < count * 200 {
        attempts += 1;
        let r = rng.range(radius_range.0, radius_range.1);
        let e = Ellipse {
            cx_px: rng.range(r + 2.0, width as f64 - r - 2.0),
            cy_px: rng.range(r + 2.0, height as f64 - r - 2.0),
            semi_major: r,
            semi_minor: r * rng.range(0.5, 1.0),
            angle_deg: rng.range(-90.0, 90.0),
        };
        if placed.iter().any(|o| {
            let d = ((o.cx_px - e.cx_px).powi(2) + (o.cy_px - e.cy_px).powi(2)).sqrt();
            d < o.semi_major + e.semi_major + 3.0
        }) {
            continue;
        }
        draw_ellipse(&mut img, &e, 1.0, 20.0, 220.0, 4);
        placed.push(e);
    }
    add_gaussian_noise(&mut img, noise_sigma, &mut rng);
    Ok((img, placed))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_has_unit_variance() {
        let mut rng = SplitMix64::new(42);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.02,
            "{mean} {var}"
        );
    }

    #[test]
    fn coverage_sums_to_the_ellipse_area() {
        for par in [1.0, 0.86, 1.3] {
            let mut img = GrayImage::filled(80, 80, 0u16).unwrap();
            let e = Ellipse {
                cx_px: 40.3,
                cy_px: 39.8,
                semi_major: 15.0,
                semi_minor: 6.0,
                angle_deg: 33.0,
            };
            draw_ellipse(&mut img, &e, par, 0.0, 1000.0, 16);
            let total: f64 = img.as_slice().iter().map(|&p| p as f64 / 1000.0).sum();
            assert!(
                (total - e.area_px(par)).abs() < 0.5,
                "par {par}: {total} vs {}",
                e.area_px(par)
            );
        }
    }
}
