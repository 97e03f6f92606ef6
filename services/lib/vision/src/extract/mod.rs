//! Blob extraction: every connected bright region of a frame, or of a set of windows, with its
//! exact moments, in one pass over the pixels.
//!
//! Thesis: Eq. 3.33–3.40 / 4.1–4.9 (binary moments of a region of interest), extended from the
//! thesis's one-object-per-window to every connected region (the thesis's code summed every
//! bright pixel of a window into one object), and Eq. 3.1 for the optional grey-level weights.
//!
//! Method: each row is scanned for runs of foreground pixels (`pixel >= threshold`) 64 pixels
//! at a time (SSE2 compares on `u8`), runs are joined to the touching runs of the row above
//! through a union-find over provisional labels (no label image), and each run adds its moments
//! in closed form (`RawMoments::add_run`) to its label's accumulator, so a blob's moments are
//! complete when the scan ends — no second pass per blob.
//!
//! Windows: the union of the windows is scanned as one region, so a pixel covered by two
//! overlapping windows is counted once and a blob spanning them is one blob. Where windows
//! with different thresholds overlap, the lower threshold applies (the more inclusive one).
//! A blob touching a window edge that is not the frame edge is flagged `CLIPPED`: it may
//! continue outside the window.
//!
//! Parallel: with `threads > 1` the rows are cut into bands scanned on the rayon pool, and
//! the blobs touching each cut are joined afterwards (moments are additive).
//!
//! Pixel conventions: `docs/conventions.md`.

use crate::error::VisionError;
use crate::image::{GrayView, Pixel, PixelRect};
use crate::moments::{RawMoments, RunBlock, WeightedMoments};

/// Which neighbours join two foreground pixels into one blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Connectivity {
    /// Left, right, up, down.
    Four,
    /// The four plus the diagonals (default).
    #[default]
    Eight,
}

/// A region of interest with its own optional threshold (the thesis's `struct region`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub rect: PixelRect,
    /// `None`: the frame threshold passed to [`Extractor::extract`].
    pub threshold: Option<u32>,
}

impl Window {
    pub fn new(rect: PixelRect) -> Self {
        Window {
            rect,
            threshold: None,
        }
    }
}

/// Blob flags (a bit set).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct BlobFlags(pub u8);

impl BlobFlags {
    /// The blob touches the frame border: part of the object may be outside the image.
    pub const TOUCHES_BORDER: BlobFlags = BlobFlags(1);
    /// The blob touches a window edge inside the frame: it may continue outside the window.
    pub const CLIPPED: BlobFlags = BlobFlags(2);

    pub fn contains(self, f: BlobFlags) -> bool {
        self.0 & f.0 == f.0
    }

    pub fn insert(&mut self, f: BlobFlags) {
        self.0 |= f.0;
    }

    /// Flag names, for output.
    pub fn names(self) -> Vec<&'static str> {
        let mut v = Vec::new();
        if self.contains(Self::TOUCHES_BORDER) {
            v.push("touches_border");
        }
        if self.contains(Self::CLIPPED) {
            v.push("clipped");
        }
        v
    }
}

/// One connected bright region.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blob {
    /// Exact binary moments in frame coordinates.
    pub moments: RawMoments,
    /// Bounding box, inclusive.
    pub bbox: PixelRect,
    pub flags: BlobFlags,
    /// Grey-level moments (pixel − background), when enabled in [`ExtractConfig::weighting`].
    pub weighted: Option<WeightedMoments>,
    /// The blob's first pixel in raster order, `(y, x)`: blobs are listed in this order.
    pub first_pixel: (u32, u32),
}

impl Blob {
    pub fn area_px(&self) -> u64 {
        self.moments.m00
    }

    /// Binary centroid (Eq. 3.36–3.37).
    pub fn centroid_px(&self) -> (f64, f64) {
        self.moments.centroid_px().unwrap_or((f64::NAN, f64::NAN))
    }

    /// Intensity-weighted centroid when weights were computed, else the binary one.
    pub fn best_centroid_px(&self) -> (f64, f64) {
        self.weighted
            .and_then(|w| w.centroid_px())
            .unwrap_or_else(|| self.centroid_px())
    }

    pub fn central(&self) -> crate::moments::CentralMoments {
        self.moments.central()
    }

    /// Intensity-weighted central moments when weights were computed (sub-pixel edges), else
    /// the binary ones.
    pub fn best_central(&self) -> crate::moments::CentralMoments {
        match self.weighted {
            Some(w) if w.w00 > 0 => w.central(self.moments.m00),
            _ => self.moments.central(),
        }
    }

    /// Major-axis angle, degrees CCW on screen from the x axis, (−90, 90] (Eq. 3.44 corrected).
    pub fn orientation_deg(&self, par: f64) -> f64 {
        self.moments.central().orientation_deg(par)
    }
}

/// Grey-level weighting of the moments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Weighting {
    /// Binary moments only (the thesis's choice).
    #[default]
    Binary,
    /// Also grey-level moments with weight `pixel − background` over each blob's pixels.
    /// `background` must be below every threshold used.
    Intensity { background: u32 },
    /// Also coverage moments: weight `min(pixel − background, full − background)`, i.e. each
    /// pixel's estimated coverage by the target times `full − background`. Pixels at or above
    /// `full` count as fully covered whatever their shading, edge pixels in proportion, so the
    /// weighted centroid is the silhouette's with sub-pixel edges (no pull towards the lit side
    /// of a ball) and `w00 / (full − background)` its area in pixels.
    Coverage { background: u32, full: u32 },
}

