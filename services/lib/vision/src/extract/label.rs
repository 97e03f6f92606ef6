//! Connected runs joined into blobs: a union-find over provisional labels per band (no label
//! image), each run's moments added to its label's accumulator (Eq. 3.33–3.40, Eq. 3.1 weights),
//! and the bands of a parallel scan joined at their cuts. Part of `extract` (module docs there).

use super::*;

// ---------------------------------------------------------------------------------------------
// Scanning one band of rows.

#[derive(Debug, Clone, Copy)]
pub(super) struct RunRef {
    pub(super) x0: u32,
    pub(super) x1: u32,
    pub(super) label: u32,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Acc {
    pub(super) m: RawMoments,
    pub(super) bbox: PixelRect,
    pub(super) first: (u32, u32),
    pub(super) flags: BlobFlags,
}

#[derive(Debug, Default)]
pub(super) struct Scratch {
    pub(super) prev: Vec<RunRef>,
    pub(super) cur: Vec<RunRef>,
    pub(super) parent: Vec<u32>,
    pub(super) acc: Vec<Acc>,
    pub(super) wacc: Vec<WeightedMoments>,
    pub(super) row_runs: Vec<(u32, u32, bool)>,
    pub(super) first_row: Vec<RunRef>,
    pub(super) first_row_y: Option<u32>,
    pub(super) last_row: Vec<RunRef>,
    pub(super) last_row_y: Option<u32>,
    pub(super) runs: usize,
}

#[inline]
pub(super) fn find(parent: &mut [u32], mut a: u32) -> u32 {
    while parent[a as usize] != a {
        let p = parent[a as usize];
        parent[a as usize] = parent[p as usize];
        a = p;
    }
    a
}

pub(super) fn merge_acc(into: &mut Acc, from: &Acc) {
    into.m.merge(&from.m);
    into.bbox.x0 = into.bbox.x0.min(from.bbox.x0);
    into.bbox.y0 = into.bbox.y0.min(from.bbox.y0);
    into.bbox.x1 = into.bbox.x1.max(from.bbox.x1);
    into.bbox.y1 = into.bbox.y1.max(from.bbox.y1);
    into.first = into.first.min(from.first);
    into.flags.0 |= from.flags.0;
}

// The narrow-window pixel tests (a tracking window's row is one 64-pixel chunk), in SSE2 (the
// x86-64 baseline) or, when `AVX2` is set, with 256-bit vectors: two loads per row instead of
// four. `AVX2 = true` is instantiated only inside `Scratch::scan_avx2`, which runs only after
// the CPU was found to support AVX2 (`Extractor::new`) and is compiled with it enabled. Whole
// rows (the full-frame pass) keep the 16-byte tests: with 256-bit ones the full pass measured
// 20 % slower (docs/performance.md), every other 32-byte load of a row straddling a cache line.

impl Scratch {
    /// Adds the run `x0..=x1` of row `y` to blob `label`'s sums (and weighted sums).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn add_run<P: Pixel, const AVX2: bool>(
        &mut self,
        label: u32,
        x0: u32,
        x1: u32,
        y: u32,
        clipped: bool,
        background: Option<(u32, u32)>,
        img: &GrayView<'_, P>,
    ) {
        let a = &mut self.acc[label as usize];
        a.m.add_run(x0, x1, y);
        a.bbox.x0 = a.bbox.x0.min(x0);
        a.bbox.x1 = a.bbox.x1.max(x1);
        a.bbox.y1 = y;
        if clipped {
            a.flags.insert(BlobFlags::CLIPPED);
        }
        if let Some(levels) = background {
            self.add_weighted_run::<P, AVX2>(label, x0, x1, y, levels, img);
        }
    }

