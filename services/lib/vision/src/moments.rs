//! Binary image moments of a blob, exact, and what follows from them.
//!
//! Thesis: Eq. 3.33–3.43 / 4.1–4.13 (raw moments M00…M11 and central moments of a binary
//! region), Eq. 3.44 / 4.14b (orientation with pixel-aspect-ratio compensation), Eq. 3.1 (grey
//! level moments, here with the background subtracted), and third-order moments to tell the two
//! ends of an elongated blob apart (not in the thesis).
//!
//! Conventions (`docs/conventions.md`): pixel centres at integer coordinates, x right, y down.
//! Moments are sums over pixel centres in frame coordinates.
//!
//! Exactness: every raw sum is an integer. A run of foreground pixels `x = a..=b` on row `y`
//! adds its sums in closed form, so a blob's moments cost a few multiplications per run. For
//! frames up to 8192×8192 pixels the second-order sums fit in `u64` (≤ 8192²·8191² ≈ 4.5e15)
//! and the third-order ones in `u128`; central moments are formed from the raw sums in `i128`
//! without rounding (M00·M20 − M10² and so on) and divided once, so large frames lose nothing
//! to cancellation — the thesis's integer code truncated and its float code summed in `f32`.
//!
//! Pixel aspect ratio, PAR: the width of a pixel divided by its height, once and everywhere.
//! A pixel at column x lies at physical `X = x·PAR`, `Y = y` (units of pixel height). The
//! thesis's Eq. 3.44 scales y by PAR while its code scales x; with PAR = pixel width / pixel
//! height the code's form is the right one. See `docs/vision.md` for the derivation.

/// Raw (ordinary) binary moments of a pixel set: sums of `x^p y^q` over its pixel centres.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RawMoments {
    pub m00: u64,
    pub m10: u64,
    pub m01: u64,
    pub m20: u64,
    pub m11: u64,
    pub m02: u64,
    pub m30: u128,
    pub m21: u128,
    pub m12: u128,
    pub m03: u128,
}

/// Σ_{x=0..=k} x, as used by the run closed forms.
#[inline(always)]
fn sum1(k: u64) -> u64 {
    k * (k + 1) / 2
}

/// Σ_{x=0..=k} x².
#[inline(always)]
fn sum2(k: u64) -> u64 {
    k * (k + 1) * (2 * k + 1) / 6
}

/// `v` rounded to the nearest `f64`, as `v as f64`, but through the one-instruction `i64`
/// conversion when `v` fits (central moments of blobs of any practical size do).
#[inline(always)]
fn to_f64(v: i128) -> f64 {
    // The wide conversion kept out of line: inlined, the compiler folds both arms into the
    // (library-call) `i128` conversion.
    #[cold]
    #[inline(never)]
    fn wide(v: i128) -> f64 {
        v as f64
    }
    let narrow = v as i64;
    if narrow as i128 == v {
        narrow as f64
    } else {
        wide(v)
    }
}

/// [`to_f64`] for an unsigned sum (the weighted sums): `v as f64`, through the `i64`
/// conversion when `v` fits.
#[inline(always)]
fn unsigned_to_f64(v: u128) -> f64 {
    #[cold]
    #[inline(never)]
    fn wide(v: u128) -> f64 {
        v as f64
    }
    match i64::try_from(v) {
        Ok(narrow) => narrow as f64,
        Err(_) => wide(v),
    }
}

