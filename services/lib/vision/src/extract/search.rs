//! The tracker's search test: whether anything is bright outside the windows, read from a
//! sample of the frame's rows with nothing labelled (thesis ch. 5: the full-frame search for
//! new or lost objects, done only when this finds something). Part of `extract` (module docs
//! there).

use super::*;

/// Which rows a read of the frame looks at: those `y` with `y % step == phase`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RowSample {
    /// At least 1 (a 0 reads as 1).
    pub step: u32,
    /// Below `step` (taken modulo `step`).
    pub phase: u32,
}

impl RowSample {
    /// Every row.
    pub const ALL: RowSample = RowSample { step: 1, phase: 0 };

    /// The first sampled row at or after `y`, and the step to the next.
    fn first_from(self, y: u32) -> (u32, u32) {
        let step = self.step.max(1);
        let phase = self.phase % step;
        let ahead = (phase + step - y % step) % step;
        (y.saturating_add(ahead), step)
    }
}

/// Whether any pixel of `img` is `>= threshold` outside every rectangle of `windows`, in the
/// rows `rows` samples: one read of those rows, 256 pixels at a time (AVX2 where the CPU has
/// it), with nothing labelled or stored. The tracker's periodic search for new objects runs
/// this first and labels the whole frame only when it is true; when it is false (and every
/// row was read) every foreground pixel is inside the windows, so their union's blobs are the
/// frame's blobs.
pub fn any_foreground_outside<P: Pixel>(
    img: &GrayView<'_, P>,
    threshold: u32,
    windows: &[PixelRect],
    rows: RowSample,
) -> bool {
    #[cfg(target_arch = "x86_64")]
    if cpu_has_avx2() {
        // SAFETY: the CPU was just found to support AVX2.
        return unsafe { foreground_outside_avx2(img, threshold, windows, rows) };
    }
    foreground_outside_with::<P, false>(img, threshold, windows, rows)
}

/// [`foreground_outside_with`] compiled with AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn foreground_outside_avx2<P: Pixel>(
    img: &GrayView<'_, P>,
    threshold: u32,
    windows: &[PixelRect],
    rows: RowSample,
) -> bool {
    foreground_outside_with::<P, true>(img, threshold, windows, rows)
}

#[inline(always)]
pub(super) fn foreground_outside_with<P: Pixel, const AVX2: bool>(
    img: &GrayView<'_, P>,
    threshold: u32,
    windows: &[PixelRect],
    rows: RowSample,
) -> bool {
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return false;
    }
    // The rows where the set of covering windows changes: between two of them every row has
    // the same uncovered gaps, found once for the band rather than once per row.
    let mut cuts: Vec<u32> = Vec::with_capacity(2 * windows.len() + 2);
    cuts.extend([0, h]);
    for r in windows.iter().filter(|r| r.x0 <= r.x1 && r.y0 <= r.y1) {
        cuts.extend([r.y0.min(h), r.y1.saturating_add(1).min(h)]);
    }
    cuts.sort_unstable();
    cuts.dedup();
    let mut covering: Vec<(u32, u32)> = Vec::with_capacity(windows.len());
    let mut gaps: Vec<(usize, usize)> = Vec::with_capacity(windows.len() + 1);
    for band in cuts.windows(2) {
        let (ya, yb) = (band[0], band[1]);
        covering.clear();
        covering.extend(
            windows
                .iter()
                .filter(|r| r.x0 <= r.x1 && r.y0 <= ya && ya <= r.y1 && r.x0 < w)
                .map(|r| (r.x0, r.x1.min(w - 1))),
        );
        covering.sort_unstable();
        gaps.clear();
        let mut x = 0u32;
        for &(a, b) in &covering {
            if a > x {
                gaps.push((x as usize, a as usize));
            }
            x = x.max(b + 1);
        }
        if x < w {
            gaps.push((x as usize, w as usize));
        }
        if gaps.is_empty() {
            continue;
        }
        let whole_row = gaps[..] == [(0, w as usize)];
        let (first, step) = rows.first_from(ya);
        for y in (first..yb).step_by(step as usize) {
            let row = img.row(y);
            // Most rows hold nothing bright anywhere: one test of the whole row settles them
            // (the gaps between windows are many short pieces, each read apart).
            if !any_at_least::<P, AVX2>(row, threshold) {
                continue;
            }
            if whole_row
                || gaps
                    .iter()
                    .any(|&(a, b)| any_in::<P, AVX2>(row, a, b, threshold))
            {
                return true;
            }
        }
    }
    false
}

/// Whether any of `row[a..b]` is `>= threshold`: a piece shorter than 64 pixels as one mask
/// read inside the row ([`mask_at`]), a longer one by [`any_at_least`].
#[inline(always)]
fn any_in<P: Pixel, const AVX2: bool>(row: &[P], a: usize, b: usize, threshold: u32) -> bool {
    if b - a >= 64 || row.len() < 64 {
        any_at_least::<P, AVX2>(&row[a..b], threshold)
    } else {
        b > a && mask_at::<P, AVX2>(row, a, b - a, threshold) != 0
    }
}

/// Whether any of `pixels` is `>= threshold`: eight 64-pixel chunks at a time (one bounds
/// check for the eight), then four, then single chunks, the last one ending at the end
/// (overlapping the one before).
#[inline(always)]
fn any_at_least<P: Pixel, const AVX2: bool>(pixels: &[P], threshold: u32) -> bool {
    let n = pixels.len();
    let mut x = 0;
    while let Some(Ok(block)) = pixels.get(x..x + 512).map(<&[P; 512]>::try_from) {
        let c = |k: usize| &block[64 * k..64 * (k + 1)];
        if runs::any64x4::<P, AVX2>([c(0), c(1), c(2), c(3)], threshold)
            | runs::any64x4::<P, AVX2>([c(4), c(5), c(6), c(7)], threshold)
        {
            return true;
        }
        x += 512;
    }
    while x + 256 <= n {
        let c = |k: usize| &pixels[x + 64 * k..x + 64 * (k + 1)];
        if runs::any64x4::<P, AVX2>([c(0), c(1), c(2), c(3)], threshold) {
            return true;
        }
        x += 256;
    }
    while x + 64 <= n {
        if runs::mask64::<P, AVX2>(&pixels[x..x + 64], threshold) != 0 {
            return true;
        }
        x += 64;
    }
    if x < n {
        if n >= 64 {
            return runs::mask64::<P, AVX2>(&pixels[n - 64..n], threshold) != 0;
        }
        return pixels[x..].iter().any(|p| p.value() >= threshold);
    }
    false
}
