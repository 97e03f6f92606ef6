//! Foreground runs of a row: `pixel >= threshold` tested 64 pixels at a time (SSE2, or AVX2 where
//! the CPU has it) and turned into runs `x0..=x1` (thesis Eq. 3.33–3.40 sum over them in closed
//! form). Part of `extract` (module docs there).

use super::*;

#[inline(always)]
pub(super) fn mask64<P: Pixel, const AVX2: bool>(chunk: &[P], threshold: u32) -> u64 {
    if AVX2 {
        // SAFETY: see above — AVX2 is present whenever this instantiation runs.
        unsafe { P::foreground_mask64_avx2(chunk, threshold) }
    } else {
        P::foreground_mask64(chunk, threshold)
    }
}

/// A run's weight sums over `row[a..b]` ([`Pixel::weight_sums`]), with 256-bit vectors when
/// `AVX2`.
#[inline(always)]
pub(super) fn weight_sums<P: Pixel, const AVX2: bool>(
    row: &[P],
    a: usize,
    b: usize,
    bg: u32,
    cap: u32,
) -> (u64, u64, u64) {
    if AVX2 {
        // SAFETY: as for `mask64`.
        unsafe { P::weight_sums_avx2(row, a, b, bg, cap) }
    } else {
        P::weight_sums(row, a, b, bg, cap)
    }
}

#[inline(always)]
pub(super) fn any64x4<P: Pixel, const AVX2: bool>(chunks: [&[P]; 4], threshold: u32) -> bool {
    if AVX2 {
        // SAFETY: as for `mask64`.
        unsafe { P::any_foreground64x4_avx2(chunks, threshold) }
    } else {
        P::any_foreground64x4(chunks, threshold)
    }
}

/// Whether any pixel of the row's segments is foreground: the quick test that lets empty rows
/// (most rows of a tracking window) skip all bookkeeping. A segment of 64 pixels or more is
/// read in whole 64-pixel chunks, the last one ending at the segment's end (overlapping the one
/// before), so no chunk needs a mask.
#[inline(always)]
pub(super) fn row_has_foreground<P: Pixel, const AVX2: bool>(row: &[P], segs: &[Seg]) -> bool {
    for seg in segs {
        let (mut x, end) = (seg.x0 as usize, seg.x1 as usize + 1);
        if end - x >= 64 {
            // Four chunks at a time, then one, then the last ending at the segment's end.
            while x + 256 <= end {
                let c = |i: usize| &row[x + 64 * i..x + 64 * (i + 1)];
                if any64x4::<P, AVX2>([c(0), c(1), c(2), c(3)], seg.threshold) {
                    return true;
                }
                x += 256;
            }
            while x + 64 <= end {
                if mask64::<P, AVX2>(&row[x..x + 64], seg.threshold) != 0 {
                    return true;
                }
                x += 64;
            }
            if x < end && mask64::<P, AVX2>(&row[end - 64..end], seg.threshold) != 0 {
                return true;
            }
        } else if x + 64 <= row.len() {
            let n = end - x;
            if mask64::<P, AVX2>(&row[x..x + 64], seg.threshold) & ((1u64 << n) - 1) != 0 {
                return true;
            }
        } else if row[x..end].iter().any(|p| p.value() >= seg.threshold) {
            return true;
        }
    }
    false
}

/// The first row in `y..y1` with a foreground pixel in `segs`, or `y1` (bands of whole rows
/// or several segments; a narrow window's band is skipped four rows at a time in the scan).
#[inline(always)]
pub(super) fn next_nonempty_row<P: Pixel, const AVX2: bool>(
    img: &GrayView<'_, P>,
    segs: &[Seg],
    mut y: u32,
    y1: u32,
) -> u32 {
    while y < y1 && !row_has_foreground::<P, AVX2>(img.row(y), segs) {
        y += 1;
    }
    y
}