impl RawMoments {
    /// Adds the run of pixels `x = a..=b` on row `y` (a ≤ b) in closed form.
    ///
    /// Every per-run product fits `u64` for coordinates below 8192 (each is at most about
    /// 2^53: Σx³ is formed as Σx · (S₁(b) + S₁(a−1)) rather than S₁(b)² − S₁(a−1)²), so only the
    /// third-order accumulators are widened to `u128`.
    #[inline(always)]
    pub fn add_run(&mut self, a: u32, b: u32, y: u32) {
        let (a, b, y) = (a as u64, b as u64, y as u64);
        let n = b - a + 1;
        let s1 = (a + b) * n / 2;
        let s2 = if a == 0 {
            sum2(b)
        } else {
            sum2(b) - sum2(a - 1)
        };
        let t_lo = if a == 0 { 0 } else { sum1(a - 1) };
        // Σx³ over a..=b = S₁(b)² − S₁(a−1)² = (S₁(b) − S₁(a−1))·(S₁(b) + S₁(a−1)) = Σx·(…).
        let s3 = s1 * (sum1(b) + t_lo);
        let y2 = y * y;
        self.m00 += n;
        self.m10 += s1;
        self.m01 += n * y;
        self.m20 += s2;
        self.m11 += s1 * y;
        self.m02 += n * y2;
        self.m30 += s3 as u128;
        self.m21 += (s2 * y) as u128;
        self.m12 += (s1 * y2) as u128;
        self.m03 += (n * y2 * y) as u128;
    }

    /// Adds one pixel (for tests and references).
    pub fn add_pixel(&mut self, x: u32, y: u32) {
        self.add_run(x, x, y);
    }

    /// Merges another pixel set's moments into this one (moments are additive).
    #[inline]
    pub fn merge(&mut self, o: &RawMoments) {
        self.m00 += o.m00;
        self.m10 += o.m10;
        self.m01 += o.m01;
        self.m20 += o.m20;
        self.m11 += o.m11;
        self.m02 += o.m02;
        self.m30 += o.m30;
        self.m21 += o.m21;
        self.m12 += o.m12;
        self.m03 += o.m03;
    }

    /// Area in pixels (Eq. 3.33).
    pub fn area_px(&self) -> u64 {
        self.m00
    }

    /// Centroid (Eq. 3.36–3.37); `None` for an empty set.
    pub fn centroid_px(&self) -> Option<(f64, f64)> {
        if self.m00 == 0 {
            return None;
        }
        let n = self.m00 as f64;
        Some((self.m10 as f64 / n, self.m01 as f64 / n))
    }

    /// Central second-order moments (Eq. 3.41–3.43 / 4.11–4.13), exact up to the final division.
    pub fn central(&self) -> CentralMoments {
        if self.m00 == 0 {
            return CentralMoments::default();
        }
        let n = self.m00 as i128;
        let (m10, m01) = (self.m10 as i128, self.m01 as i128);
        let mu20 = n * self.m20 as i128 - m10 * m10;
        let mu02 = n * self.m02 as i128 - m01 * m01;
        let mu11 = n * self.m11 as i128 - m10 * m01;
        let nf = self.m00 as f64;
        CentralMoments {
            mu20: to_f64(mu20) / nf,
            mu02: to_f64(mu02) / nf,
            mu11: to_f64(mu11) / nf,
        }
    }

    /// Central third-order moments mu30, mu21, mu12, mu03 (sums over pixels), exact in `i128`
    /// up to the final division by M00².
    pub fn central_third(&self) -> [f64; 4] {
        if self.m00 == 0 {
            return [0.0; 4];
        }
        let n = self.m00 as i128;
        let (m10, m01) = (self.m10 as i128, self.m01 as i128);
        let (m20, m11, m02) = (self.m20 as i128, self.m11 as i128, self.m02 as i128);
        let (m30, m21, m12, m03) = (
            self.m30 as i128,
            self.m21 as i128,
            self.m12 as i128,
            self.m03 as i128,
        );
        let nn = n * n;
        let mu30 = nn * m30 - 3 * n * m10 * m20 + 2 * m10 * m10 * m10;
        let mu03 = nn * m03 - 3 * n * m01 * m02 + 2 * m01 * m01 * m01;
        let mu21 = nn * m21 - n * m01 * m20 - 2 * n * m10 * m11 + 2 * m10 * m10 * m01;
        let mu12 = nn * m12 - n * m10 * m02 - 2 * n * m01 * m11 + 2 * m01 * m01 * m10;
        let d = (self.m00 as f64) * (self.m00 as f64);
        [
            to_f64(mu30) / d,
            to_f64(mu21) / d,
            to_f64(mu12) / d,
            to_f64(mu03) / d,
        ]
    }
}