    /// Adds the run's grey-level weights (Eq. 3.1, `pixel − background` capped) to blob
    /// `label`'s weighted sums.
    #[inline(always)]
    pub(super) fn add_weighted_run<P: Pixel, const AVX2: bool>(
        &mut self,
        label: u32,
        x0: u32,
        x1: u32,
        y: u32,
        (bg, cap): (u32, u32),
        img: &GrayView<'_, P>,
    ) {
        let row = img.row(y);
        let (sw, swx, swxx) = weight_sums::<P, AVX2>(row, x0 as usize, x1 as usize + 1, bg, cap);
        self.wacc[label as usize].add_row_sums(sw, swx, swxx, y);
    }

    /// A new blob whose first run is `x0..=x1` of row `y` (its sums still empty), with
    /// weighted sums when `weighted`: its label.
    #[inline(always)]
    fn new_label(&mut self, x0: u32, x1: u32, y: u32, weighted: bool) -> u32 {
        let label = self.parent.len() as u32;
        self.parent.push(label);
        self.acc.push(Acc {
            m: RawMoments::default(),
            bbox: PixelRect {
                x0,
                y0: y,
                x1,
                y1: y,
            },
            first: (y, x0),
            flags: BlobFlags::default(),
        });
        if weighted {
            self.wacc.push(WeightedMoments::default());
        }
        label
    }

    pub(super) fn reset(&mut self) {
        self.prev.clear();
        self.cur.clear();
        self.parent.clear();
        self.acc.clear();
        self.wacc.clear();
        self.first_row.clear();
        self.first_row_y = None;
        self.last_row.clear();
        self.last_row_y = None;
        self.runs = 0;
    }