/// A narrow segment's row as one mask (bit i = pixel `seg.x0 + i`): its first 64-pixel chunk,
/// and its second (starting `offset` pixels in, overlapping the first) when it is wider.
#[inline(always)]
pub(super) fn narrow_row_mask<P: Pixel, const AVX2: bool>(
    first: &[P],
    second: Option<(&[P], u32)>,
    threshold: u32,
) -> u128 {
    let a = mask64::<P, AVX2>(first, threshold) as u128;
    match second {
        Some((chunk, offset)) => a | (mask64::<P, AVX2>(chunk, threshold) as u128) << offset,
        None => a,
    }
}

/// The runs of a segment read as one masked chunk of up to 128 pixels (bit i = pixel
/// `seg.x0 + i`).
#[inline]
pub(super) fn runs_from_mask(mut mask: u128, seg: &Seg, out: &mut Vec<(u32, u32, bool)>) {
    out.clear();
    let n = seg.x1 - seg.x0 + 1;
    while mask != 0 {
        let start = mask.trailing_zeros();
        let end = start + (!(mask >> start)).trailing_zeros(); // exclusive
        let clipped = (start == 0 && seg.open_left) || (end == n && seg.open_right);
        out.push((seg.x0 + start, seg.x0 + end - 1, clipped));
        mask = if end >= 128 {
            0
        } else {
            mask & (u128::MAX << end)
        };
    }
}

/// Finds the foreground runs of one row across the row's segments, joining runs that cross
/// from one segment into a contiguous next one. Each run: `(x0, x1, clipped_horizontally)`.
#[inline(always)]
pub(super) fn find_row_runs<P: Pixel, const AVX2: bool>(
    row: &[P],
    segs: &[Seg],
    out: &mut Vec<(u32, u32, bool)>,
) {
    out.clear();
    // An open run: (start, clipped on the left).
    let mut open: Option<(u32, bool)> = None;
    for seg in segs {
        if seg.open_left {
            // Not contiguous with a previous segment: nothing can be open here.
            if let Some((s, c)) = open.take() {
                out.push((s, seg.x0 - 1, c));
            }
        }
        let thr = seg.threshold;
        let mut x = seg.x0;
        let end = seg.x1 + 1;
        // 64 pixels at a time; the last chunk of a segment is masked to the segment's end
        // (read from the row when it has 64 pixels left, else from a padded copy).
        while x < end {
            if open.is_none() {
                // The common case: 64 background pixels, one compare and skip.
                while x + 64 <= end
                    && mask64::<P, AVX2>(&row[x as usize..x as usize + 64], thr) == 0
                {
                    x += 64;
                }
                if x >= end {
                    break;
                }
            }
            let n = (end - x).min(64);
            let limit = if n == 64 { u64::MAX } else { (1u64 << n) - 1 };
            let mask = if x as usize + 64 <= row.len() {
                mask64::<P, AVX2>(&row[x as usize..x as usize + 64], thr) & limit
            } else {
                // The last pixels of the row: read through a padded copy.
                let mut pad = [P::default(); 64];
                pad[..n as usize].copy_from_slice(&row[x as usize..(x + n) as usize]);
                P::foreground_mask64(&pad, thr) & limit
            };
            if open.is_none() && mask == 0 {
                x += n;
                continue;
            }
            if open.is_some() && mask == limit {
                x += n;
                continue;
            }
            let mut pos = 0u32;
            while pos < n {
                match open {
                    Some((start, c)) => {
                        let ones = (!mask >> pos).trailing_zeros();
                        if pos + ones >= n {
                            break;
                        }
                        out.push((start, x + pos + ones - 1, c));
                        open = None;
                        pos += ones;
                    }
                    None => {
                        let zeros = (mask >> pos).trailing_zeros();
                        if zeros >= n - pos {
                            break;
                        }
                        let start = x + pos + zeros;
                        open = Some((start, start == seg.x0 && seg.open_left));
                        pos += zeros;
                    }
                }
            }
            x += n;
        }
        if seg.open_right
            && let Some((s, _c)) = open.take()
        {
            out.push((s, seg.x1, true));
        }
    }
    if let Some((s, c)) = open.take() {
        // Ends at the last segment's end, which is then the frame's right edge or contiguous.
        let last = segs.last().map_or(s, |g| g.x1);
        out.push((s, last, c));
    }
}