/// The runs of consecutive rows of one blob, summed relative to the first row `y0` so that
/// every sum stays in `u64`, then added to the blob's [`RawMoments`] once (the same Eq. 3.33–
/// 3.43 sums as [`RawMoments::add_run`], expanded binomially in `y = y0 + dy`).
///
/// Exact for runs of any length in frames up to 8192 × 8192 (`MAX_SIDE_PX`): each sum is a sum
/// of `x^p · dy^q` (p + q ≤ 3) over the block's pixels, at most the same sum over a whole
/// 8192 × 8192 frame, which is below 2^63. This is what the tracker's windows need: a window's
/// blob row is one run continuing the one above, and a run of such rows costs a few `u64`
/// multiply-adds each instead of four `u128` additions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RunBlock {
    y0: u32,
    n: u64,
    s1: u64,
    s2: u64,
    s3: u64,
    n_dy: u64,
    s1_dy: u64,
    s2_dy: u64,
    n_dy2: u64,
    s1_dy2: u64,
    n_dy3: u64,
}

impl RunBlock {
    /// An empty block whose rows are counted from `y0`.
    #[inline(always)]
    pub fn new(y0: u32) -> Self {
        RunBlock {
            y0,
            ..Default::default()
        }
    }

    /// Adds the run `x = a..=b` (a ≤ b) on row `y0 + dy`.
    #[inline(always)]
    pub fn add_run(&mut self, a: u32, b: u32, dy: u32) {
        debug_assert!(a <= b && b < crate::image::MAX_SIDE_PX);
        let (a, b, dy) = (a as u64, b as u64, dy as u64);
        let n = b - a + 1;
        let s1 = (a + b) * n / 2;
        let s2 = sum2(b) - if a == 0 { 0 } else { sum2(a - 1) };
        let t_lo = if a == 0 { 0 } else { sum1(a - 1) };
        let s3 = s1 * (sum1(b) + t_lo);
        let dy2 = dy * dy;
        self.n += n;
        self.s1 += s1;
        self.s2 += s2;
        self.s3 += s3;
        self.n_dy += n * dy;
        self.s1_dy += s1 * dy;
        self.s2_dy += s2 * dy;
        self.n_dy2 += n * dy2;
        self.s1_dy2 += s1 * dy2;
        self.n_dy3 += n * dy2 * dy;
    }

    /// Adds the block's sums to `m`: `Σ x^p (y0 + dy)^q` expanded in powers of `y0`.
    #[inline]
    pub fn add_to(&self, m: &mut RawMoments) {
        let y = self.y0 as u64;
        let y2 = y * y;
        m.m00 += self.n;
        m.m10 += self.s1;
        m.m01 += y * self.n + self.n_dy;
        m.m20 += self.s2;
        m.m11 += y * self.s1 + self.s1_dy;
        m.m02 += y2 * self.n + 2 * y * self.n_dy + self.n_dy2;
        let (yw, y2w) = (y as u128, y2 as u128);
        m.m30 += self.s3 as u128;
        m.m21 += yw * self.s2 as u128 + self.s2_dy as u128;
        m.m12 += y2w * self.s1 as u128 + 2 * yw * self.s1_dy as u128 + self.s1_dy2 as u128;
        m.m03 += y2w * yw * self.n as u128
            + 3 * y2w * self.n_dy as u128
            + 3 * yw * self.n_dy2 as u128
            + self.n_dy3 as u128;
    }
}

/// Central second-order moments: sums over pixels (not divided by the area), as OpenCV's
/// `mu20`, `mu02`, `mu11`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CentralMoments {
    pub mu20: f64,
    pub mu02: f64,
    pub mu11: f64,
}

/// The shape of a blob's second moments in physical (PAR-corrected) units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisShape {
    /// Major-axis angle, degrees, from the image x axis, counter-clockwise as seen on screen,
    /// in (−90, 90].
    pub angle_deg: f64,
    /// Eigenvalues of the physical covariance (variance along the major and minor axes),
    /// in squared units of pixel height.
    pub major_var: f64,
    pub minor_var: f64,
    /// `[cos, sin]` of `angle_deg`, from the moments without trigonometry (for the
    /// third-order direction).
    pub axis_unit: [f64; 2],
}