impl Weighting {
    /// `(background, largest weight)` when grey-level moments are computed.
    fn levels(self) -> Option<(u32, u32)> {
        match self {
            Weighting::Binary => None,
            Weighting::Intensity { background } => Some((background, u32::MAX)),
            Weighting::Coverage { background, full } => {
                Some((background, full.saturating_sub(background)))
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExtractConfig {
    pub connectivity: Connectivity,
    /// Blobs smaller than this are not reported (counted in `below_min_area`).
    pub min_area_px: u64,
    /// Output capacity. When more blobs qualify, the largest are kept and the rest counted in
    /// `dropped_over_capacity`.
    pub max_blobs: usize,
    pub weighting: Weighting,
    /// Threads to cut a frame over: 1 scans on the caller's thread; 0 uses every core.
    pub threads: usize,
}

impl Default for ExtractConfig {
    fn default() -> Self {
        ExtractConfig {
            connectivity: Connectivity::Eight,
            min_area_px: 1,
            max_blobs: 1024,
            weighting: Weighting::Binary,
            threads: 1,
        }
    }
}

/// What one extraction saw besides its blobs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExtractStats {
    /// Connected regions found, before the area filter and the capacity.
    pub regions: usize,
    pub below_min_area: usize,
    /// Regions flagged `CLIPPED` (touching a window's edge inside the frame), before the area
    /// filter and the capacity.
    pub clipped_regions: usize,
    pub dropped_over_capacity: usize,
    /// Foreground runs.
    pub runs: usize,
    /// Pixels inside the scanned region.
    pub pixels_scanned: u64,
}

mod block;
mod label;
mod region;
mod ring;
mod runs;
mod search;

use block::*;
use label::*;
use region::*;
use ring::*;
use runs::*;
pub use search::{RowSample, any_foreground_outside};

// ---------------------------------------------------------------------------------------------
// The extractor.

/// Reusable blob extractor. After the first frames it allocates nothing per frame.
#[derive(Debug)]
pub struct Extractor {
    cfg: ExtractConfig,
    region: Region,
    scratch: Vec<Scratch>,
    blobs: Vec<Blob>,
    /// The blobs' labels in their order (scratch of [`emit_blobs`]).
    keys: Vec<((u32, u32), u32)>,
    stats: ExtractStats,
    // Joining bands.
    gparent: Vec<u32>,
    gacc: Vec<Acc>,
    gwacc: Vec<WeightedMoments>,
    offsets: Vec<u32>,
    ranges: Vec<(u32, u32)>,
    // Clustering windows.
    wparent: Vec<u32>,
    order: Vec<(u32, u32)>,
    clustered: Vec<Window>,
    cluster_ends: Vec<usize>,
    /// Pixel tests with AVX2 (found at construction; see [`Extractor::use_avx2`]).
    avx2: bool,
}

/// Below this many pixels a second thread costs more than it saves.
const PARALLEL_PIXELS: u64 = 65_536;

/// Whether two windows touch: they overlap, or no pixel lies between them (side by side or
/// corner to corner), so a blob can cross from one into the other.
fn touch(a: &PixelRect, b: &PixelRect) -> bool {
    a.x0 <= b.x1.saturating_add(1)
        && b.x0 <= a.x1.saturating_add(1)
        && a.y0 <= b.y1.saturating_add(1)
        && b.y0 <= a.y1.saturating_add(1)
}

/// Whether this CPU runs the AVX2 pixel tests.
fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

impl Extractor {
    pub fn new(cfg: ExtractConfig) -> Self {
        Extractor {
            cfg,
            region: Region::default(),
            scratch: Vec::new(),
            blobs: Vec::new(),
            keys: Vec::new(),
            stats: ExtractStats::default(),
            gparent: Vec::new(),
            gacc: Vec::new(),
            gwacc: Vec::new(),
            offsets: Vec::new(),
            ranges: Vec::new(),
            wparent: Vec::new(),
            order: Vec::new(),
            clustered: Vec::new(),
            cluster_ends: Vec::new(),
            avx2: cpu_has_avx2(),
        }
    }

    /// Uses the AVX2 pixel tests when `enabled` and the CPU has AVX2 (the default), else the
    /// SSE2 ones; results are identical either way. Returns whether AVX2 is now used.
    pub fn use_avx2(&mut self, enabled: bool) -> bool {
        self.avx2 = enabled && cpu_has_avx2();
        self.avx2
    }

    pub fn config(&self) -> &ExtractConfig {
        &self.cfg
    }

    pub fn set_config(&mut self, cfg: ExtractConfig) {
        self.cfg = cfg;
    }

    /// Statistics of the last extraction.
    pub fn stats(&self) -> ExtractStats {
        self.stats
    }

    /// The blobs of the last extraction.
    pub fn blobs(&self) -> &[Blob] {
        &self.blobs
    }

    /// Extracts the blobs of `img` with foreground `pixel >= threshold`, in the whole frame when
    /// `windows` is empty, else in the union of the windows (each may carry its own threshold).
    /// Blobs come in raster order of their first pixel.
    pub fn extract<P: Pixel>(
        &mut self,
        img: GrayView<'_, P>,
        threshold: u32,
        windows: &[Window],
    ) -> Result<&[Blob], VisionError> {
        check_threshold::<P>(threshold)?;
        if let Some((background, _)) = self.cfg.weighting.levels() {
            let min_thr = windows
                .iter()
                .filter_map(|w| w.threshold)
                .fold(threshold, u32::min);
            if background >= min_thr {
                return Err(VisionError::BackgroundNotBelowThreshold {
                    background,
                    threshold: min_thr,
                });
            }
        }
        let (w, h) = (img.width(), img.height());
        check_windows::<P>(windows, w, h)?;
        let threads = match self.cfg.threads {
            0 => rayon::current_num_threads(),
            n => n,
        };
        let cfg = self.cfg;
        let avx2 = self.avx2;
        // Windows on one thread: each cluster of windows that touch one another is scanned as
        // a region of its own, so a window apart from the others (a tracked marker, usually)
        // is one narrow segment on every row, the scan's fast path, rather than one of several
        // segments on the rows it shares with other windows. The clusters do not touch, so no
        // blob spans two; their blobs are the union's.
        let window_area: u64 = windows
            .iter()
            .map(|w| w.rect.width() as u64 * w.rect.height() as u64)
            .sum();
        if !windows.is_empty() && (threads == 1 || window_area < PARALLEL_PIXELS) {
            self.cluster_windows(windows);
            if self.scratch.is_empty() {
                self.scratch.push(Scratch::default());
            }
            self.scratch[0].reset();
            let mut pixels = 0;
            let mut start = 0;
            for &end in &self.cluster_ends {
                self.region
                    .set_windows(&self.clustered[start..end], w, h, threshold);
                pixels += self.region.pixel_count();
                let rows = self.region.rows();
                self.scratch[0].scan(&img, &self.region, rows, &cfg, avx2);
                start = end;
            }
            self.join_parts(1, w, h, pixels);
            self.add_edge_rings(&img, threshold, windows);
            return Ok(&self.blobs);
        }
        if windows.is_empty() {
            self.region.full(w, h, threshold);
        } else {
            self.region.set_windows(windows, w, h, threshold);
        }
        let (ya, yb) = self.region.rows();
        let pixels = self.region.pixel_count();
        let parts = if pixels < PARALLEL_PIXELS {
            1
        } else {
            threads.clamp(1, ((yb - ya) / 16).max(1) as usize)
        };
        if self.scratch.len() < parts {
            self.scratch.resize_with(parts, Scratch::default);
        }
        self.ranges.clear();
        let rows = yb - ya;
        for i in 0..parts as u32 {
            let a = ya + rows * i / parts as u32;
            let b = ya + rows * (i + 1) / parts as u32;
            self.ranges.push((a, b));
        }
        let region = &self.region;
        for s in &mut self.scratch[..parts] {
            s.reset();
        }
        if parts == 1 {
            self.scratch[0].scan(&img, region, (ya, yb), &cfg, avx2);
        } else {
            // The caller scans the first band itself while the pool takes the others, so a
            // frame never waits idle for a worker to wake up.
            let ranges = &self.ranges;
            let (first, rest) = self.scratch[..parts].split_at_mut(1);
            rayon::in_place_scope(|scope| {
                for (i, s) in rest.iter_mut().enumerate() {
                    let (a, b) = ranges[i + 1];
                    let img = &img;
                    let cfg = &cfg;
                    scope.spawn(move |_| s.scan(img, region, (a, b), cfg, avx2));
                }
                let (a, b) = ranges[0];
                first[0].scan(&img, region, (a, b), &cfg, avx2);
            });
        }
        self.join_parts(parts, w, h, pixels);
        self.add_edge_rings(&img, threshold, windows);
        Ok(&self.blobs)
    }

    /// With coverage weights, each blob's ring of dim edge pixels ([`add_edge_ring`]), at the
    /// threshold of the windows its first pixel is in.
    fn add_edge_rings<P: Pixel>(
        &mut self,
        img: &GrayView<'_, P>,
        threshold: u32,
        windows: &[Window],
    ) {
        if let Weighting::Coverage { background, full } = self.cfg.weighting {
            let levels = (threshold, background, full);
            edge_rings(&mut self.blobs, img, levels, windows, self.avx2);
        }
    }

    /// Groups `windows` into clusters of windows that touch (overlap, or lie side by side or
    /// corner to corner with no pixel between them), transitively: `clustered` holds the
    /// windows cluster after cluster, `cluster_ends` where each cluster ends in it.
    fn cluster_windows(&mut self, windows: &[Window]) {
        let n = windows.len();
        self.wparent.clear();
        self.wparent.extend(0..n as u32);
        for i in 0..n {
            for j in i + 1..n {
                if touch(&windows[i].rect, &windows[j].rect) {
                    let (a, b) = (
                        find(&mut self.wparent, i as u32),
                        find(&mut self.wparent, j as u32),
                    );
                    if a != b {
                        self.wparent[a.max(b) as usize] = a.min(b);
                    }
                }
            }
        }
        self.order.clear();
        for i in 0..n as u32 {
            let root = find(&mut self.wparent, i);
            self.order.push((root, i));
        }
        self.order.sort_unstable();
        self.clustered.clear();
        self.cluster_ends.clear();
        for (k, &(root, i)) in self.order.iter().enumerate() {
            if k > 0 && self.order[k - 1].0 != root {
                self.cluster_ends.push(k);
            }
            self.clustered.push(windows[i as usize]);
        }
        self.cluster_ends.push(n);
    }

    /// Joins the bands' labels into blobs and applies area filter, flags and capacity.
    fn join_parts(&mut self, parts: usize, width: u32, height: u32, pixels: u64) {
        let k = match self.cfg.connectivity {
            Connectivity::Eight => 1u32,
            Connectivity::Four => 0u32,
        };
        let weighted = self.cfg.weighting.levels().is_some();
        let stats = ExtractStats {
            runs: self.scratch[..parts].iter().map(|s| s.runs).sum(),
            pixels_scanned: pixels,
            ..Default::default()
        };
        if parts == 1 {
            // One part (every tracking step): its labels are the blobs, nothing to copy or join.
            let s = &mut self.scratch[0];
            for l in 0..s.parent.len() as u32 {
                let r = find(&mut s.parent, l);
                s.parent[l as usize] = r;
            }
            self.stats = emit_blobs(
                &s.parent,
                &s.acc,
                weighted.then_some(&s.wacc[..]),
                &self.cfg,
                (width, height),
                stats,
                &mut self.keys,
                &mut self.blobs,
            );
            return;
        }
        self.gparent.clear();
        self.gacc.clear();
        self.gwacc.clear();
        self.offsets.clear();
        for s in &mut self.scratch[..parts] {
            self.offsets.push(self.gparent.len() as u32);
            for l in 0..s.parent.len() as u32 {
                let r = find(&mut s.parent, l);
                self.gparent.push(self.offsets[self.offsets.len() - 1] + r);
            }
            self.gacc.extend_from_slice(&s.acc);
            if weighted {
                self.gwacc.extend_from_slice(&s.wacc);
            }
        }
        // Join across cuts: the last row of part i and the first row of part i + 1.
        for i in 0..parts.saturating_sub(1) {
            let (up, down) = (&self.scratch[i], &self.scratch[i + 1]);
            let (Some(yu), Some(yd)) = (up.last_row_y, down.first_row_y) else {
                continue;
            };
            if yu + 1 != yd {
                continue;
            }
            let (ou, od) = (self.offsets[i], self.offsets[i + 1]);
            let mut j = 0usize;
            for d in &down.first_row {
                while j < up.last_row.len() && up.last_row[j].x1 + k < d.x0 {
                    j += 1;
                }
                let mut jj = j;
                while jj < up.last_row.len() && up.last_row[jj].x0 <= d.x1 + k {
                    let a = find(&mut self.gparent, ou + up.last_row[jj].label);
                    let b = find(&mut self.gparent, od + d.label);
                    if a != b {
                        let (keep, gone) = if a < b { (a, b) } else { (b, a) };
                        self.gparent[gone as usize] = keep;
                        let from = self.gacc[gone as usize];
                        merge_acc(&mut self.gacc[keep as usize], &from);
                        if weighted {
                            let wf = self.gwacc[gone as usize];
                            self.gwacc[keep as usize].merge(&wf);
                        }
                    }
                    jj += 1;
                }
            }
        }
        self.stats = emit_blobs(
            &self.gparent,
            &self.gacc,
            weighted.then_some(&self.gwacc[..]),
            &self.cfg,
            (width, height),
            stats,
            &mut self.keys,
            &mut self.blobs,
        );
    }
}

/// The roots of `parent` (labels that are their own parent) as blobs: area filter, border flag,
/// capacity (largest kept), raster order of first pixels. The kept labels are put in order
/// first (`keys`, scratch) and each blob is made once, in place: a blob is some 250 bytes, and
/// sorting the blobs themselves (regions scanned one by one, such as the tracker's cores, give
/// them out of raster order) moved each several times.
#[allow(clippy::too_many_arguments)]
fn emit_blobs(
    parent: &[u32],
    acc: &[Acc],
    wacc: Option<&[WeightedMoments]>,
    cfg: &ExtractConfig,
    (width, height): (u32, u32),
    mut stats: ExtractStats,
    keys: &mut Vec<((u32, u32), u32)>,
    blobs: &mut Vec<Blob>,
) -> ExtractStats {
    keys.clear();
    for (l, a) in acc.iter().enumerate() {
        if parent[l] as usize != l {
            continue;
        }
        stats.regions += 1;
        if a.flags.contains(BlobFlags::CLIPPED) {
            stats.clipped_regions += 1;
        }
        if a.m.m00 < cfg.min_area_px {
            stats.below_min_area += 1;
            continue;
        }
        keys.push((a.first, l as u32));
    }
    if keys.len() > cfg.max_blobs {
        stats.dropped_over_capacity = keys.len() - cfg.max_blobs;
        // Keep the largest; ties by raster order.
        keys.sort_unstable_by(|&(p_first, p), &(q_first, q)| {
            acc[q as usize]
                .m
                .m00
                .cmp(&acc[p as usize].m.m00)
                .then(p_first.cmp(&q_first))
        });
        keys.truncate(cfg.max_blobs);
    }
    // Labels are made in raster order and a merge keeps the older, so the labels of one region
    // come sorted already (not after the capacity cut). First pixels are distinct.
    if !keys.is_sorted_by_key(|&(first, _)| first) {
        keys.sort_unstable_by_key(|&(first, _)| first);
    }
    blobs.clear();
    blobs.extend(keys.iter().map(|&(first, l)| {
        let a = &acc[l as usize];
        let mut flags = a.flags;
        let b = a.bbox;
        if b.x0 == 0 || b.y0 == 0 || b.x1 + 1 == width || b.y1 + 1 == height {
            flags.insert(BlobFlags::TOUCHES_BORDER);
        }
        Blob {
            moments: a.m,
            bbox: b,
            flags,
            weighted: wacc.map(|w| w[l as usize]),
            first_pixel: first,
        }
    }));
    stats
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::GrayImage;

    /// Reference: flood fill on a label image, moments pixel by pixel.
    fn reference_blobs(
        img: &GrayImage<u8>,
        thr: u32,
        conn: Connectivity,
        mask: Option<&[Window]>,
    ) -> Vec<(RawMoments, PixelRect, bool)> {
        reference_weighted_blobs(img, thr, conn, mask, 0)
            .into_iter()
            .map(|(b, _)| b)
            .collect()
    }

    /// [`reference_blobs`] with each blob's grey-level moments (weight `pixel − background`),
    /// pixel by pixel.
    fn reference_weighted_blobs(
        img: &GrayImage<u8>,
        thr: u32,
        conn: Connectivity,
        mask: Option<&[Window]>,
        background: u32,
    ) -> Vec<((RawMoments, PixelRect, bool), WeightedMoments)> {
        let (w, h) = (img.width() as i64, img.height() as i64);
        let inside = |x: i64, y: i64| -> Option<u32> {
            if x < 0 || y < 0 || x >= w || y >= h {
                return None;
            }
            match mask {
                None => Some(thr),
                Some(ws) => ws
                    .iter()
                    .filter(|win| {
                        let r = win.rect;
                        x as u32 >= r.x0 && x as u32 <= r.x1 && y as u32 >= r.y0 && y as u32 <= r.y1
                    })
                    .map(|win| win.threshold.unwrap_or(thr))
                    .min(),
            }
        };
        let fg = |x: i64, y: i64| {
            inside(x, y).is_some_and(|t| img.get(x as u32, y as u32).unwrap() as u32 >= t)
        };
        let mut seen = vec![false; (w * h) as usize];
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                if seen[(y * w + x) as usize] || !fg(x, y) {
                    continue;
                }
                let mut m = RawMoments::default();
                let mut wm = WeightedMoments::default();
                let mut bb = PixelRect {
                    x0: x as u32,
                    y0: y as u32,
                    x1: x as u32,
                    y1: y as u32,
                };
                let mut stack = vec![(x, y)];
                seen[(y * w + x) as usize] = true;
                // Clipped: a pixel with a 4-neighbour in the frame but outside the region.
                let mut clipped = false;
                while let Some((px, py)) = stack.pop() {
                    m.add_pixel(px as u32, py as u32);
                    let wt = (img.get(px as u32, py as u32).unwrap() as u32)
                        .saturating_sub(background) as u64;
                    wm.add_row_sums(wt, wt * px as u64, wt * (px * px) as u64, py as u32);
                    for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                        let (nx, ny) = (px + dx, py + dy);
                        if nx >= 0 && ny >= 0 && nx < w && ny < h && inside(nx, ny).is_none() {
                            clipped = true;
                        }
                    }
                    bb.x0 = bb.x0.min(px as u32);
                    bb.x1 = bb.x1.max(px as u32);
                    bb.y0 = bb.y0.min(py as u32);
                    bb.y1 = bb.y1.max(py as u32);
                    for (dx, dy) in [
                        (-1, 0),
                        (1, 0),
                        (0, -1),
                        (0, 1),
                        (-1, -1),
                        (1, -1),
                        (-1, 1),
                        (1, 1),
                    ] {
                        if conn == Connectivity::Four && dx != 0 && dy != 0 {
                            continue;
                        }
                        let (nx, ny) = (px + dx, py + dy);
                        if fg(nx, ny) && !seen[(ny * w + nx) as usize] {
                            seen[(ny * w + nx) as usize] = true;
                            stack.push((nx, ny));
                        }
                    }
                }
                out.push(((m, bb, clipped), wm));
            }
        }
        out
    }

