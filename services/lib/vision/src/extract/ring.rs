//! Coverage weights of the dim pixels round each blob (its edge ring, Eq. 3.1 weights added to
//! the blob's grey-level moments), read as 64-pixel masks. Part of `extract` (module docs
//! there).

use super::*;

/// [`add_edge_ring`] for each blob, at the lowest threshold of the windows holding its first
/// pixel (`levels`: the frame's threshold, the background and the full level), with AVX2 pixel
/// tests and sums when `avx2` (the CPU was found to have it).
pub(super) fn edge_rings<P: Pixel>(
    blobs: &mut [Blob],
    img: &GrayView<'_, P>,
    levels: (u32, u32, u32),
    windows: &[Window],
    avx2: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        /// # Safety
        /// The CPU must support AVX2.
        #[target_feature(enable = "avx2")]
        unsafe fn with_avx2<P: Pixel>(
            blobs: &mut [Blob],
            img: &GrayView<'_, P>,
            levels: (u32, u32, u32),
            windows: &[Window],
        ) {
            edge_rings_with::<P, true>(blobs, img, levels, windows);
        }
        // SAFETY: `avx2` is set only when the CPU was found to support AVX2.
        unsafe { with_avx2(blobs, img, levels, windows) };
        return;
    }
    let _ = avx2;
    edge_rings_with::<P, false>(blobs, img, levels, windows);
}

#[inline(always)]
fn edge_rings_with<P: Pixel, const AVX2: bool>(
    blobs: &mut [Blob],
    img: &GrayView<'_, P>,
    (threshold, background, full): (u32, u32, u32),
    windows: &[Window],
) {
    for b in blobs {
        let thr = windows
            .iter()
            .filter(|w| {
                w.rect
                    .contains(b.first_pixel.1 as f64, b.first_pixel.0 as f64)
            })
            .map(|w| w.threshold.unwrap_or(threshold))
            .min()
            .unwrap_or(threshold);
        add_edge_ring::<P, AVX2>(b, img, thr, background, full);
    }
}

/// Coverage weights of the pixels around a blob that fell below its threshold: a pixel that
/// the target covers by less than about half is dimmer than the threshold, and leaving it out
/// pulls the centroid towards the pixel grid (up to a tenth of a pixel on a marker of 20
/// pixels). In the blob's box widened by one pixel, every pixel below the threshold and above
/// the background that lies outside the blob's outline on its row — left of its first pixel at
/// or above the threshold, right of its last — adds `pixel − background`, and so does every
/// such pixel of the rows just above and below the box. (Only the outside is read: a big
/// blob's inside costs nothing again. A dim hollow inside a blob's row, such as a double
/// ball's waist, is not added; a dim pixel within two pixels of two blobs counts in both.)
///
/// Each row is read as 64-pixel masks: one at the threshold finds the outline, one just above
/// the background picks the few pixels that carry a weight (most of the outside is
/// background), and only those are summed.
#[inline(always)]
fn add_edge_ring<P: Pixel, const AVX2: bool>(
    b: &mut Blob,
    img: &GrayView<'_, P>,
    threshold: u32,
    background: u32,
    full: u32,
) {
    let Some(wm) = b.weighted.as_mut() else {
        return;
    };
    let (w, h) = (img.width(), img.height());
    let bb = b.bbox;
    let (x0, x1) = (bb.x0.saturating_sub(1), (bb.x1 + 1).min(w - 1));
    let (y0, y1) = (bb.y0.saturating_sub(1), (bb.y1 + 1).min(h - 1));
    let top = threshold.min(full);
    // Pixels at or above this level weigh something; none when the background is the top.
    let Some(weighty) = background.checked_add(1).filter(|&l| l <= P::MAX_VALUE) else {
        return;
    };
    let (a, e) = (x0 as usize, x1 as usize + 1);
    // 8-bit pixels with AVX2, a box up to 128 pixels wide: in vectors (`block::ring_avx2`).
    #[cfg(target_arch = "x86_64")]
    if AVX2
        && let Some(bytes) = img.as_u8()
        && ring_fits((x0, x1 + 1), w)
    {
        // SAFETY: `AVX2` is instantiated only on a CPU with AVX2; the columns fit (checked);
        // `y0 <= y1 < h`.
        let sums = unsafe { ring_avx2(&bytes, (x0, x1 + 1), (y0, y1), top, background) };
        wm.merge(&sums);
        return;
    }
    for y in y0..=y1 {
        let row = img.row(y);
        let mut sums = (0u64, 0u64, 0u64);
        if row.len() < 64 {
            // A frame narrower than one mask: pixel by pixel.
            let first = (a..e).find(|&x| row[x].value() >= top).unwrap_or(e);
            let last = (first..e).rev().find(|&x| row[x].value() >= top);
            for x in (a..first).chain(last.map_or(e, |l| l + 1)..e) {
                add_weight(&mut sums, x, row[x].value(), background);
            }
        } else if e - a <= 64 {
            // The row's box in one mask (a marker; a target at 640 × 480).
            let n = e - a;
            let bright = mask_at::<P, AVX2>(row, a, n, top);
            let inside = if bright == 0 {
                0
            } else {
                let (f, l) = (bright.trailing_zeros(), 63 - bright.leading_zeros());
                (u64::MAX >> (63 - l)) & (u64::MAX << f)
            };
            let weighed = mask_at::<P, AVX2>(row, a, n, weighty) & !inside;
            add_weights(&mut sums, row, a, weighed, background);
        } else if e - a <= 128 {
            // In two masks (a target up to 126 pixels wide).
            let n = e - a;
            let bright = masks128::<P, AVX2>(row, a, n, top);
            let inside = if bright == 0 {
                0
            } else {
                let (f, l) = (bright.trailing_zeros(), 127 - bright.leading_zeros());
                (u128::MAX >> (127 - l)) & (u128::MAX << f)
            };
            let weighed = masks128::<P, AVX2>(row, a, n, weighty) & !inside;
            add_weights(&mut sums, row, a, weighed as u64, background);
            add_weights(&mut sums, row, a + 64, (weighed >> 64) as u64, background);
        } else {
            let mut first = None;
            let mut c = a;
            while c < e {
                let n = (e - c).min(64);
                let m = mask_at::<P, AVX2>(row, c, n, top);
                if m != 0 {
                    first = Some(c + m.trailing_zeros() as usize);
                    break;
                }
                c += n;
            }
            let outside = match first {
                None => [(a, e), (e, e)],
                Some(f) => {
                    // From the right back to the last bright pixel (there is one: `f`).
                    let mut end = e;
                    let last = loop {
                        let c = end.saturating_sub(64).max(f);
                        let m = mask_at::<P, AVX2>(row, c, end - c, top);
                        if m != 0 {
                            break c + 63 - m.leading_zeros() as usize;
                        }
                        end = c;
                    };
                    [(a, f), (last + 1, e)]
                }
            };
            for (mut c, end) in outside {
                while c < end {
                    let n = (end - c).min(64);
                    let m = mask_at::<P, AVX2>(row, c, n, weighty);
                    add_weights(&mut sums, row, c, m, background);
                    c += n;
                }
            }
        }
        let (sw, swx, swxx) = sums;
        if sw > 0 {
            wm.add_row_sums(sw, swx, swxx, y);
        }
    }
}