impl AxisShape {
    /// Minor/major axis length ratio in [0, 1]: 1 for a circle, where the angle means nothing.
    pub fn roundness(&self) -> f64 {
        if self.major_var <= 0.0 {
            return 1.0;
        }
        (self.minor_var.max(0.0) / self.major_var).sqrt()
    }
}

impl CentralMoments {
    /// Orientation and axes with pixel-aspect-ratio compensation (Eq. 3.44 / 4.14b, corrected).
    ///
    /// In physical coordinates `X = PAR·x`, `Y' = −y` (up on screen) the covariance is
    /// `PAR²·mu20`, `mu02`, `−PAR·mu11` (all divided by the pixel height²), so the major axis is
    /// `θ = ½·atan2(−2·PAR·mu11, PAR²·mu20 − mu02)`. This equals the thesis's code
    /// (`atan2(−2cMxy, PAR·cMxx − cMyy/PAR)`, multiplied through by PAR); its Eq. 3.44 puts PAR on
    /// the y terms, which is right only if PAR is taken as height/width.
    ///
    /// `par` must be finite and positive (callers validate it; see `validate_par`).
    pub fn axis_shape(&self, par: f64) -> AxisShape {
        let cxx = par * par * self.mu20;
        let cyy = self.mu02;
        let cxy = -par * self.mu11;
        let angle_rad = 0.5 * (2.0 * cxy).atan2(cxx - cyy);
        let mut angle_deg = angle_rad.to_degrees();
        if angle_deg <= -90.0 {
            angle_deg += 180.0;
        }
        let mean = 0.5 * (cxx + cyy);
        let diff = (0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy).sqrt();
        // cos 2θ = (cxx − cyy) / 2·diff, sin 2θ = 2·cxy / 2·diff; θ in (−90°, 90°] has
        // cos θ ≥ 0 and sin θ of the sign of sin 2θ (+1 at 90°).
        let axis_unit = if diff > 0.0 {
            let c2 = ((cxx - cyy) / (2.0 * diff)).clamp(-1.0, 1.0);
            let sin = ((1.0 - c2) / 2.0).sqrt();
            [
                ((1.0 + c2) / 2.0).sqrt(),
                if cxy < 0.0 { -sin } else { sin },
            ]
        } else {
            [1.0, 0.0]
        };
        AxisShape {
            angle_deg,
            major_var: mean + diff,
            minor_var: mean - diff,
            axis_unit,
        }
    }

    /// Major-axis angle in degrees, (−90, 90]; see [`CentralMoments::axis_shape`].
    pub fn orientation_deg(&self, par: f64) -> f64 {
        self.axis_shape(par).angle_deg
    }
}

/// Checks a pixel aspect ratio (pixel width / pixel height).
pub fn validate_par(par: f64) -> Result<f64, crate::VisionError> {
    if par.is_finite() && par > 0.0 {
        Ok(par)
    } else {
        Err(crate::VisionError::InvalidPixelAspectRatio { par })
    }
}