    fn random_image(w: u32, h: u32, seed: u64, density: u32) -> GrayImage<u8> {
        let mut rng = stereoscope_numeric::SplitMix64::new(seed);
        let mut img = GrayImage::filled(w, h, 0u8).unwrap();
        for p in img.as_mut_slice() {
            *p = if (rng.next_u64() % 100) < density as u64 {
                200 + (rng.next_u64() % 50) as u8
            } else {
                (rng.next_u64() % 90) as u8
            };
        }
        img
    }

    fn sorted(mut v: Vec<(RawMoments, PixelRect, bool)>) -> Vec<(RawMoments, PixelRect, bool)> {
        v.sort_by_key(|(m, b, _)| (b.y0, b.x0, m.m00, m.m10, m.m01));
        v
    }

    /// An extractor with no capacity limit, on `threads`, with the AVX2 pixel tests when
    /// `avx2` (and the CPU has them).
    fn uncapped(connectivity: Connectivity, threads: usize, avx2: bool) -> Extractor {
        let mut ex = Extractor::new(ExtractConfig {
            connectivity,
            threads,
            max_blobs: 1 << 20,
            ..Default::default()
        });
        ex.use_avx2(avx2);
        ex
    }

    fn ours(blobs: &[Blob]) -> Vec<(RawMoments, PixelRect, bool)> {
        sorted(
            blobs
                .iter()
                .map(|b| (b.moments, b.bbox, b.flags.contains(BlobFlags::CLIPPED)))
                .collect(),
        )
    }