/// Bit `i` set where `row[c + i] >= level`, for the `n` pixels from `c` (`1 <= n <= 64`,
/// `c + n <= row.len()`, `row.len() >= 64`): one 64-pixel mask, read from `c` or, near the
/// row's end, from the last 64 pixels and shifted.
#[inline(always)]
pub(super) fn mask_at<P: Pixel, const AVX2: bool>(
    row: &[P],
    c: usize,
    n: usize,
    level: u32,
) -> u64 {
    let s = c.min(row.len() - 64);
    let m = mask64::<P, AVX2>(&row[s..s + 64], level) >> (c - s);
    if n >= 64 { m } else { m & ((1u64 << n) - 1) }
}

/// [`mask_at`] for up to 128 pixels (`1 <= n <= 128`), in one or two masks. (A function, not
/// a closure: a closure is not compiled with its caller's AVX2.)
#[inline(always)]
fn masks128<P: Pixel, const AVX2: bool>(row: &[P], c: usize, n: usize, level: u32) -> u128 {
    let m = mask_at::<P, AVX2>(row, c, n.min(64), level) as u128;
    if n > 64 {
        m | (mask_at::<P, AVX2>(row, c + 64, n - 64, level) as u128) << 64
    } else {
        m
    }
}

/// Adds `pixel − background` at column `x` to the row's sums `(Σw, Σw·x, Σw·x²)`, for a pixel
/// above the background.
#[inline(always)]
fn add_weight(sums: &mut (u64, u64, u64), x: usize, v: u32, background: u32) {
    if v > background {
        let (x, wt) = (x as u64, (v - background) as u64);
        sums.0 += wt;
        sums.1 += wt * x;
        sums.2 += wt * x * x;
    }
}

/// [`add_weight`] for each pixel `row[c + i]` with bit `i` of `mask` set.
#[inline(always)]
fn add_weights<P: Pixel>(
    sums: &mut (u64, u64, u64),
    row: &[P],
    c: usize,
    mut mask: u64,
    background: u32,
) {
    while mask != 0 {
        let x = c + mask.trailing_zeros() as usize;
        add_weight(sums, x, row[x].value(), background);
        mask &= mask - 1;
    }
}