/// The direction of a blob's major axis, resolved to 0–360° with third-order moments.
///
/// Along the unit major axis `u` (physical, y up), the third central moment
/// `s = Σ (u·d)³` says which end carries the longer tail: a big ball glued to a small one has
/// its centroid near the big ball, so the small ball's side has the positive skew. The
/// returned direction points to that end. `None` when the skew is too small to trust
/// (normalised skew `s / (M00·σ³)` below `min_skewness`), e.g. for symmetric blobs.
/// `shape` is the blob's axis shape (`CentralMoments::axis_shape`, binary or weighted).
pub fn directed_angle_deg(
    raw: &RawMoments,
    shape: &AxisShape,
    par: f64,
    min_skewness: f64,
) -> Option<f64> {
    if raw.m00 < 3 {
        return None;
    }
    if shape.major_var <= 0.0 {
        return None;
    }
    let [mu30, mu21, mu12, mu03] = raw.central_third();
    // Physical axis (X right, Y up) → pixel-offset weights: X = par·dx, Y = −dy.
    let (ux, uy) = (shape.axis_unit[0] * par, -shape.axis_unit[1]);
    let skew = ux * ux * ux * mu30
        + 3.0 * ux * ux * uy * mu21
        + 3.0 * ux * uy * uy * mu12
        + uy * uy * uy * mu03;
    // Weighted shapes are scaled to the binary one (`WeightedMoments::central`), so the
    // variance per pixel is major_var / M00 either way.
    let sigma = (shape.major_var / raw.m00 as f64).sqrt();
    let normalised = skew / (raw.m00 as f64 * sigma * sigma * sigma);
    if !normalised.is_finite() || normalised.abs() < min_skewness {
        return None;
    }
    let mut deg = shape.angle_deg;
    if normalised < 0.0 {
        deg += 180.0;
    }
    // `deg` is in (−90, 270]: into [0, 360) without a floating-point remainder.
    Some(if deg < 0.0 { deg + 360.0 } else { deg })
}

/// Grey-level (intensity-weighted) moments of a blob's pixels, Eq. 3.1 with the weight
/// `f(x, y) = pixel − background`: sums of `w`, `w·x`, `w·y`, `w·x²`, `w·xy`, `w·y²`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WeightedMoments {
    pub w00: u128,
    pub w10: u128,
    pub w01: u128,
    pub w20: u128,
    pub w11: u128,
    pub w02: u128,
}

impl WeightedMoments {
    /// Adds a run's per-row partial sums: Σw, Σw·x, Σw·x² over the run, on row `y`.
    #[inline]
    pub fn add_row_sums(&mut self, sw: u64, swx: u64, swxx: u64, y: u32) {
        // Each product one 64 × 64 → 128-bit multiply: `y²` fits in 64 bits (y < 2³²).
        let (y, y2) = (y as u64, y as u64 * y as u64);
        self.w00 += sw as u128;
        self.w10 += swx as u128;
        self.w01 += sw as u128 * y as u128;
        self.w20 += swxx as u128;
        self.w11 += swx as u128 * y as u128;
        self.w02 += sw as u128 * y2 as u128;
    }

    pub fn merge(&mut self, o: &WeightedMoments) {
        self.w00 += o.w00;
        self.w10 += o.w10;
        self.w01 += o.w01;
        self.w20 += o.w20;
        self.w11 += o.w11;
        self.w02 += o.w02;
    }

    /// Intensity-weighted centroid; `None` if all weights are zero.
    pub fn centroid_px(&self) -> Option<(f64, f64)> {
        if self.w00 == 0 {
            return None;
        }
        let w = unsigned_to_f64(self.w00);
        Some((unsigned_to_f64(self.w10) / w, unsigned_to_f64(self.w01) / w))
    }