    /// A run's weight sums by every path — pixel by pixel in pieces, 16-byte vectors, 32-byte
    /// vectors (where the CPU has AVX2) — equal plain 64-bit sums: runs of every length up to
    /// many pieces, starting and ending anywhere in rows of every width (rows narrower than one
    /// vector, runs shorter than one, runs ending at the row's end), columns up to 64 000, at
    /// the largest weights (no overflow) and at random ones.
    #[test]
    fn weighted_run_sums_equal_64_bit_sums() {
        fn reference<P: Pixel>(
            row: &[P],
            a: usize,
            b: usize,
            bg: u32,
            cap: u32,
        ) -> (u64, u64, u64) {
            let mut s = (0u64, 0u64, 0u64);
            for (x, p) in row.iter().enumerate().take(b).skip(a) {
                let w = p.value().saturating_sub(bg).min(cap) as u64;
                let x = x as u64;
                s = (s.0 + w, s.1 + w * x, s.2 + w * x * x);
            }
            s
        }
        fn check<P: Pixel>(row: &[P], a: usize, b: usize, bg: u32, cap: u32) {
            let want = reference(row, a, b, bg, cap);
            let what = format!(
                "{a}..{b} of {} pixels, background {bg}, cap {cap}",
                row.len()
            );
            assert_eq!(
                crate::weights::scalar(row, a, b, bg, cap),
                want,
                "pieces: {what}"
            );
            assert_eq!(P::weight_sums(row, a, b, bg, cap), want, "16 bytes: {what}");
            if cpu_has_avx2() {
                // SAFETY: the CPU has AVX2 (checked).
                let got = unsafe { P::weight_sums_avx2(row, a, b, bg, cap) };
                assert_eq!(got, want, "32 bytes: {what}");
            }
        }
        let mut rng = stereoscope_numeric::SplitMix64::new(7);
        for len in [1usize, 15, 16, 17, 31, 32, 33, 100, 129, 300, 5000, 64_100] {
            let max8 = vec![255u8; len];
            let max16 = vec![65535u16; len];
            let rand8: Vec<u8> = (0..len).map(|_| rng.next_u64() as u8).collect();
            let rand16: Vec<u16> = (0..len).map(|_| rng.next_u64() as u16).collect();
            let mut ranges = vec![(0, len), (0, 0), (len, len), (len - 1, len)];
            for _ in 0..40 {
                let n = [
                    1, 5, 15, 16, 17, 31, 32, 33, 127, 128, 129, 255, 256, 257, 1000,
                ][(rng.next_u64() % 15) as usize]
                    .min(len);
                let a = match rng.next_u64() % 3 {
                    0 => 0,
                    1 => len - n,
                    _ => (rng.next_u64() % (len - n + 1) as u64) as usize,
                };
                ranges.push((a, a + n));
            }
            for (a, b) in ranges {
                for (bg, cap) in [(0, u32::MAX), (0, 255), (40, 180), (1000, 30_000), (250, 3)] {
                    check(&max8, a, b, bg, cap);
                    check(&rand8, a, b, bg, cap);
                    check(&max16, a, b, bg, cap);
                    check(&rand16, a, b, bg, cap);
                }
            }
        }
    }