    /// Scans rows `ya..yb` of the region, with AVX2 pixel tests when `avx2` (the CPU has it),
    /// adding its blobs' labels to those of the regions scanned since the last
    /// [`Scratch::reset`] (regions that do not touch: their blobs cannot join).
    pub(super) fn scan<P: Pixel>(
        &mut self,
        img: &GrayView<'_, P>,
        region: &Region,
        (ya, yb): (u32, u32),
        cfg: &ExtractConfig,
        avx2: bool,
    ) {
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: `avx2` is set only when the CPU was found to support AVX2.
            unsafe { self.scan_avx2(img, region, ya, yb, cfg) };
            return;
        }
        let _ = avx2;
        self.scan_with::<P, false>(img, region, ya, yb, cfg);
    }

    /// [`Scratch::scan_with`] compiled with AVX2, so its 256-bit pixel tests are inlined.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn scan_avx2<P: Pixel>(
        &mut self,
        img: &GrayView<'_, P>,
        region: &Region,
        ya: u32,
        yb: u32,
        cfg: &ExtractConfig,
    ) {
        self.scan_with::<P, true>(img, region, ya, yb, cfg);
    }

    #[inline(always)]
    pub(super) fn scan_with<P: Pixel, const AVX2: bool>(
        &mut self,
        img: &GrayView<'_, P>,
        region: &Region,
        ya: u32,
        yb: u32,
        cfg: &ExtractConfig,
    ) {
        // A region scanned after another (a cluster of windows) starts with no row above it;
        // its labels go on from the last region's (the caller resets between frames).
        self.prev.clear();
        self.cur.clear();
        let k = match cfg.connectivity {
            Connectivity::Eight => 1u32,
            Connectivity::Four => 0u32,
        };
        let background = cfg.weighting.levels();
        // The frame as bytes for the 8-bit vector block (`block`).
        let bytes = if AVX2 { img.as_u8() } else { None };
        let mut prev_y: Option<u32> = None;
        for (bi, band) in region.bands.iter().enumerate() {
            let (y0, y1) = (band.y0.max(ya), band.y1.min(yb));
            if y0 >= y1 {
                continue;
            }
            let segs = &region.segs[band.segs.0..band.segs.1];
            // A band that is one segment of at most 128 pixels (a tracking window) is read as
            // one or two 64-pixel chunks per row — the second ending at the segment's end,
            // overlapping the first, so the two cover the segment exactly — its runs taken
            // straight from the chunks' mask (bit i = pixel `seg.x0 + i`).
            let narrow = match segs {
                [seg] if seg.x1 - seg.x0 < 128 && seg.x0 + 64 <= img.width() => {
                    let n = seg.x1 - seg.x0 + 1;
                    let limit = if n == 128 {
                        u128::MAX
                    } else {
                        (1u128 << n) - 1
                    };
                    let second = (n > 64).then(|| seg.x1 + 1 - 64);
                    Some((*seg, limit, second))
                }
                _ => None,
            };
            // A band of one segment, narrow or wide (at least 64 pixels): its blobs' rows of one
            // run each are summed as blocks (below).
            let one_seg = match (narrow, segs) {
                (Some((seg, _, _)), _) => Some(seg),
                (None, [seg]) if seg.x1 - seg.x0 >= 63 => Some(*seg),
                _ => None,
            };
            // The single run of row `yy` of the band's one segment `wide` (None: no run, or
            // several).
            let one_run = |yy: u32, wide: &Seg| match narrow {
                Some((seg, limit, second)) => {
                    // SAFETY: every caller's `yy < y1 <= height`; a narrow band has
                    // `seg.x0 + 64 <= width` (checked above) and its second chunk ends at
                    // `seg.x1 < width`.
                    let chunk = |x: usize| unsafe { img.chunk64_unchecked(yy, x) };
                    let mask = narrow_row_mask::<P, AVX2>(
                        chunk(seg.x0 as usize),
                        second.map(|b| (chunk(b as usize), b - seg.x0)),
                        seg.threshold,
                    ) & limit;
                    single_run_of_mask(mask, &seg)
                }
                None => single_run_of_row::<P, AVX2>(img.row(yy), wide),
            };
            let mut row_runs = std::mem::take(&mut self.row_runs);
            let mut y = y0;
            while y < y1 {
                // Empty rows (most rows of a tracking window) are skipped in a tight loop: they
                // join nothing, and an empty cut row needs no record for the band joins.
                let skip_from = y;
                let mut narrow_mask = 0u128;
                let row = match narrow {
                    Some((seg, limit, second)) => {
                        let x0 = seg.x0 as usize;
                        // SAFETY: a narrow band has `seg.x0 + 64 <= width` (checked above), its
                        // second chunk ends at `seg.x1 < width`, and its rows are below
                        // `y1 <= height`; every call below is for a row < y1.
                        let chunk = |y: u32, x: usize| unsafe { img.chunk64_unchecked(y, x) };
                        let mut mask = 0;
                        // Right after a row with runs the next row is likely busy too: test it
                        // alone before skipping four chunks at a time (four rows of one chunk,
                        // or two rows of two).
                        let mut skip_fours =
                            prev_y != Some(y.wrapping_sub(1)) || self.prev.is_empty();
                        while y < y1 {
                            match second {
                                None if skip_fours
                                    && y + 4 <= y1
                                    && !any64x4::<P, AVX2>(
                                        [
                                            chunk(y, x0),
                                            chunk(y + 1, x0),
                                            chunk(y + 2, x0),
                                            chunk(y + 3, x0),
                                        ],
                                        seg.threshold,
                                    ) =>
                                {
                                    y += 4;
                                    continue;
                                }
                                Some(b)
                                    if skip_fours
                                        && y + 2 <= y1
                                        && !any64x4::<P, AVX2>(
                                            [
                                                chunk(y, x0),
                                                chunk(y, b as usize),
                                                chunk(y + 1, x0),
                                                chunk(y + 1, b as usize),
                                            ],
                                            seg.threshold,
                                        ) =>
                                {
                                    y += 2;
                                    continue;
                                }
                                _ => {}
                            }
                            mask = narrow_row_mask::<P, AVX2>(
                                chunk(y, x0),
                                second.map(|b| (chunk(y, b as usize), b - seg.x0)),
                                seg.threshold,
                            ) & limit;
                            if mask != 0 {
                                break;
                            }
                            skip_fours = true;
                            y += 1;
                        }
                        narrow_mask = mask;
                        None
                    }
                    None => {
                        y = next_nonempty_row::<P, AVX2>(img, segs, y, y1);
                        if y < y1 { Some(img.row(y)) } else { None }
                    }
                };
                if y > skip_from {
                    self.prev.clear();
                    prev_y = Some(y - 1);
                }
                if y >= y1 {
                    break;
                }
                // The common row of a tracked blob: one run, continuing the one run of the row
                // above — no labels to join, so it goes straight into that blob's sums — or
                // starting a blob (nothing in the row above), which it labels. Taken when the
                // band is one segment: narrow (its rows read as a mask, above) or wide (at least
                // 64 pixels, read chunk by chunk).
                let above = if prev_y == Some(y.wrapping_sub(1)) && y > 0 {
                    self.prev.len()
                } else {
                    0
                };
                if let Some(seg) = one_seg
                    && y != ya
                    && y + 1 != yb
                    && above <= 1
                {
                    let first = match row {
                        Some(row) => single_run_of_row::<P, AVX2>(row, &seg),
                        None => single_run_of_mask(narrow_mask, &seg),
                    };
                    // Whether run `b` joins run `a` of the row above (touching by `k`).
                    let joins = |a: (u32, u32), b: (u32, u32)| a.0 <= b.1 + k && a.1 + k >= b.0;
                    if let Some((x0, x1)) = first
                        && (above == 0 || joins((self.prev[0].x0, self.prev[0].x1), (x0, x1)))
                    {
                        let hclip = |(r0, r1): (u32, u32)| {
                            (r0 == seg.x0 && seg.open_left) || (r1 == seg.x1 && seg.open_right)
                        };
                        let label = if above == 0 {
                            self.new_label(x0, x1, y, background.is_some())
                        } else {
                            find(&mut self.parent, self.prev[0].label)
                        };
                        let edge_row = (band.check_top && y == band.y0)
                            || (band.check_bottom && y + 1 == band.y1);
                        let mut clipped = hclip((x0, x1))
                            || (edge_row && region.vertically_clipped(bi, y, x0, x1));
                        let mut stop = y1.min(yb - 1);
                        if band.check_bottom {
                            stop = stop.min(band.y1 - 1);
                        }
                        // 8-bit pixels with AVX2 in a window up to 256 pixels wide: the rows
                        // in vectors (`block`), the same sums as the loop below.
                        #[cfg(target_arch = "x86_64")]
                        if let (true, Some(bytes)) = (AVX2, &bytes)
                            && narrow_block_fits(&seg, img.width())
                        {
                            // SAFETY: `AVX2` is instantiated only on a CPU with AVX2; the
                            // segment fits (checked); `y < y1 <= height`, `stop <= y1`; row
                            // `y`'s only run in the segment is `x0..=x1` (found above).
                            let b =
                                unsafe { narrow_block_avx2(bytes, &seg, y, stop, k, background) };
                            let (bx0, bx1) = b.x_span;
                            clipped |= hclip((bx0, bx1));
                            let a = &mut self.acc[label as usize];
                            a.m.merge(&b.moments);
                            a.bbox.x0 = a.bbox.x0.min(bx0);
                            a.bbox.x1 = a.bbox.x1.max(bx1);
                            a.bbox.y1 = b.end_y - 1;
                            if clipped {
                                a.flags.insert(BlobFlags::CLIPPED);
                            }
                            if background.is_some() {
                                self.wacc[label as usize].merge(&b.weighted);
                            }
                            self.prev.clear();
                            self.prev.push(RunRef {
                                x0: b.last.0,
                                x1: b.last.1,
                                label,
                            });
                            self.runs += (b.end_y - y) as usize;
                            prev_y = Some(b.end_y - 1);
                            y = b.end_y;
                            continue;
                        }
                        // The blob's next rows, while each is again one run continuing the
                        // one above: summed relative to this row in u64 and added once. The
                        // loop stops before the part's last row (recorded for the joins) and
                        // before a bottom row that needs the coverage check.
                        let mut block = RunBlock::new(y);
                        block.add_run(x0, x1, 0);
                        if let Some(levels) = background {
                            self.add_weighted_run::<P, AVX2>(label, x0, x1, y, levels, img);
                        }
                        let (mut bx0, mut bx1) = (x0, x1);
                        let mut run = (x0, x1);
                        let mut yy = y + 1;
                        while yy < stop {
                            let Some((r0, r1)) = one_run(yy, &seg) else {
                                break;
                            };
                            if !joins(run, (r0, r1)) {
                                break;
                            }
                            clipped |= hclip((r0, r1));
                            block.add_run(r0, r1, yy - y);
                            if let Some(levels) = background {
                                self.add_weighted_run::<P, AVX2>(label, r0, r1, yy, levels, img);
                            }
                            bx0 = bx0.min(r0);
                            bx1 = bx1.max(r1);
                            run = (r0, r1);
                            yy += 1;
                        }
                        let a = &mut self.acc[label as usize];
                        block.add_to(&mut a.m);
                        a.bbox.x0 = a.bbox.x0.min(bx0);
                        a.bbox.x1 = a.bbox.x1.max(bx1);
                        a.bbox.y1 = yy - 1;
                        if clipped {
                            a.flags.insert(BlobFlags::CLIPPED);
                        }
                        self.prev.clear();
                        self.prev.push(RunRef {
                            x0: run.0,
                            x1: run.1,
                            label,
                        });
                        self.runs += (yy - y) as usize;
                        prev_y = Some(yy - 1);
                        y = yy;
                        continue;
                    }
                }
                match (row, narrow) {
                    (Some(row), _) => find_row_runs::<P, AVX2>(row, segs, &mut row_runs),
                    (None, Some((seg, _, _))) => runs_from_mask(narrow_mask, &seg, &mut row_runs),
                    (None, None) => row_runs.clear(),
                }
                if prev_y != Some(y.wrapping_sub(1)) || y == 0 {
                    self.prev.clear();
                }
                self.cur.clear();
                let mut j = 0usize;
                for &(x0, x1, hclip) in &row_runs {
                    while j < self.prev.len() && self.prev[j].x1 + k < x0 {
                        j += 1;
                    }
                    let mut label = u32::MAX;
                    let mut jj = j;
                    while jj < self.prev.len() && self.prev[jj].x0 <= x1 + k {
                        let r = find(&mut self.parent, self.prev[jj].label);
                        if label == u32::MAX {
                            label = r;
                        } else if r != label {
                            let (keep, gone) = if r < label { (r, label) } else { (label, r) };
                            self.parent[gone as usize] = keep;
                            let from = self.acc[gone as usize];
                            merge_acc(&mut self.acc[keep as usize], &from);
                            if background.is_some() {
                                let w = self.wacc[gone as usize];
                                self.wacc[keep as usize].merge(&w);
                            }
                            label = keep;
                        }
                        jj += 1;
                    }
                    let edge_row =
                        (band.check_top && y == band.y0) || (band.check_bottom && y + 1 == band.y1);
                    let clipped = hclip || (edge_row && region.vertically_clipped(bi, y, x0, x1));
                    if label == u32::MAX {
                        label = self.new_label(x0, x1, y, background.is_some());
                    }
                    self.add_run::<P, AVX2>(label, x0, x1, y, clipped, background, img);
                    self.cur.push(RunRef { x0, x1, label });
                }
                self.runs += row_runs.len();
                if y == ya {
                    self.first_row.clear();
                    self.first_row.extend_from_slice(&self.cur);
                    self.first_row_y = Some(y);
                }
                if y + 1 == yb {
                    self.last_row.clear();
                    self.last_row.extend_from_slice(&self.cur);
                    self.last_row_y = Some(y);
                }
                std::mem::swap(&mut self.prev, &mut self.cur);
                prev_y = Some(y);
                y += 1;
            }
            self.row_runs = row_runs;
        }
    }
}