    /// Weighted central second moments, normalised to the same scale as the binary ones
    /// (divided by the mean weight, so a uniform blob gives the binary values).
    pub fn central(&self, area_px: u64) -> CentralMoments {
        if self.w00 == 0 || area_px == 0 {
            return CentralMoments::default();
        }
        let w = self.w00 as i128;
        let (w10, w01) = (self.w10 as i128, self.w01 as i128);
        let c20 = to_f64(w * self.w20 as i128 - w10 * w10);
        let c02 = to_f64(w * self.w02 as i128 - w01 * w01);
        let c11 = to_f64(w * self.w11 as i128 - w10 * w01);
        // Σw(x−x̄)² = c20 / W; scale by area / W so that uniform weights reproduce mu20.
        let w00 = unsigned_to_f64(self.w00);
        let s = area_px as f64 / (w00 * w00);
        CentralMoments {
            mu20: c20 * s,
            mu02: c02 * s,
            mu11: c11 * s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row's weighted sums are added as their definition in `u128`, for any sums and row.
    #[test]
    fn row_sums_add_as_their_definition() {
        let mut rng = stereoscope_numeric::SplitMix64::new(31);
        for i in 0..10_000u64 {
            let (sw, swx, swxx) = (rng.next_u64(), rng.next_u64() >> (i % 64), rng.next_u64());
            let y = match i {
                0 => u32::MAX,
                1 => 0,
                _ => (rng.next_u64() >> (i % 33)) as u32,
            };
            let mut w = WeightedMoments::default();
            w.add_row_sums(sw, swx, swxx, y);
            let (s, yy) = (sw as u128, y as u128);
            assert_eq!((w.w00, w.w10, w.w20), (s, swx as u128, swxx as u128));
            assert_eq!((w.w01, w.w11), (s * yy, swx as u128 * yy), "{sw} {y}");
            assert_eq!(w.w02, s * yy * yy, "{sw} {y}");
        }
    }

    /// The narrow conversions round as the wide ones, at and around the `i64` boundary too.
    #[test]
    fn conversions_round_as_the_wide_casts() {
        let mut rng = stereoscope_numeric::SplitMix64::new(23);
        let mut values: Vec<u128> = vec![0, 1, (1 << 53) + 1, i64::MAX as u128, u64::MAX as u128];
        values.extend([i64::MAX as u128 + 1, i64::MAX as u128 - 1, u128::MAX]);
        for shift in 0..128 {
            let r = ((rng.next_u64() as u128) << 64 | rng.next_u64() as u128) >> shift;
            values.extend([r, r | 1, r.saturating_add(1 << 10)]);
        }
        for v in values {
            assert_eq!(unsigned_to_f64(v).to_bits(), (v as f64).to_bits(), "{v}");
            let signed = v as i128;
            assert_eq!(
                to_f64(signed).to_bits(),
                (signed as f64).to_bits(),
                "{signed}"
            );
            let negated = signed.wrapping_neg();
            assert_eq!(
                to_f64(negated).to_bits(),
                (negated as f64).to_bits(),
                "{signed}"
            );
        }
    }

    /// A block of rows gives exactly the sums of its runs added one by one, for runs of any
    /// length, at the edges of the 8192-pixel frame too.
    #[test]
    fn run_block_equals_runs_added_one_by_one() {
        let mut rng = stereoscope_numeric::SplitMix64::new(11);
        for case in 0..300 {
            let y0 = match case {
                0 => 0,
                1 => 8191 - 63,
                _ => (rng.next_u64() % 8100) as u32,
            };
            let rows = 1 + (rng.next_u64() % 64) as u32;
            let rows = rows.min(8192 - y0);
            let mut block = RunBlock::new(y0);
            let mut one_by_one = RawMoments::default();
            for dy in 0..rows {
                // Short runs (a marker's row) in most cases, any length up to the frame's
                // width in every third.
                let longest = if case % 3 == 2 { 8192 } else { 64 };
                let len = 1 + (rng.next_u64() % longest) as u32;
                let a = match case {
                    0 => 0,
                    1 => 8192 - len,
                    _ => (rng.next_u64() % (8192 - len as u64)) as u32,
                };
                block.add_run(a, a + len - 1, dy);
                one_by_one.add_run(a, a + len - 1, y0 + dy);
            }
            let mut from_block = RawMoments::default();
            block.add_to(&mut from_block);
            assert_eq!(from_block, one_by_one, "case {case}, y0 {y0}, {rows} rows");
        }
        // The largest blocks: 8192 rows of the frame's last 64 columns, and of the whole
        // 8192-pixel width (overflow would panic in this test's build).
        for a in [8128, 0] {
            let mut block = RunBlock::new(0);
            let mut one_by_one = RawMoments::default();
            for y in 0..8192 {
                block.add_run(a, 8191, y);
                one_by_one.add_run(a, 8191, y);
            }
            let mut from_block = RawMoments::default();
            block.add_to(&mut from_block);
            assert_eq!(from_block, one_by_one, "runs from {a}");
        }
    }

    /// The axis' unit vector agrees with the cosine and sine of its angle, every quadrant and
    /// the edge cases (a circle, 90°, −0 products).
    #[test]
    fn axis_unit_is_the_angle_without_trigonometry() {
        let mut rng = stereoscope_numeric::SplitMix64::new(7);
        let mut cases: Vec<(f64, f64, f64)> = (0..2000)
            .map(|_| {
                let a = rng.next_u64() as f64 / u64::MAX as f64 * 100.0;
                let b = rng.next_u64() as f64 / u64::MAX as f64 * 100.0;
                let c = (rng.next_u64() as f64 / u64::MAX as f64 - 0.5) * 100.0;
                (a, b, c)
            })
            .collect();
        cases.extend([
            (5.0, 5.0, 0.0),
            (1.0, 4.0, 0.0),
            (4.0, 1.0, 0.0),
            (2.0, 2.0, 1.5),
            (2.0, 2.0, -1.5),
            (1.0, 4.0, -0.0),
        ]);
        for (mu20, mu02, mu11) in cases {
            for par in [1.0, 0.86, 1.3] {
                let c = CentralMoments { mu20, mu02, mu11 };
                let s = c.axis_shape(par);
                let t = s.angle_deg.to_radians();
                if s.major_var - s.minor_var < 1e-9 {
                    continue; // a circle: any axis
                }
                assert!(
                    (s.axis_unit[0] - t.cos()).abs() < 1e-9
                        && (s.axis_unit[1] - t.sin()).abs() < 1e-9,
                    "{mu20} {mu02} {mu11} par {par}: {:?} vs {}°",
                    s.axis_unit,
                    s.angle_deg
                );
            }
        }
    }

    fn brute(pixels: &[(u32, u32)]) -> RawMoments {
        let mut m = RawMoments::default();
        for &(x, y) in pixels {
            let (x, y) = (x as u64, y as u64);
            m.m00 += 1;
            m.m10 += x;
            m.m01 += y;
            m.m20 += x * x;
            m.m11 += x * y;
            m.m02 += y * y;
            m.m30 += (x * x * x) as u128;
            m.m21 += (x * x * y) as u128;
            m.m12 += (x * y * y) as u128;
            m.m03 += (y * y * y) as u128;
        }
        m
    }

    #[test]
    fn run_closed_form_matches_pixel_sums() {
        for (a, b, y) in [
            (0, 0, 0),
            (0, 7, 3),
            (5, 5, 9),
            (17, 400, 1000),
            (8000, 8191, 8191),
        ] {
            let mut run = RawMoments::default();
            run.add_run(a, b, y);
            let pixels: Vec<_> = (a..=b).map(|x| (x, y)).collect();
            assert_eq!(run, brute(&pixels), "run {a}..={b} on row {y}");
        }
    }

    #[test]
    fn rectangle_moments_match_closed_form() {
        // A w×h rectangle at (x0, y0): mu20 = h·w(w²−1)/12, mu02 = w·h(h²−1)/12, mu11 = 0.
        let (x0, y0, w, h) = (1234u32, 987u32, 31u32, 12u32);
        let mut m = RawMoments::default();
        for y in y0..y0 + h {
            m.add_run(x0, x0 + w - 1, y);
        }
        let c = m.central();
        let (wf, hf) = (w as f64, h as f64);
        assert_eq!(m.area_px(), (w * h) as u64);
        let (cx, cy) = m.centroid_px().unwrap();
        assert!((cx - (x0 as f64 + (wf - 1.0) / 2.0)).abs() < 1e-12);
        assert!((cy - (y0 as f64 + (hf - 1.0) / 2.0)).abs() < 1e-12);
        assert!((c.mu20 - hf * wf * (wf * wf - 1.0) / 12.0).abs() < 1e-6);
        assert!((c.mu02 - wf * hf * (hf * hf - 1.0) / 12.0).abs() < 1e-6);
        assert!(c.mu11.abs() < 1e-6);
        // Symmetric: third central moments vanish.
        for t in m.central_third() {
            assert!(t.abs() < 1e-6, "{t}");
        }
    }

    #[test]
    fn central_moments_are_translation_invariant_and_exact_on_large_frames() {
        let mut near = RawMoments::default();
        let mut far = RawMoments::default();
        for (dy, (a, b)) in [(0u32, (3u32, 9u32)), (1, (2, 11)), (2, (4, 8))].into_iter() {
            near.add_run(a, b, dy);
            far.add_run(a + 8000, b + 8000, dy + 8100);
        }
        assert_eq!(near.central(), far.central());
        assert_eq!(near.central_third(), far.central_third());
    }

    #[test]
    fn orientation_of_a_diagonal_line() {
        // Pixels along y = −x on screen (x right, y down → rising to the right): +45° CCW.
        let mut m = RawMoments::default();
        for i in 0..20u32 {
            m.add_pixel(10 + i, 40 - i);
        }
        assert!((m.central().orientation_deg(1.0) - 45.0).abs() < 1e-9);
        let mut m = RawMoments::default();
        for i in 0..20u32 {
            m.add_pixel(10 + i, 10 + i);
        }
        assert!((m.central().orientation_deg(1.0) + 45.0).abs() < 1e-9);
        // Vertical line: +90°, never −90°.
        let mut m = RawMoments::default();
        for i in 0..20u32 {
            m.add_pixel(5, i);
        }
        assert_eq!(m.central().orientation_deg(1.0), 90.0);
    }

    #[test]
    fn par_stretches_x_before_the_angle() {
        // A line with pixel slope −1 (rising on screen) on pixels twice as wide as high is
        // physically at atan(1/2) above the x axis.
        let mut m = RawMoments::default();
        for i in 0..50u32 {
            m.add_pixel(10 + i, 80 - i);
        }
        let got = m.central().orientation_deg(2.0);
        assert!((got - 0.5f64.atan().to_degrees()).abs() < 1e-9, "{got}");
    }

    #[test]
    fn third_order_moments_find_the_heavy_end() {
        // A 9×9 square with a 3×3 tail to its right: the tail side is the direction (0°).
        let mut m = RawMoments::default();
        for y in 100..109u32 {
            m.add_run(100, 108, y);
        }
        for y in 103..106u32 {
            m.add_run(109, 120, y);
        }
        let d = directed_angle_deg(&m, &m.central().axis_shape(1.0), 1.0, 0.1).unwrap();
        assert!(d.abs() < 1e-6 || (d - 360.0).abs() < 1e-6, "{d}");
        // Mirror it: tail to the left → 180°.
        let mut m = RawMoments::default();
        for y in 100..109u32 {
            m.add_run(100, 108, y);
        }
        for y in 103..106u32 {
            m.add_run(88, 99, y);
        }
        let d = directed_angle_deg(&m, &m.central().axis_shape(1.0), 1.0, 0.1).unwrap();
        assert!((d - 180.0).abs() < 1e-6, "{d}");
        // A symmetric bar has no direction.
        let mut m = RawMoments::default();
        for y in 100..103u32 {
            m.add_run(100, 130, y);
        }
        assert_eq!(
            directed_angle_deg(&m, &m.central().axis_shape(1.0), 1.0, 0.1),
            None
        );
    }

    #[test]
    fn weighted_moments_reduce_to_binary_for_uniform_weights() {
        let mut raw = RawMoments::default();
        let mut w = WeightedMoments::default();
        for y in 10..20u32 {
            let (a, b) = (5 + y / 3, 30 + y);
            raw.add_run(a, b, y);
            let (mut sw, mut swx, mut swxx) = (0u64, 0u64, 0u64);
            for x in a..=b {
                sw += 7;
                swx += 7 * x as u64;
                swxx += 7 * (x as u64) * (x as u64);
            }
            w.add_row_sums(sw, swx, swxx, y);
        }
        let (bx, by) = raw.centroid_px().unwrap();
        let (wx, wy) = w.centroid_px().unwrap();
        assert!((bx - wx).abs() < 1e-12 && (by - wy).abs() < 1e-12);
        let (bc, wc) = (raw.central(), w.central(raw.area_px()));
        assert!((bc.mu20 - wc.mu20).abs() < 1e-9 * bc.mu20.abs().max(1.0));
        assert!((bc.mu11 - wc.mu11).abs() < 1e-9 * bc.mu20.abs().max(1.0));
    }
}