    #[test]
    fn matches_flood_fill_on_random_images_full_frame() {
        for (seed, w, h) in [
            (1u64, 67u32, 41u32),
            (2, 130, 90),
            (3, 200, 3),
            (4, 1, 50),
            (5, 300, 257),
        ] {
            for density in [5, 30, 60] {
                let img = random_image(w, h, seed * 100 + density as u64, density);
                for conn in [Connectivity::Four, Connectivity::Eight] {
                    for threads in [1, 3] {
                        // The SSE2 tests with one thread, the CPU's best with three.
                        let mut ex = uncapped(conn, threads, threads != 1);
                        let got = ours(ex.extract(img.view(), 100, &[]).unwrap());
                        let want = sorted(reference_blobs(&img, 100, conn, None));
                        assert_eq!(
                            got, want,
                            "seed {seed} {w}×{h} density {density} {conn:?} threads {threads}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn matches_flood_fill_inside_overlapping_windows_with_own_thresholds() {
        let img = random_image(160, 120, 77, 35);
        let windows = [
            Window {
                rect: PixelRect {
                    x0: 10,
                    y0: 5,
                    x1: 70,
                    y1: 60,
                },
                threshold: None,
            },
            Window {
                rect: PixelRect {
                    x0: 50,
                    y0: 40,
                    x1: 120,
                    y1: 100,
                },
                threshold: Some(150),
            },
            Window {
                rect: PixelRect {
                    x0: 60,
                    y0: 0,
                    x1: 159,
                    y1: 20,
                },
                threshold: Some(60),
            },
            Window {
                rect: PixelRect {
                    x0: 100,
                    y0: 90,
                    x1: 400,
                    y1: 400,
                },
                threshold: None,
            },
        ];
        for conn in [Connectivity::Four, Connectivity::Eight] {
            for threads in [1, 2] {
                let mut ex = uncapped(conn, threads, true);
                let got = ours(ex.extract(img.view(), 100, &windows).unwrap());
                let want = sorted(reference_blobs(&img, 100, conn, Some(&windows)));
                assert_eq!(got, want, "{conn:?} threads {threads}");
            }
        }
    }

    /// The search's read of what no window covers, both pixel-test widths, every row and
    /// sampled rows, against a pixel by pixel reference: frames of widths round the 64- and
    /// 256-pixel chunks with a few bright pixels anywhere and random windows.
    #[test]
    fn foreground_outside_matches_a_pixel_by_pixel_reference() {
        let mut rng = stereoscope_numeric::SplitMix64::new(17);
        let mut seen = [0usize; 2];
        for trial in 0..400u64 {
            let (w, h) = (40 + (trial % 9) as u32 * 37, 12);
            let mut img = GrayImage::filled(w, h, 20u8).unwrap();
            // A few bright pixels anywhere, except in every third trial (below).
            let scattered = if trial % 3 == 0 { 0 } else { trial % 4 };
            for _ in 0..scattered {
                let (x, y) = (rng.next_u64() % w as u64, rng.next_u64() % h as u64);
                img.as_mut_slice()[(y * w as u64 + x) as usize] = 200;
            }
            let windows: Vec<PixelRect> = (0..(trial % 5))
                .map(|_| {
                    let x0 = (rng.next_u64() % w as u64) as u32;
                    let y0 = (rng.next_u64() % h as u64) as u32;
                    PixelRect {
                        x0,
                        y0,
                        x1: x0 + (rng.next_u64() % 300) as u32,
                        y1: y0 + (rng.next_u64() % 8) as u32,
                    }
                })
                .collect();
            // Every third trial lights only the pixel just past one edge of a window: gaps
            // and bands that are one pixel short fail there.
            // Or only a window's own edge pixel (inside it): a gap read one pixel too wide
            // fails there.
            if let (0, Some(r)) = (trial % 3, windows.first()) {
                let (x, y) = match (trial / 3) % 8 {
                    0 => (r.x1 as i64 + 1, r.y0 as i64),
                    1 => (r.x0 as i64 - 1, r.y0 as i64),
                    2 => (r.x0 as i64, r.y1 as i64 + 1),
                    3 => (r.x0 as i64, r.y0 as i64 - 1),
                    4 => (r.x0 as i64, r.y0 as i64),
                    5 => (r.x1 as i64, r.y0 as i64),
                    6 => (r.x0 as i64, r.y1 as i64),
                    _ => (r.x1 as i64, r.y1 as i64),
                };
                if (0..w as i64).contains(&x) && (0..h as i64).contains(&y) {
                    img.as_mut_slice()[(y * w as i64 + x) as usize] = 200;
                }
            }
            // Every row, or every 2nd or 3rd from a phase (taken modulo the step).
            let rows = RowSample {
                step: 1 + ((trial / 7) % 3) as u32,
                phase: ((trial / 2) % 4) as u32,
            };
            let want = (0..h).any(|y| {
                y % rows.step == rows.phase % rows.step
                    && (0..w).any(|x| {
                        img.as_slice()[(y * w + x) as usize] >= 128
                            && !windows
                                .iter()
                                .any(|r| r.x0 <= x && x <= r.x1 && r.y0 <= y && y <= r.y1)
                    })
            });
            seen[usize::from(want)] += 1;
            let v = img.view();
            assert_eq!(
                any_foreground_outside(&v, 128, &windows, rows),
                want,
                "trial {trial}"
            );
            assert_eq!(
                search::foreground_outside_with::<u8, false>(&v, 128, &windows, rows),
                want,
                "trial {trial}"
            );
        }
        assert!(seen[0] > 50 && seen[1] > 50, "{seen:?}");
    }

    #[test]
    fn matches_flood_fill_in_random_narrow_and_wide_windows() {
        // Widths around the 64- and 128-pixel chunks (the narrow-window paths of one and of
        // two chunks), windows at the right edge (where a 64-pixel read would leave the row),
        // overlapping and apart.
        let mut rng = stereoscope_numeric::SplitMix64::new(99);
        for trial in 0..120u64 {
            let (w, h) = (100 + (trial % 7) as u32 * 25, 70);
            let img = random_image(w, h, 500 + trial, 40);
            let count = 1 + (trial % 4) as usize;
            let windows: Vec<Window> = (0..count)
                .map(|_| {
                    let ww = 1 + (rng.next_u64() % 150) as u32;
                    let hh = 1 + (rng.next_u64() % 40) as u32;
                    let x0 = (rng.next_u64() % w as u64) as u32;
                    let y0 = (rng.next_u64() % h as u64) as u32;
                    let threshold = if rng.uniform() < 0.3 {
                        Some(60 + (rng.next_u64() % 120) as u32)
                    } else {
                        None
                    };
                    Window {
                        rect: PixelRect {
                            x0,
                            y0,
                            x1: x0 + ww - 1,
                            y1: y0 + hh - 1,
                        },
                        threshold,
                    }
                })
                .collect();
            for conn in [Connectivity::Four, Connectivity::Eight] {
                let want = sorted(reference_blobs(&img, 100, conn, Some(&windows)));
                for avx2 in [false, true] {
                    let mut ex = uncapped(conn, 1, avx2);
                    let got = ours(ex.extract(img.view(), 100, &windows).unwrap());
                    assert_eq!(got, want, "trial {trial} {conn:?} avx2 {avx2} {windows:?}");
                }
            }
        }
    }

    /// A tracked blob's rows of one run each in a narrow window (`block`: 8-bit pixels, AVX2,
    /// the grey-level sums kept in vector lanes and added up every 32 rows) give the blobs of
    /// the row-by-row path (SSE2) exactly, moments, boxes, flags and grey-level moments with
    /// and without a cap — and, with weights of the pixel minus 0, the pixel-by-pixel sums:
    /// bars and ellipses up to 190 rows tall and 250 wide at the brightest level, in windows
    /// of every width up to and past 128 and 256 pixels, some at the frame's right edge.
    #[test]
    fn narrow_blocks_sum_tall_bright_blobs_exactly() {
        use crate::raster::{Ellipse, draw_ellipse};
        let (w, h) = (300, 200);
        let mut rng = stereoscope_numeric::SplitMix64::new(1234);
        let mut tall = 0;
        for trial in 0..150u64 {
            let mut img = random_image(w, h, 900 + trial, 0);
            let mut windows = Vec::new();
            for _ in 0..1 + trial % 3 {
                let (bw, bh) = (
                    1 + (rng.next_u64() % 250) as u32,
                    1 + (rng.next_u64() % 190) as u32,
                );
                let x0 = (rng.next_u64() % (w - bw + 1) as u64) as u32;
                let y0 = (rng.next_u64() % (h - bh + 1) as u64) as u32;
                if rng.next_u64().is_multiple_of(2) {
                    for y in y0..y0 + bh {
                        for x in x0..x0 + bw {
                            let v = if rng.next_u64().is_multiple_of(3) {
                                255
                            } else {
                                100 + (rng.next_u64() % 156) as u8
                            };
                            img.set(x, y, v);
                        }
                    }
                } else {
                    let e = Ellipse {
                        cx_px: x0 as f64 + bw as f64 / 2.0,
                        cy_px: y0 as f64 + bh as f64 / 2.0,
                        semi_major: bh as f64 / 2.0,
                        semi_minor: (bw as f64 / 2.0).min(bh as f64 / 2.0),
                        angle_deg: 80.0 + 20.0 * rng.uniform(),
                    };
                    draw_ellipse(&mut img, &e, 1.0, 10.0, 255.0, 4);
                }
                let m = (rng.next_u64() % 8) as u32;
                let right = if rng.next_u64().is_multiple_of(4) {
                    w - 1
                } else {
                    (x0 + bw - 1 + m).min(w - 1)
                };
                windows.push(Window::new(PixelRect {
                    x0: x0.saturating_sub(m),
                    y0: y0.saturating_sub(m),
                    x1: right,
                    y1: (y0 + bh - 1 + m).min(h - 1),
                }));
            }
            for conn in [Connectivity::Four, Connectivity::Eight] {
                for weighting in [
                    Weighting::Binary,
                    Weighting::Intensity { background: 0 },
                    Weighting::Intensity { background: 60 },
                    Weighting::Coverage {
                        background: 40,
                        full: 180,
                    },
                ] {
                    let cfg = ExtractConfig {
                        connectivity: conn,
                        weighting,
                        max_blobs: 1 << 20,
                        ..Default::default()
                    };
                    let mut rows = Extractor::new(cfg);
                    rows.use_avx2(false);
                    let want = rows.extract(img.view(), 100, &windows).unwrap().to_vec();
                    let mut vectors = Extractor::new(cfg);
                    vectors.use_avx2(true);
                    let got = vectors.extract(img.view(), 100, &windows).unwrap();
                    assert_eq!(got, &want[..], "trial {trial} {conn:?} {weighting:?}");
                    if weighting == (Weighting::Intensity { background: 0 }) {
                        let refs = reference_weighted_blobs(&img, 100, conn, Some(&windows), 0);
                        for b in got {
                            let r = refs.iter().find(|(r, _)| r.0 == b.moments && r.1 == b.bbox);
                            assert_eq!(r.map(|r| r.1), b.weighted, "trial {trial} {conn:?}");
                            tall += (b.bbox.height() > 64) as usize;
                        }
                    }
                }
            }
        }
        assert!(tall > 100, "only {tall} blobs taller than 64 rows");
    }

    /// Windows are scanned in clusters of windows that touch: two windows side by side, one
    /// above the other or corner to corner with no pixel between them are one region (a blob
    /// crossing from one into the other is one blob, unclipped there); one pixel apart, two.
    /// Against the flood fill of the windows' union, with several clusters in one frame, and
    /// the blobs in raster order of their first pixel.
    /// Discs and bars of bright pixels (200–249) of every size up to the frame's, on a dim
    /// background (0–89) with a sprinkle of bright pixels: rows of one long run, of several,
    /// and runs ending at any column.
    fn shapes_image(w: u32, h: u32, seed: u64) -> GrayImage<u8> {
        let mut rng = stereoscope_numeric::SplitMix64::new(seed);
        let mut img = random_image(w, h, seed, 1);
        for _ in 0..1 + rng.next_u64() % 6 {
            let (cx, cy) = (
                (rng.next_u64() % w as u64) as i64,
                (rng.next_u64() % h as u64) as i64,
            );
            let (rx, ry) = (
                1 + (rng.next_u64() % (w as u64 / 2)) as i64,
                1 + (rng.next_u64() % (h as u64 / 2)) as i64,
            );
            let bar = rng.next_u64().is_multiple_of(3);
            for y in (cy - ry).max(0)..(cy + ry).min(h as i64) {
                for x in (cx - rx).max(0)..(cx + rx).min(w as i64) {
                    let (dx, dy) = ((x - cx) as f64 / rx as f64, (y - cy) as f64 / ry as f64);
                    if bar || dx * dx + dy * dy <= 1.0 {
                        img.set(x as u32, y as u32, 200 + (rng.next_u64() % 50) as u8);
                    }
                }
            }
        }
        img
    }

    /// Windows of every width, narrow (one or two 64-pixel chunks a row) and wide, over blobs
    /// whose rows are one run longer than 64 pixels, or several: the same blobs as the flood
    /// fill. (A run longer than 64 pixels in a window narrower than 128 once overran the
    /// block sums' table.)
    #[test]
    fn long_runs_in_windows_of_every_width_are_summed_exactly() {
        let (w, h) = (420, 160);
        let mut rng = stereoscope_numeric::SplitMix64::new(97);
        let mut long_runs = 0;
        for trial in 0..160u64 {
            let img = shapes_image(w, h, 500 + trial);
            let windows: Vec<Window> = (0..1 + trial % 3)
                .map(|_| {
                    let ww = 1 + (rng.next_u64() % w as u64) as u32;
                    let hh = 1 + (rng.next_u64() % h as u64) as u32;
                    let x0 = (rng.next_u64() % (w - ww + 1) as u64) as u32;
                    let y0 = (rng.next_u64() % (h - hh + 1) as u64) as u32;
                    Window::new(PixelRect {
                        x0,
                        y0,
                        x1: x0 + ww - 1,
                        y1: y0 + hh - 1,
                    })
                })
                .collect();
            for conn in [Connectivity::Four, Connectivity::Eight] {
                let want = sorted(reference_blobs(&img, 100, conn, Some(&windows)));
                long_runs += want.iter().filter(|(_, b, _)| b.x1 - b.x0 >= 64).count();
                for (threads, avx2) in [(1, false), (1, true), (2, true)] {
                    let mut ex = uncapped(conn, threads, avx2);
                    let blobs = ex.extract(img.view(), 100, &windows).unwrap();
                    let got = ours(blobs);
                    assert_eq!(
                        got, want,
                        "trial {trial} {conn:?} {threads} avx2 {avx2} {windows:?}"
                    );
                }
            }
        }
        assert!(
            long_runs > 100,
            "only {long_runs} blobs wider than 64 pixels"
        );
    }

    #[test]
    fn touching_windows_are_one_region_and_windows_apart_are_scanned_apart() {
        let mut rng = stereoscope_numeric::SplitMix64::new(31);
        let mut crossing = 0;
        for trial in 0..240u64 {
            let (w, h) = (140, 100);
            let img = random_image(w, h, 7000 + trial, 55);
            let gap = (trial % 2) as u32;
            // Beside (right), below, corner below-right, corner below-left.
            let dir = (trial / 2) % 4;
            let (ww, hh) = (
                1 + (rng.next_u64() % 40) as u32,
                1 + (rng.next_u64() % 30) as u32,
            );
            let (x0, y0) = (
                45 + (rng.next_u64() % 10) as u32,
                5 + (rng.next_u64() % 10) as u32,
            );
            let a = PixelRect {
                x0,
                y0,
                x1: x0 + ww - 1,
                y1: y0 + hh - 1,
            };
            let (bw, bh) = (
                1 + (rng.next_u64() % 40) as u32,
                1 + (rng.next_u64() % 30) as u32,
            );
            let (bx0, by0) = match dir {
                0 => (a.x1 + 1 + gap, a.y0 + (rng.next_u64() % hh as u64) as u32),
                1 => (a.x0 + (rng.next_u64() % ww as u64) as u32, a.y1 + 1 + gap),
                2 => (a.x1 + 1 + gap, a.y1 + 1 + gap),
                _ => (a.x0 - gap - bw, a.y1 + 1 + gap),
            };
            let b = PixelRect {
                x0: bx0,
                y0: by0,
                x1: bx0 + bw - 1,
                y1: by0 + bh - 1,
            };
            // A third window far from both: another cluster in the same frame.
            let c = PixelRect {
                x0: 2,
                y0: 70,
                x1: 2 + (rng.next_u64() % 30) as u32,
                y1: 99,
            };
            let windows: Vec<Window> = [b, c, a].into_iter().map(Window::new).collect();
            for conn in [Connectivity::Four, Connectivity::Eight] {
                let want = sorted(reference_blobs(&img, 100, conn, Some(&windows)));
                let apart = sorted(
                    [&windows[0..1], &windows[1..2], &windows[2..3]]
                        .into_iter()
                        .flat_map(|one| reference_blobs(&img, 100, conn, Some(one)))
                        .collect(),
                );
                if gap == 0 && want != apart {
                    crossing += 1;
                }
                for avx2 in [false, true] {
                    let mut ex = uncapped(conn, 1, avx2);
                    let blobs = ex.extract(img.view(), 100, &windows).unwrap();
                    assert!(blobs.is_sorted_by_key(|b| b.first_pixel), "trial {trial}");
                    let got = ours(blobs);
                    assert_eq!(got, want, "trial {trial} {conn:?} avx2 {avx2} {windows:?}");
                }
            }
        }
        // The touching cases really had blobs crossing between the windows.
        assert!(crossing > 100, "only {crossing} cases with a blob crossing");
    }

    /// The tracking windows' inner loop (a blob's rows summed as a block) and both pixel-test
    /// widths against the flood fill: ellipses of radius 2–14 px in windows up to 150 px wide,
    /// some cutting them, some overlapping, at the frame's edges too; and a blob the window
    /// holds whole gets the very moments (binary and grey-level) of the full-frame pass; every
    /// blob's grey-level moments equal the flood fill's, pixel by pixel.
    #[test]
    fn tracking_windows_over_ellipses_match_flood_fill_with_either_vector_width() {
        use crate::raster::{Ellipse, draw_ellipse};
        let mut rng = stereoscope_numeric::SplitMix64::new(5);
        let (mut whole, mut weighed) = (0, 0);
        for trial in 0..120u64 {
            let (w, h) = (160 + (trial % 5) as u32 * 17, 120);
            let mut img = GrayImage::filled(w, h, 10u8).unwrap();
            let mut windows = Vec::new();
            for _ in 0..1 + trial % 4 {
                let r = 2.0 + 12.0 * rng.uniform();
                let (cx, cy) = (rng.uniform() * w as f64, rng.uniform() * h as f64);
                let e = Ellipse {
                    cx_px: cx,
                    cy_px: cy,
                    semi_major: r,
                    semi_minor: r * (0.4 + 0.6 * rng.uniform()),
                    angle_deg: 180.0 * rng.uniform(),
                };
                draw_ellipse(&mut img, &e, 1.0, 10.0, 210.0, 4);
                let half = 5 + (rng.next_u64() % 70) as u32;
                let jitter = (rng.uniform() - 0.5) * r;
                windows.push(Window::new(crate::tracker::clamp_window(
                    cx + jitter,
                    cy - jitter,
                    half,
                    w,
                    h,
                )));
            }
            for conn in [Connectivity::Four, Connectivity::Eight] {
                let want = sorted(reference_blobs(&img, 100, conn, Some(&windows)));
                for avx2 in [false, true] {
                    for weighting in [Weighting::Binary, Weighting::Intensity { background: 10 }] {
                        let cfg = ExtractConfig {
                            connectivity: conn,
                            weighting,
                            ..Default::default()
                        };
                        let mut ex = Extractor::new(cfg);
                        ex.use_avx2(avx2);
                        let got = ex.extract(img.view(), 100, &windows).unwrap().to_vec();
                        assert_eq!(ours(&got), want, "trial {trial} {conn:?} avx2 {avx2}");
                        if let Weighting::Intensity { background } = weighting {
                            // Grey-level moments pixel by pixel, blob for blob.
                            let refs = reference_weighted_blobs(
                                &img,
                                100,
                                conn,
                                Some(&windows),
                                background,
                            );
                            for b in &got {
                                let r =
                                    refs.iter().find(|(r, _)| r.0 == b.moments && r.1 == b.bbox);
                                assert_eq!(
                                    r.map(|r| r.1),
                                    b.weighted,
                                    "trial {trial} {conn:?} avx2 {avx2}"
                                );
                                weighed += 1;
                            }
                        }
                        let mut full = Extractor::new(cfg);
                        full.use_avx2(!avx2);
                        let all = full.extract(img.view(), 100, &[]).unwrap();
                        for b in got.iter().filter(|b| !b.flags.contains(BlobFlags::CLIPPED)) {
                            let same = all.iter().find(|a| a.first_pixel == b.first_pixel);
                            assert_eq!(same, Some(b), "trial {trial} {conn:?} avx2 {avx2}");
                            whole += 1;
                        }
                    }
                }
            }
        }
        assert!(whole > 200, "{whole} whole blobs compared");
        assert!(
            weighed > 200,
            "{weighed} blobs' grey-level moments compared"
        );
    }

    #[test]
    fn windowed_blob_equals_full_frame_blob_and_is_counted_once() {
        let mut img = GrayImage::filled(100, 80, 10u8).unwrap();
        for y in 30..41 {
            for x in 40..61 {
                img.set(x, y, 200);
            }
        }
        let mut ex = Extractor::new(ExtractConfig::default());
        let full = ex.extract(img.view(), 100, &[]).unwrap().to_vec();
        assert_eq!(full.len(), 1);
        // Two overlapping windows both covering the whole blob: one blob, same moments.
        let windows = [
            Window::new(PixelRect {
                x0: 30,
                y0: 20,
                x1: 65,
                y1: 50,
            }),
            Window::new(PixelRect {
                x0: 35,
                y0: 25,
                x1: 70,
                y1: 60,
            }),
        ];
        let win = ex.extract(img.view(), 100, &windows).unwrap().to_vec();
        assert_eq!(win.len(), 1);
        assert_eq!(win[0].moments, full[0].moments);
        assert_eq!(win[0].flags, BlobFlags::default());
        // A window cutting the blob flags it clipped.
        let cut = ex
            .extract(
                img.view(),
                100,
                &[Window::new(PixelRect {
                    x0: 45,
                    y0: 20,
                    x1: 70,
                    y1: 60,
                })],
            )
            .unwrap();
        assert_eq!(cut.len(), 1);
        assert!(cut[0].flags.contains(BlobFlags::CLIPPED));
        assert_eq!(cut[0].area_px(), 16 * 11);
        let cut = ex
            .extract(
                img.view(),
                100,
                &[Window::new(PixelRect {
                    x0: 0,
                    y0: 35,
                    x1: 99,
                    y1: 79,
                })],
            )
            .unwrap();
        assert!(cut[0].flags.contains(BlobFlags::CLIPPED));
    }

    #[test]
    fn translation_changes_centroid_only() {
        let mut a = GrayImage::filled(64, 64, 0u8).unwrap();
        let mut b = GrayImage::filled(64, 64, 0u8).unwrap();
        let shape = [
            (3, 1),
            (4, 1),
            (2, 2),
            (3, 2),
            (4, 2),
            (5, 2),
            (3, 3),
            (6, 3),
            (7, 4),
        ];
        for &(x, y) in &shape {
            a.set(x + 10, y + 10, 255);
            b.set(x + 37, y + 29, 255);
        }
        let mut ex = Extractor::new(ExtractConfig::default());
        let ba = ex.extract(a.view(), 128, &[]).unwrap()[0];
        let bb = ex.extract(b.view(), 128, &[]).unwrap()[0];
        assert_eq!(ba.area_px(), bb.area_px());
        assert_eq!(ba.central(), bb.central());
        let (ca, cb) = (ba.centroid_px(), bb.centroid_px());
        assert!((cb.0 - ca.0 - 27.0).abs() < 1e-12 && (cb.1 - ca.1 - 19.0).abs() < 1e-12);
    }

    #[test]
    fn border_capacity_and_area_filter_are_reported() {
        let mut img = GrayImage::filled(50, 40, 0u8).unwrap();
        // A blob on the left border, three of area 4, six single pixels.
        for y in 5..10 {
            img.set(0, y, 255);
            img.set(1, y, 255);
        }
        for i in 0..3 {
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                img.set(10 + 8 * i + dx, 20 + dy, 255);
            }
        }
        for i in 0..6 {
            img.set(5 + 7 * i, 35, 255);
        }
        let mut ex = Extractor::new(ExtractConfig {
            min_area_px: 2,
            max_blobs: 3,
            ..Default::default()
        });
        let blobs = ex.extract(img.view(), 1, &[]).unwrap();
        assert_eq!(blobs.len(), 3);
        assert_eq!(blobs[0].area_px(), 10, "largest kept, raster order");
        assert!(blobs[0].flags.contains(BlobFlags::TOUCHES_BORDER));
        // Of the three of area 4, the first two in raster order are kept (ties at the cut).
        let kept: Vec<_> = blobs[1..].iter().map(|b| b.first_pixel).collect();
        assert_eq!(kept, [(20, 10), (20, 18)]);
        let s = ex.stats();
        assert_eq!(s.regions, 10);
        assert_eq!(s.below_min_area, 6);
        assert_eq!(s.dropped_over_capacity, 1);
    }

    #[test]
    fn coverage_weights_give_the_silhouette_not_the_lit_side() {
        // A disc of radius 8, 80 levels bright at its rim, with a highlight off-centre (a lit
        // ball): grey-level weights pull the centroid to the highlight; coverage weights,
        // saturating below the rim's level, give the silhouette.
        let (cx, cy, r) = (40.3, 30.6, 8.0);
        let mut img = GrayImage::filled(80, 60, 20u8).unwrap();
        let n = 16;
        for y in 0..60u32 {
            for x in 0..80u32 {
                let mut cov = 0.0;
                for j in 0..n {
                    for i in 0..n {
                        let (sx, sy) = (
                            x as f64 - 0.5 + (i as f64 + 0.5) / n as f64,
                            y as f64 - 0.5 + (j as f64 + 0.5) / n as f64,
                        );
                        if (sx - cx).powi(2) + (sy - cy).powi(2) <= r * r {
                            cov += 1.0 / (n * n) as f64;
                        }
                    }
                }
                let d2 = (x as f64 - cx - 3.0).powi(2) + (y as f64 - cy).powi(2);
                let shade = 80.0 + 100.0 * (-d2 / 8.0).exp();
                img.set(x, y, (20.0 + cov * shade).round() as u8);
            }
        }
        let mut intensity = Extractor::new(ExtractConfig {
            weighting: Weighting::Intensity { background: 20 },
            ..Default::default()
        });
        let bi = intensity.extract(img.view(), 25, &[]).unwrap()[0];
        let mut coverage = Extractor::new(ExtractConfig {
            weighting: Weighting::Coverage {
                background: 20,
                full: 100,
            },
            ..Default::default()
        });
        let bc = coverage.extract(img.view(), 25, &[]).unwrap()[0];
        let (ix, _) = bi.best_centroid_px();
        let (kx, ky) = bc.best_centroid_px();
        assert!(ix - cx > 0.2, "grey-level centroid {ix} should lean right");
        assert!(
            (kx - cx).abs() < 0.05 && (ky - cy).abs() < 0.05,
            "coverage centroid ({kx}, {ky})"
        );
        let area = bc.weighted.unwrap().w00 as f64 / 80.0;
        let truth = std::f64::consts::PI * r * r;
        assert!(
            (area - truth).abs() / truth < 0.02,
            "area {area} vs {truth}"
        );
        let mut bad = Extractor::new(ExtractConfig {
            weighting: Weighting::Coverage {
                background: 30,
                full: 60,
            },
            ..Default::default()
        });
        assert!(bad.extract(img.view(), 25, &[]).is_err());
    }

    /// A disc of `r` px at `(cx, cy)`: coverage × 100 above a background of 20 (16 × 16
    /// samples a pixel).
    fn small_disc(cx: f64, cy: f64, r: f64) -> GrayImage<u8> {
        let mut img = GrayImage::filled(24, 24, 20u8).unwrap();
        let n = 16;
        for y in 0..24u32 {
            for x in 0..24u32 {
                let mut cov = 0.0;
                for j in 0..n {
                    for i in 0..n {
                        let sx = x as f64 - 0.5 + (i as f64 + 0.5) / n as f64;
                        let sy = y as f64 - 0.5 + (j as f64 + 0.5) / n as f64;
                        if (sx - cx).powi(2) + (sy - cy).powi(2) <= r * r {
                            cov += 1.0 / (n * n) as f64;
                        }
                    }
                }
                img.set(x, y, (20.0 + cov * 100.0).round() as u8);
            }
        }
        img
    }

    /// The edge ring against its pixel-by-pixel definition: from the left up to the first
    /// pixel at or above the level, from the right back to the last one, `pixel − background`
    /// for each pixel above the background. Random boxes over random 8- and 16-bit frames:
    /// rows with no bright pixel, one, many; boxes at the frame's edges.
    #[test]
    fn the_edge_ring_equals_its_pixel_by_pixel_definition() {
        fn reference<P: Pixel>(
            img: &GrayView<'_, P>,
            bb: PixelRect,
            top: u32,
            background: u32,
        ) -> WeightedMoments {
            let mut wm = WeightedMoments::default();
            let (w, h) = (img.width(), img.height());
            let (x0, x1) = (bb.x0.saturating_sub(1), (bb.x1 + 1).min(w - 1));
            let (y0, y1) = (bb.y0.saturating_sub(1), (bb.y1 + 1).min(h - 1));
            for y in y0..=y1 {
                let row: Vec<u32> = (x0..=x1).map(|x| img.row(y)[x as usize].value()).collect();
                let first = row.iter().position(|&v| v >= top).unwrap_or(row.len());
                let last = row.iter().rposition(|&v| v >= top);
                let (mut sw, mut swx, mut swxx) = (0u64, 0u64, 0u64);
                for (i, &v) in row.iter().enumerate() {
                    let outside = i < first || last.is_some_and(|l| i > l);
                    if outside && v > background {
                        let x = x0 as u64 + i as u64;
                        let wt = (v - background) as u64;
                        sw += wt;
                        swx += wt * x;
                        swxx += wt * x * x;
                    }
                }
                if sw > 0 {
                    wm.add_row_sums(sw, swx, swxx, y);
                }
            }
            wm
        }
        fn check<P: Pixel>(img: &GrayView<'_, P>, rng: &mut stereoscope_numeric::SplitMix64) {
            let (w, h) = (img.width(), img.height());
            for _ in 0..400 {
                let x0 = (rng.next_u64() % w as u64) as u32;
                let y0 = (rng.next_u64() % h as u64) as u32;
                let bb = PixelRect {
                    x0,
                    y0,
                    x1: (x0 + (rng.next_u64() % 140) as u32).min(w - 1),
                    y1: (y0 + (rng.next_u64() % 90) as u32).min(h - 1),
                };
                let max = P::MAX_VALUE as u64;
                let background = (rng.next_u64() % (max / 2)) as u32;
                let threshold = background + 1 + (rng.next_u64() % (max / 2)) as u32;
                let full = threshold + (rng.next_u64() % (max / 4)) as u32;
                let blob = Blob {
                    moments: RawMoments::default(),
                    bbox: bb,
                    flags: BlobFlags::default(),
                    weighted: Some(WeightedMoments::default()),
                    first_pixel: (bb.y0, bb.x0),
                };
                let want = reference(img, bb, threshold.min(full), background);
                for avx2 in [false, true] {
                    let mut blob = blob;
                    edge_rings(
                        std::slice::from_mut(&mut blob),
                        img,
                        (threshold, background, full),
                        &[],
                        avx2 && cpu_has_avx2(),
                    );
                    assert_eq!(
                        blob.weighted,
                        Some(want),
                        "{bb:?} {background} {threshold} {full} avx2 {avx2}"
                    );
                }
            }
        }
        let mut rng = stereoscope_numeric::SplitMix64::new(404);
        // 150 pixels wide: boxes of one mask, of several, at the right edge; 50: a frame
        // narrower than one mask. Boxes up to 92 rows (the vector sums add their lanes up
        // every 32).
        for (density, width) in [0, 3, 30, 90, 100]
            .into_iter()
            .flat_map(|d| [(d, 150), (d, 50)])
        {
            let img8 = random_image(width, 100, 77 + density as u64, density);
            check(&img8.view(), &mut rng);
            let data: Vec<u16> = img8
                .as_slice()
                .iter()
                .map(|&p| (p as u16 * 257) ^ (rng.next_u64() as u16 & 0xff))
                .collect();
            let img16 = GrayImage::from_vec(data, width, 100).unwrap();
            check(&img16.view(), &mut rng);
        }
    }

    #[test]
    fn a_small_markers_coverage_centroid_counts_its_dim_edge_pixels() {
        // A marker of radius 2.5 px, threshold at half coverage: the edge pixels covered by
        // less than half are below it. Left out, they pulled the centroid up to ~0.1 px
        // towards the pixel grid as the marker moved across a pixel.
        let mut ex = Extractor::new(ExtractConfig {
            weighting: Weighting::Coverage {
                background: 20,
                full: 120,
            },
            ..Default::default()
        });
        let mut worst: f64 = 0.0;
        for k in 0..10 {
            let (cx, cy) = (11.0 + 0.1 * k as f64, 12.0 + 0.07 * k as f64);
            let img = small_disc(cx, cy, 2.5);
            let blobs = ex.extract(img.view(), 70, &[]).unwrap();
            assert_eq!(blobs.len(), 1);
            let (x, y) = blobs[0].best_centroid_px();
            worst = worst.max((x - cx).abs()).max((y - cy).abs());
            // The binary area is untouched: pixels at or above the threshold.
            assert_eq!(
                blobs[0].area_px(),
                img.as_slice().iter().filter(|&&p| p >= 70).count() as u64
            );
        }
        assert!(worst < 0.01, "worst centroid error {worst} px");
    }

    #[test]
    fn bad_input_gets_typed_errors() {
        let img = GrayImage::filled(20, 10, 0u8).unwrap();
        let mut ex = Extractor::new(ExtractConfig::default());
        assert!(matches!(
            ex.extract(img.view(), 256, &[]),
            Err(VisionError::ThresholdOutOfRange {
                threshold: 256,
                bits: 8,
                ..
            })
        ));
        let empty = Window::new(PixelRect {
            x0: 5,
            y0: 5,
            x1: 4,
            y1: 6,
        });
        assert!(matches!(
            ex.extract(img.view(), 10, &[empty]),
            Err(VisionError::EmptyWindow { index: 0, .. })
        ));
        let outside = Window::new(PixelRect {
            x0: 25,
            y0: 0,
            x1: 30,
            y1: 5,
        });
        let ok = Window::new(PixelRect {
            x0: 0,
            y0: 0,
            x1: 3,
            y1: 3,
        });
        assert!(matches!(
            ex.extract(img.view(), 10, &[ok, outside]),
            Err(VisionError::WindowOutsideFrame { index: 1, .. })
        ));
        let bad_thr = Window {
            rect: PixelRect {
                x0: 0,
                y0: 0,
                x1: 3,
                y1: 3,
            },
            threshold: Some(300),
        };
        assert!(matches!(
            ex.extract(img.view(), 10, &[bad_thr]),
            Err(VisionError::ThresholdOutOfRange { threshold: 300, .. })
        ));
        // A window reaching past the frame is clipped, not an error.
        let past = Window::new(PixelRect {
            x0: 15,
            y0: 5,
            x1: 1000,
            y1: 1000,
        });
        assert!(ex.extract(img.view(), 10, &[past]).is_ok());
        let mut wex = Extractor::new(ExtractConfig {
            weighting: Weighting::Intensity { background: 50 },
            ..Default::default()
        });
        assert!(matches!(
            wex.extract(img.view(), 50, &[]),
            Err(VisionError::BackgroundNotBelowThreshold { .. })
        ));
        // 16-bit frames take thresholds up to 65535.
        let img16 = GrayImage::filled(20, 10, 1000u16).unwrap();
        assert_eq!(ex.extract(img16.view(), 65535, &[]).unwrap().len(), 0);
        assert_eq!(ex.extract(img16.view(), 1000, &[]).unwrap().len(), 1);
        assert!(ex.extract(img16.view(), 65536, &[]).is_err());
    }

    #[test]
    fn sixteen_bit_and_strided_views_match_eight_bit() {
        let img8 = random_image(150, 70, 9, 30);
        let padded: Vec<u16> = (0..70u32)
            .flat_map(|y| {
                let row: Vec<u16> = img8
                    .view()
                    .row(y)
                    .iter()
                    .map(|&p| p as u16 * 256 + 7)
                    .collect();
                row.into_iter().chain(std::iter::repeat_n(65535u16, 13))
            })
            .collect();
        let v16 = GrayView::new(&padded, 150, 70, 163).unwrap();
        let mut ex = Extractor::new(ExtractConfig {
            max_blobs: 1 << 20,
            ..Default::default()
        });
        let a = ours(ex.extract(img8.view(), 100, &[]).unwrap());
        let b = ours(ex.extract(v16, 100 * 256, &[]).unwrap());
        assert_eq!(a, b);
    }

    #[test]
    fn long_runs_cross_simd_chunks() {
        // Runs that start, end and continue across 64-pixel chunk edges.
        let mut img = GrayImage::filled(300, 3, 0u8).unwrap();
        for x in 60..200 {
            img.set(x, 1, 255);
        }
        for x in 0..300 {
            img.set(x, 0, if x % 70 < 64 { 255 } else { 0 });
        }
        let mut ex = Extractor::new(ExtractConfig {
            connectivity: Connectivity::Four,
            ..Default::default()
        });
        let got = ours(ex.extract(img.view(), 128, &[]).unwrap());
        let want = sorted(reference_blobs(&img, 128, Connectivity::Four, None));
        assert_eq!(got, want);
    }
}