/// The one run of a segment's row held as a mask (bit i = pixel `seg.x0 + i`, as
/// [`narrow_row_mask`] reads it): `None` when the row holds no run or several.
#[inline(always)]
pub(super) fn single_run_of_mask(mask: u128, seg: &Seg) -> Option<(u32, u32)> {
    if mask == 0 {
        return None;
    }
    let start = mask.trailing_zeros();
    let end = start + (!(mask >> start)).trailing_zeros(); // exclusive
    if end < 128 && mask >> end != 0 {
        return None;
    }
    Some((seg.x0 + start, seg.x0 + end - 1))
}

/// The one run of a wide segment's row (at least 64 pixels), read 64 pixels at a time, the
/// last chunk ending at the segment's end: `None` when the row holds no run or several. It
/// stops at the first chunk that shows a second run.
#[inline(always)]
pub(super) fn single_run_of_row<P: Pixel, const AVX2: bool>(
    row: &[P],
    seg: &Seg,
) -> Option<(u32, u32)> {
    let (x0, end) = (seg.x0 as usize, seg.x1 as usize + 1);
    debug_assert!(end - x0 >= 64 && end <= row.len());
    // Where the run starts and ends (exclusive), once seen.
    let (mut start, mut stop) = (None, None);
    let mut c = x0;
    while c < end {
        let n = (end - c).min(64);
        let m = if n == 64 {
            mask64::<P, AVX2>(&row[c..c + 64], seg.threshold)
        } else {
            mask64::<P, AVX2>(&row[end - 64..end], seg.threshold) >> (64 - n)
        };
        match (start, stop) {
            (None, _) => {
                if m != 0 {
                    let s = m.trailing_zeros() as usize;
                    let e = s + (!(m >> s)).trailing_zeros() as usize;
                    start = Some(c + s);
                    if e < n {
                        if m >> e != 0 {
                            return None;
                        }
                        stop = Some(c + e);
                    }
                }
            }
            (Some(_), None) => {
                // A chunk of ones continues the run (`!m` is 0 for 64 ones); above `n` the
                // shifted mask is 0, so `ones <= n`.
                let ones = (!m).trailing_zeros() as usize;
                if ones < n {
                    if m >> ones != 0 {
                        return None;
                    }
                    stop = Some(c + ones);
                }
            }
            (Some(_), Some(_)) => {
                if m != 0 {
                    return None;
                }
            }
        }
        c += n;
    }
    let start = start?;
    Some((start as u32, stop.unwrap_or(end) as u32 - 1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The one run of a mask, bit by bit: `None` for none or several.
    fn reference(mask: u128) -> Option<(u32, u32)> {
        let ones: Vec<u32> = (0..128).filter(|&i| mask >> i & 1 == 1).collect();
        let (&a, &b) = (ones.first()?, ones.last()?);
        (b - a + 1 == ones.len() as u32).then_some((a, b))
    }

    /// Every run of every length at every place (touching bit 0, bit 127 or both), with a
    /// second run or a lone bit anywhere beside it, and random masks: the carry test says what
    /// counting the bits says.
    #[test]
    fn the_single_run_of_a_mask_is_found_and_two_are_told_apart() {
        let seg = Seg {
            x0: 5,
            x1: 132,
            threshold: 1,
            open_left: false,
            open_right: false,
        };
        let run = |a: u32, b: u32| (u128::MAX >> (127 - b)) & (u128::MAX << a);
        let mut masks = vec![0u128, u128::MAX, 1, 1 << 127, 1 | 1 << 127];
        for a in 0..128 {
            for b in a..128 {
                let m = run(a, b);
                masks.push(m);
                for lone in [0u32, 1, 63, 64, 126, 127] {
                    masks.push(m | 1 << lone);
                }
            }
        }
        let mut rng = stereoscope_numeric::SplitMix64::new(7);
        for _ in 0..2000 {
            masks.push((rng.next_u64() as u128) << 64 | rng.next_u64() as u128);
        }
        for m in masks {
            let want = reference(m).map(|(a, b)| (seg.x0 + a, seg.x0 + b));
            assert_eq!(single_run_of_mask(m, &seg), want, "{m:#034x}");
        }
    }
}
