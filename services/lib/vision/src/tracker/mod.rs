//! Self-adaptive tracking windows for several objects.
//!
//! Thesis: chapter 5, Eq. 5.1–5.3 and steps 1–5 (`auto_tracking_and_resizing_window`):
//!
//! 1. window half-width = MagicFactor (2.3) · √area (Eq. 5.1; the code uses it as the half-width
//!    `ax`), with a floor (`HalfofWidth`, 30 px at 320×240);
//! 2. centred on the object (Eq. 5.2) — here on its *predicted* position;
//! 3. the motion `new − old` (Eq. 5.3) — computed by the thesis but never used by its code; here
//!    it drives a constant-velocity prediction;
//! 4. when the object is lost, the window doubles (the code jumped straight to the full frame)
//!    each lost frame, still moving with the prediction, until it covers the frame: then the
//!    whole frame is searched to reacquire;
//! 5. the window is shifted back inside the frame (and clipped if it is larger).
//!
//! Several objects: all windows are extracted in one call over their union, so a pixel in two
//! windows counts once, and blobs are given to tracks by a global minimum-cost assignment
//! (distance to the prediction, gated by the track's window), so two tracks never share a blob.
//! Each object keeps its id while tracked or lost; ids are never reused. New objects are taken
//! only from full-frame searches, which run while no object is tracked, when a lost object's
//! window has grown to the frame, and every `search_every_frames` frames while fewer than
//! `max_objects` are tracked. A search (periodic, or a lost object's) first reads the frame for
//! any foreground pixel outside the cores, then outside the other windows
//! ([`crate::extract::any_foreground_outside`],
//! about a tenth of the cost of labelling it, and of every `search_row_step`-th row only — a
//! lost object's search, on every frame, of every other of those — from a row that moves at
//! each search); with none, the cores' (or the windows') union holds every blob of the
//! frame, so the windowed step stands for the search (new objects are taken from it) and the
//! frame is not labelled whole.
//!
//! A lost object inside another's merged blob (two markers whose images joined: it is there,
//! not anywhere else) rests instead: no window of its own is read and the frame is not searched
//! for it but on each search period's first frame, as for new objects. It is predicted where it
//! went into the merged blob, moved with that blob, and competes in the assignment for the
//! blobs whose centroids lie in the merged track's core — once one of them is no other found
//! track's nearest (its image come out of the merged one): the assignment then decides which
//! parted image is whose, so it is followed again from the first frame the two images part,
//! under its id, and no other lost track takes its image. A merge lasts while a lost track is
//! inside it. (Searching the frame for it on every frame cost the live bench's markers more
//! than all else: one of 12 was inside another's blob on 26 of 120 frames,
//! docs/performance.md.)
//!
//! The windowed step reads each object found in the last frame in its core first (its last box
//! moved by its motion, widened), and the whole windows only when the cores do not settle the
//! frame: the same tracks for a fifth of the reads ([`CoreScan`]).
//!
//! Pixel conventions: `docs/conventions.md`.

use crate::error::VisionError;
use crate::extract::{
    Blob, BlobFlags, ExtractConfig, ExtractStats, Extractor, RowSample, Window,
    any_foreground_outside,
};
use crate::histogram::{Histogram, ThresholdMethod};
use crate::image::{GrayView, Pixel, PixelRect};
use crate::moments::{AxisShape, CentralMoments, directed_angle_deg, validate_par};
use stereoscope_numeric::heading::{HeadingConfig, HeadingTracker, HeadingUpdate};
use stereoscope_numeric::{Assigner, cheapest_allowed};

mod cores;
mod merged;
pub use cores::{CORE_MARGIN_PX, CoreScan};
pub use merged::{MERGE_AREA_RATIO, MERGE_KEEP_RATIO, MERGE_SHARE};

/// The periodic search's test reads one row in `height / this` by default, at least every 2nd
/// ([`TrackerConfig::search_row_step`]).
pub const SEARCH_ROWS_AT_LEAST: u32 = 540;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackerConfig {
    /// Eq. 5.1's MagicFactor.
    pub magic_factor: f64,
    /// Floor of the window half-width, pixels (the thesis's `HalfofWidth`).
    pub min_half_width_px: u32,
    /// How many objects to track at most.
    pub max_objects: usize,
    /// While fewer than `max_objects` are tracked, search the full frame every this many frames
    /// for new ones (1 = every frame).
    pub search_every_frames: u32,
    /// The periodic search's test for foreground outside the windows reads every this many
    /// rows, from a row that moves by one at each search: an object at least this many rows
    /// tall is found at the first search it is in, a shorter one `t` rows tall within
    /// `step − t + 1` searches. `None`: one row in `height / 540`, at least every 2nd (every
    /// 2nd up to 1619 rows, every 3rd from 1620, every 4th at 4K): every object of two rows
    /// or more — any that can start a track but a one-row streak — is found at the first
    /// search it is in. The frame is still labelled whole when the test finds some.
    ///
    /// A lost object's search, which runs on every frame while its window covers the frame,
    /// reads every `2 × step`-th row from a row that moves by one each frame: two frames
    /// read as many rows as one periodic search. An object `2 × step` rows tall (4 by
    /// default: a marker of 13 px or more) is found at the first frame it shows, a shorter
    /// one `t` rows tall within `2 × step − t + 1` frames; a hidden object (two markers
    /// crossing, one inside the other's blob) costs half the reads on each frame it stays
    /// hidden.
    pub search_row_step: Option<u32>,
    /// A track lost for more than this many frames is dropped.
    pub drop_after_lost_frames: u32,
    /// Smallest blob that starts a new track, pixels.
    pub min_new_area_px: u64,
    /// Pixel aspect ratio (pixel width / pixel height) for orientation.
    pub par: f64,
    pub heading: HeadingConfig,
    /// Minimum normalised skewness to trust a third-order direction; `None` disables it.
    pub direction_min_skewness: Option<f64>,
    /// Threshold each window from its own histogram with this method (the thesis's
    /// `region.thres`); `None` uses the frame threshold everywhere.
    pub window_threshold: Option<ThresholdMethod>,
    /// Read each object found in the last frame in its core first — its last box moved by its
    /// motion and widened by a margin, inside its window — and the whole Eq. 5.1 windows only
    /// when the cores do not settle the frame ([`CoreScan`]). `false`: always the windows.
    pub core_scan: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            magic_factor: 2.3,
            min_half_width_px: 30,
            max_objects: 4,
            search_every_frames: 10,
            search_row_step: None,
            drop_after_lost_frames: 60,
            min_new_area_px: 4,
            par: 1.0,
            heading: HeadingConfig::default(),
            direction_min_skewness: Some(0.2),
            window_threshold: None,
            core_scan: true,
        }
    }
}

impl TrackerConfig {
    pub fn validate(&self) -> Result<(), VisionError> {
        let bad = |field, value: f64, reason| {
            Err(VisionError::InvalidTrackerConfig {
                field,
                value,
                reason,
            })
        };
        if !(self.magic_factor.is_finite() && self.magic_factor > 0.0) {
            return bad(
                "magic_factor",
                self.magic_factor,
                "must be a finite number above zero",
            );
        }
        if self.max_objects == 0 {
            return bad("max_objects", 0.0, "must be at least 1");
        }
        if self.search_every_frames == 0 {
            return bad("search_every_frames", 0.0, "must be at least 1");
        }
        if self.search_row_step == Some(0) {
            return bad("search_row_step", 0.0, "must be at least 1");
        }
        if !(self.heading.ambiguous_step_deg > 0.0 && self.heading.ambiguous_step_deg < 90.0) {
            return bad(
                "heading.ambiguous_step_deg",
                self.heading.ambiguous_step_deg,
                "must be in (0, 90)",
            );
        }
        validate_par(self.par)?;
        Ok(())
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackStatus {
    /// Found this frame for the first time.
    New,
    /// Found this frame in its window.
    Tracked,
    /// Not found this frame; its window is growing.
    Lost,
}

/// One tracked object.
#[derive(Debug, Clone)]
pub struct Track {
    pub id: u32,
    pub status: TrackStatus,
    /// Last measured centroid (intensity-weighted when the extractor computes weights), pixels.
    pub x_px: f64,
    pub y_px: f64,
    /// Motion per frame (Eq. 5.3).
    pub vx_px: f64,
    pub vy_px: f64,
    pub area_px: u64,
    /// The track's usual area: a running mean of its unmerged blobs' areas, pixels.
    pub usual_area_px: f64,
    /// This frame's blob holds another object's image too (`MERGE_AREA_RATIO`): its centroid
    /// is between the two and is not a measurement of either.
    pub merged: bool,
    /// Lost inside the merged blob of the track with this id ([`Track::merged`]: that blob
    /// holds the place where this one was last seen or is predicted): its image is there,
    /// joined to the other's. Its window is read, and the frame searched for it, on the first
    /// frame of each search period only; between, it competes only for the blobs in that
    /// track's core, and only once one of them is no found track's nearest (its image come
    /// out of the merged one), module docs.
    pub inside_merged: Option<u32>,
    /// This step left the track's own window unread (inside a merged blob and no search due):
    /// it competes in the assignment for the blobs in its host's window only.
    resting: bool,
    /// Where it was, from the merged track's centroid, when it went inside that track's blob:
    /// while inside, it is predicted there from the merged track's prediction (its own motion,
    /// run on over the frames it is hidden, would take it away from where it comes back out).
    merge_offset_px: (f64, f64),
    /// The window searched this frame.
    pub window: PixelRect,
    pub lost_frames: u32,
    /// This frame's blob, when found.
    pub blob: Option<Blob>,
    /// That blob's central moments and axes ([`Blob::best_central`], Eq. 3.44 at the
    /// tracker's `par`), as the heading took them: `Some` exactly when `blob` is.
    pub shape: Option<BlobShape>,
    /// Continuous heading 0–360°.
    pub heading: HeadingUpdate,
    heading_tracker: HeadingTracker,
}

/// A blob's second moments and the axes they give (Eq. 3.41–3.44), computed once a step for
/// the heading and kept for whoever reports the blob.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlobShape {
    pub central: CentralMoments,
    pub axis: AxisShape,
}

impl Track {
    fn predicted(&self) -> (f64, f64) {
        let k = (self.lost_frames + 1) as f64;
        (self.x_px + self.vx_px * k, self.y_px + self.vy_px * k)
    }

    /// Found this frame in blob `b` (centroid `(bx, by)`): the motion (Eq. 5.3, over the
    /// frames it was lost), its place, area and heading.
    fn take(&mut self, b: &Blob, (bx, by): (f64, f64), par: f64, skew: Option<f64>) {
        let k = (self.lost_frames + 1) as f64;
        self.vx_px = (bx - self.x_px) / k;
        self.vy_px = (by - self.y_px) / k;
        self.x_px = bx;
        self.y_px = by;
        self.area_px = b.area_px();
        self.lost_frames = 0;
        self.status = TrackStatus::Tracked;
        let (heading, shape) = heading_of(&mut self.heading_tracker, b, par, skew);
        self.heading = heading;
        self.shape = Some(shape);
        self.blob = Some(*b);
    }

    /// Not found this frame.
    fn lose(&mut self) {
        self.lost_frames += 1;
        self.status = TrackStatus::Lost;
        self.blob = None;
        self.shape = None;
    }
}

/// What one tracking step did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TrackStep {
    /// The frame was searched for new objects: labelled whole, or read by the search's test
    /// (its rows, [`TrackerConfig::search_row_step`]) and found to hold nothing outside the
    /// windows.
    pub full_frame: bool,
    pub extract: ExtractStats,
    pub tracked: usize,
    pub lost: usize,
    pub new: usize,
    pub dropped: usize,
    /// Blobs ignored because their centroid is in a mask rectangle, of those read (a frame
    /// the cores settle reads less than the windows: [`CoreScan`]).
    pub masked: usize,
    /// Whether the cores were read first, and whether they settled the frame.
    pub cores: CoreScan,
}

/// Self-adaptive multi-object tracker over one camera's frames.
#[derive(Debug)]
pub struct Tracker {
    cfg: TrackerConfig,
    extractor: Extractor,
    tracks: Vec<Track>,
    next_id: u32,
    /// The last step's frame number (the caller's, see [`Tracker::step_frame`], or counted).
    last_frame: Option<u64>,
    counted_frames: u64,
    windows: Vec<Window>,
    /// Each track's core ([`CoreScan`]), when it has one.
    core_rects: Vec<Option<PixelRect>>,
    /// What the cores' step reads: each track's core, or its window when it has none.
    cores: Vec<Window>,
    /// The blobs already some track's nearest, while the cores are checked.
    nearest_taken: Vec<bool>,
    /// Each track's nearest blob, as the cores' check found them: the assignment itself when
    /// they settle the frame ([`Tracker::cores_settle`]).
    nearest: Vec<Option<usize>>,
    cost: Vec<f64>,
    /// This step's blob centroids, for the costs.
    centroids: Vec<(f64, f64)>,
    assigner: Assigner,
    taken: Vec<bool>,
    /// Where blobs are not markers (lamps, reflections): ignored.
    mask: Vec<PixelRect>,
}

/// `c.round() as i64` (halves away from zero, saturating) without the library call that
/// `round` is on the x86-64 baseline.
#[inline]
fn round_half_away(c: f64) -> i64 {
    let i = c as i64;
    let f = c - i as f64;
    if f >= 0.5 {
        i.saturating_add(1)
    } else if f <= -0.5 {
        i.saturating_sub(1)
    } else {
        i
    }
}

/// The window of half-width `half` centred at `(cx, cy)`, shifted inside the frame and clipped
/// if larger (step 5).
pub fn clamp_window(cx: f64, cy: f64, half: u32, width: u32, height: u32) -> PixelRect {
    fn axis(c: f64, half: u32, size: u32) -> (u32, u32) {
        let span = 2 * half as i64 + 1;
        if span >= size as i64 {
            return (0, size - 1);
        }
        let c = if c.is_finite() {
            round_half_away(c)
        } else {
            size as i64 / 2
        };
        let lo = (c - half as i64).clamp(0, size as i64 - span);
        (lo as u32, (lo + span - 1) as u32)
    }
    let (x0, x1) = axis(cx, half, width);
    let (y0, y1) = axis(cy, half, height);
    PixelRect { x0, y0, x1, y1 }
}

impl Tracker {
    pub fn new(cfg: TrackerConfig, extract: ExtractConfig) -> Result<Self, VisionError> {
        cfg.validate()?;
        Ok(Tracker {
            cfg,
            extractor: Extractor::new(extract),
            tracks: Vec::new(),
            next_id: 1,
            last_frame: None,
            counted_frames: 0,
            windows: Vec::new(),
            core_rects: Vec::new(),
            cores: Vec::new(),
            nearest_taken: Vec::new(),
            nearest: Vec::new(),
            cost: Vec::new(),
            centroids: Vec::new(),
            assigner: Assigner::default(),
            taken: Vec::new(),
            mask: Vec::new(),
        })
    }

    /// Rectangles where bright things are not markers (`docs/calibration.md`, "Masks"): a
    /// blob whose centroid is in one is neither followed nor made a new object, and what is
    /// bright there does not force a full-frame search. A few comparisons a blob.
    pub fn set_mask(&mut self, mask: Vec<PixelRect>) {
        self.mask = mask;
    }

    pub fn config(&self) -> &TrackerConfig {
        &self.cfg
    }

    /// The extraction settings (weighting, connectivity, capacity).
    pub fn extract_config(&self) -> &ExtractConfig {
        self.extractor.config()
    }

    /// Changes the extraction settings from the next step on (e.g. new grey-level weights
    /// after a fresh threshold); tracks are kept.
    pub fn set_extract_config(&mut self, cfg: ExtractConfig) {
        self.extractor.set_config(cfg);
    }

    pub fn tracks(&self) -> &[Track] {
        &self.tracks
    }

    /// The windows searched in the last step (empty after a full-frame search).
    pub fn windows(&self) -> &[Window] {
        &self.windows
    }

    /// Eq. 5.1 with the floor and step 4's doubling per lost frame.
    fn half_width(&self, t: &Track, limit: u32) -> u32 {
        let base = (self.cfg.magic_factor * (t.area_px as f64).sqrt()) as u32;
        let base = base.max(self.cfg.min_half_width_px).max(1);
        let grown = base as u64 * (1u64 << t.lost_frames.min(20));
        grown.min(limit as u64) as u32
    }

    /// Tracks one frame: `threshold` is the frame threshold (windows may override it, see
    /// [`TrackerConfig::window_threshold`]). Frames are numbered by the calls.
    pub fn step<P: Pixel>(
        &mut self,
        img: GrayView<'_, P>,
        threshold: u32,
    ) -> Result<TrackStep, VisionError> {
        let frame = self.counted_frames;
        self.counted_frames += 1;
        self.step_frame(img, threshold, frame)
    }

    /// The rects of `windows` and the mask: what a search's test looks outside of — the
    /// windows (nothing there: the windowed step stands for the search) or the cores (nothing
    /// there: the cores do, [`CoreScan`]).
    fn with_mask(&self, windows: &[Window]) -> Vec<PixelRect> {
        windows
            .iter()
            .map(|w| w.rect)
            .chain(self.mask.iter().copied())
            .collect()
    }

    /// The rows the search of frame `frame` (in period `period`) tests, in a frame `height`
    /// rows high: the phase is `period + frame % search_every_frames`, one on from the last
    /// search's both for the periodic searches (on each period's first frame) and for a lost
    /// object's on consecutive frames, and the same for trackers fed the same frames. A lost
    /// object's search alone (`lost_only`: not a periodic one) reads every other row of the
    /// periodic search's step ([`TrackerConfig::search_row_step`]).
    fn search_rows(&self, height: u32, period: u64, frame: u64, lost_only: bool) -> RowSample {
        let step = self
            .cfg
            .search_row_step
            .unwrap_or((height / SEARCH_ROWS_AT_LEAST).max(2))
            .max(1);
        let step = if lost_only {
            step.saturating_mul(2)
        } else {
            step
        };
        let phase = period.wrapping_add(frame % self.cfg.search_every_frames as u64);
        RowSample {
            step,
            phase: (phase % step as u64) as u32,
        }
    }

    /// The assignment's costs for the extractor's blobs: squared distance to each track's
    /// prediction, gated by its window; a masked blob is as good as taken (`taken`): no track
    /// follows it, none starts from it.
    fn fill_costs(&mut self) {
        let blobs = self.extractor.blobs();
        self.cost.clear();
        self.centroids.clear();
        self.centroids
            .extend(blobs.iter().map(|b| b.best_centroid_px()));
        self.taken.clear();
        self.taken.extend(
            self.centroids
                .iter()
                .map(|&(x, y)| self.mask.iter().any(|m| m.contains(x, y))),
        );
        let n = self.centroids.len();
        if n == 0 {
            return;
        }
        // Row by row into a matrix made whole first (no per-element growth checks).
        self.cost.resize(self.tracks.len() * n, f64::INFINITY);
        let tracks = &self.tracks;
        for (t, row) in tracks.iter().zip(self.cost.chunks_exact_mut(n)) {
            // A resting track (inside a merged blob) competes for the blobs in its host's
            // window: its image comes out of the merged one there, and the assignment decides
            // which of the parted images is whose (module docs).
            let win = if t.resting {
                match host_of(tracks, t) {
                    Some(h) => cores::core_rect(h).unwrap_or(h.window),
                    None => continue,
                }
            } else {
                t.window
            };
            let (px, py) = prediction(tracks, t);
            for ((cost, &(bx, by)), &masked) in row.iter_mut().zip(&self.centroids).zip(&self.taken)
            {
                if !masked && win.contains(bx, by) {
                    *cost = (bx - px).powi(2) + (by - py).powi(2);
                }
            }
        }
        if tracks.iter().any(|t| t.resting) {
            self.leave_resting_out_of_followed_blobs(n);
        }
    }

    /// A resting track whose every candidate is the nearest blob of a track found in the last
    /// frame stays out of the assignment: no image has come out of the merged one, so it
    /// rests, and those tracks keep their nearest blobs (the cores settle such a frame
    /// as they would without it). A candidate no such track has as its nearest is an
    /// image come out: the resting track then competes for all its candidates and the assignment
    /// decides which of the parted images is whose. Its candidates are the blobs whose
    /// centroids lie in the merged track's core (the same in the cores' read and the windows'),
    /// so both reads give the same rows.
    fn leave_resting_out_of_followed_blobs(&mut self, n: usize) {
        let nearest = &mut self.nearest_taken;
        nearest.clear();
        nearest.resize(n, false);
        for (t, row) in self.tracks.iter().zip(self.cost.chunks_exact(n)) {
            if t.lost_frames > 0 {
                continue;
            }
            if let Some(j) = cheapest_allowed(row) {
                nearest[j] = true;
            }
        }
        for (t, row) in self.tracks.iter().zip(self.cost.chunks_exact_mut(n)) {
            let nothing_out = row
                .iter()
                .zip(nearest.iter())
                .all(|(c, &followed)| !c.is_finite() || followed);
            if t.resting && nothing_out {
                row.fill(f64::INFINITY);
            }
        }
    }

    /// [`Tracker::step`] for frame number `frame` (the camera's sequence number): the periodic
    /// search for new objects runs on the first frame of each period of
    /// `search_every_frames` numbers, so trackers fed the same frames search on the same ones
    /// whenever each started (a replay of recorded frames finds objects when the live system
    /// did), and a skipped frame does not skip a period's search.
    pub fn step_frame<P: Pixel>(
        &mut self,
        img: GrayView<'_, P>,
        threshold: u32,
        frame: u64,
    ) -> Result<TrackStep, VisionError> {
        let (w, h) = (img.width(), img.height());
        let limit = w.max(h);
        let covers_frame = |r: &PixelRect| r.width() == w && r.height() == h;
        let every = self.cfg.search_every_frames as u64;
        let period = frame / every;
        let new_period = self.last_frame.is_none_or(|l| period != l / every);
        self.last_frame = Some(frame);
        // Steps 1–5: a window per track around its prediction.
        self.windows.clear();
        let mut needs_full = self.tracks.is_empty();
        for i in 0..self.tracks.len() {
            let t = &self.tracks[i];
            let (px, py) = prediction(&self.tracks, t);
            let half = self.half_width(t, limit);
            let rect = clamp_window(px, py, half, w, h);
            // A lost object inside a merged blob is where that blob is: its window is read (and
            // the frame searched for it) on each search period's first frame, as new objects
            // are looked for; between, the other track's window is where it comes back out.
            let resting = t.inside_merged.is_some() && !new_period;
            self.tracks[i].resting = resting;
            self.tracks[i].window = rect;
            if resting {
                continue;
            }
            if covers_frame(&rect) {
                needs_full = true;
            }
            let thr = match self.cfg.window_threshold {
                Some(m) => Some(Histogram::of_rect(&img, rect).threshold::<P>(m)?),
                None => None,
            };
            self.windows.push(Window {
                rect,
                threshold: thr,
            });
        }
        let searching = self.tracks.len() < self.cfg.max_objects && new_period;
        // A search — the periodic one, or a lost object's once its window has grown to the
        // frame — first tests the frame outside the other windows: with nothing bright there,
        // the windowed step over those finds every blob there is (a lost object hidden in
        // another's blob, as two markers crossing in the image are, costs no labelling of the
        // whole frame on every frame it stays hidden).
        let tested = (searching || needs_full)
            && !self.tracks.is_empty()
            && self.cfg.window_threshold.is_none();
        if tested {
            // A window grown to the frame is what the test searches, not a window to scan.
            self.windows.retain(|win| !covers_frame(&win.rect));
        }
        // The cores (each object found in the last frame read where its blob must be): on a
        // frame with no search, where they may settle it; on a search's, when the test finds
        // nothing bright outside them either, so their blobs are the frame's.
        let core_scan =
            self.cfg.core_scan && self.cfg.window_threshold.is_none() && self.set_cores(w, h);
        let rows = self.search_rows(h, period, frame, !searching);
        let mut searched_in_cores = false;
        let searched_in_windows = tested && !self.windows.is_empty() && {
            searched_in_cores = core_scan
                && !any_foreground_outside(&img, threshold, &self.with_mask(&self.cores), rows);
            searched_in_cores
                || !any_foreground_outside(&img, threshold, &self.with_mask(&self.windows), rows)
        };
        let full_frame = (needs_full || searching) && !searched_in_windows;
        if full_frame {
            self.windows.clear();
        }
        // The cores first, where they may settle the frame; else (or then) the windows.
        let mut cores = CoreScan::Windows;
        // Whether the cores' check settled the frame: then each track's nearest blob is the
        // minimum-cost assignment (it found no two tracks with the same nearest, and that is
        // the assignment's own first case), and the solver is not asked again.
        let mut nearest_assigned = false;
        if core_scan && (searched_in_cores || !(searching || needs_full)) {
            self.prefetch_cores(&img);
            self.extractor.extract(img, threshold, &self.cores)?;
            self.fill_costs();
            // After a search that found nothing outside the cores, every blob the windows
            // hold is in the cores: whole when none touches a core's edge.
            let settled = if searched_in_cores {
                self.extractor.stats().clipped_regions == 0
            } else {
                nearest_assigned = self.cores_settle(w, h);
                nearest_assigned
            };
            cores = if settled {
                CoreScan::Settled
            } else {
                CoreScan::Widened
            };
        }
        if cores != CoreScan::Settled {
            self.extractor.extract(img, threshold, &self.windows)?;
            self.fill_costs();
        }
        let blobs = self.extractor.blobs();
        let mut step = TrackStep {
            full_frame: full_frame || searched_in_windows,
            extract: self.extractor.stats(),
            masked: self.taken.iter().filter(|&&m| m).count(),
            cores,
            ..Default::default()
        };
        let assignment = if nearest_assigned {
            &self.nearest[..]
        } else {
            self.assigner
                .solve(&self.cost, self.tracks.len(), blobs.len())
        };
        let par = self.cfg.par;
        let skew = self.cfg.direction_min_skewness;
        for (t, a) in self.tracks.iter_mut().zip(assignment) {
            match a {
                Some(j) => {
                    self.taken[*j] = true;
                    t.take(&blobs[*j], self.centroids[*j], par, skew);
                    step.tracked += 1;
                }
                None => {
                    t.lose();
                    step.lost += 1;
                }
            }
        }
        self.flag_merged();
        let before = self.tracks.len();
        let drop_after = self.cfg.drop_after_lost_frames;
        self.tracks.retain(|t| t.lost_frames <= drop_after);
        step.dropped = before - self.tracks.len();

        // New objects, only from full-frame searches: largest unclaimed, whole blobs first.
        if (full_frame || searched_in_windows) && self.tracks.len() < self.cfg.max_objects {
            let blobs = self.extractor.blobs();
            let mut fresh: Vec<usize> = (0..blobs.len())
                .filter(|&j| {
                    !self.taken[j]
                        && blobs[j].area_px() >= self.cfg.min_new_area_px
                        && !blobs[j].flags.contains(BlobFlags::CLIPPED)
                })
                .collect();
            fresh.sort_by(|&a, &b| blobs[b].area_px().cmp(&blobs[a].area_px()).then(a.cmp(&b)));
            for j in fresh {
                if self.tracks.len() >= self.cfg.max_objects {
                    break;
                }
                let b = blobs[j];
                let (bx, by) = b.best_centroid_px();
                let mut ht = HeadingTracker::new(self.cfg.heading);
                let (heading, shape) = heading_of(&mut ht, &b, par, skew);
                self.tracks.push(Track {
                    id: self.next_id,
                    status: TrackStatus::New,
                    x_px: bx,
                    y_px: by,
                    vx_px: 0.0,
                    vy_px: 0.0,
                    area_px: b.area_px(),
                    usual_area_px: b.area_px() as f64,
                    merged: false,
                    inside_merged: None,
                    resting: false,
                    merge_offset_px: (0.0, 0.0),
                    window: PixelRect::full(w, h),
                    lost_frames: 0,
                    blob: Some(b),
                    shape: Some(shape),
                    heading,
                    heading_tracker: ht,
                });
                self.next_id += 1;
                step.new += 1;
            }
        }
        Ok(step)
    }
}

/// The track `t` is inside (its merged blob's), if it is still followed.
fn host_of<'a>(tracks: &'a [Track], t: &Track) -> Option<&'a Track> {
    let host = t.inside_merged?;
    tracks.iter().find(|h| h.id == host)
}

/// Where track `t` is expected this frame: by its own motion (Eq. 5.3), or, inside another
/// track's merged blob, at its place in that blob moved with it.
fn prediction(tracks: &[Track], t: &Track) -> (f64, f64) {
    match host_of(tracks, t) {
        Some(h) => {
            let (hx, hy) = h.predicted();
            (hx + t.merge_offset_px.0, hy + t.merge_offset_px.1)
        }
        None => t.predicted(),
    }
}

/// The blob's heading update and its shape (which the heading is taken from).
fn heading_of(
    ht: &mut HeadingTracker,
    b: &Blob,
    par: f64,
    min_skew: Option<f64>,
) -> (HeadingUpdate, BlobShape) {
    let central = b.best_central();
    let shape = central.axis_shape(par);
    let roundness = shape.roundness();
    // A round blob's heading is held, so its direction is not worth the third moments.
    let directed = if roundness > ht.config().max_roundness {
        None
    } else {
        min_skew.and_then(|s| directed_angle_deg(&b.moments, &shape, par, s))
    };
    let update = ht.update(shape.angle_deg, roundness, directed);
    (
        update,
        BlobShape {
            central,
            axis: shape,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::GrayImage;
    use crate::raster::{Ellipse, draw_ellipse};
    use stereoscope_numeric::heading::HeadingStatus;

    fn frame(objs: &[(f64, f64, f64)]) -> GrayImage<u8> {
        discs_frame(320, 240, 10, 210, objs)
    }

    /// A `width × height` frame of discs `(x, y, radius)` at `level` on `background`.
    pub(in crate::tracker) fn discs_frame(
        width: u32,
        height: u32,
        background: u8,
        level: u8,
        discs: &[(f64, f64, f64)],
    ) -> GrayImage<u8> {
        let mut img = GrayImage::filled(width, height, background).unwrap();
        for &(x, y, r) in discs {
            let (bg, fg) = (background as f64, level as f64);
            draw_ellipse(&mut img, &Ellipse::disc(x, y, r), 1.0, bg, fg, 4);
        }
        img
    }

    /// A lamp inside a mask rectangle is never followed, a marker is, also while it passes
    /// beside the lamp; without the mask the lamp is an object.
    #[test]
    fn a_masked_lamp_is_ignored_and_a_marker_beside_it_followed() {
        let scene = |f: u64| frame(&[(250.0, 60.0, 7.0), (120.0 + 3.0 * f as f64, 62.0, 4.0)]);
        let lamp = PixelRect {
            x0: 238,
            y0: 48,
            x1: 262,
            y1: 72,
        };
        let mut masked = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        masked.set_mask(vec![lamp]);
        let mut open = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        for f in 0..40 {
            let img = scene(f);
            let step = masked.step_frame(img.view(), 100, f).unwrap();
            open.step_frame(img.view(), 100, f).unwrap();
            assert_eq!(masked.tracks().len(), 1, "frame {f}");
            let t = &masked.tracks()[0];
            assert!(
                t.status != TrackStatus::Lost && (t.x_px - (120.0 + 3.0 * f as f64)).abs() < 0.5,
                "frame {f}: {t:?}"
            );
            assert!(!lamp.contains(t.x_px, t.y_px));
            // Seen at the first (full) search and when the marker's window reaches it; the
            // lamp, masked, forces no full search of its own.
            assert!(step.masked <= 1 && (f > 0 || step.masked == 1), "frame {f}");
        }
        assert_eq!(open.tracks().len(), 2);
    }

    /// Two trackers fed the same numbered frames, one from frame 0 and one from frame 13 (a
    /// replay of a recording that began mid-run): an object appearing at frame 15 is found by
    /// both at frame 20, the next search period, and from then on they report the same.
    #[test]
    fn periodic_searches_follow_the_frame_numbers() {
        let scene = |f: u64| {
            let mut objs = vec![(60.0 + f as f64, 80.0, 5.0)];
            if f >= 15 {
                objs.push((200.0, 150.0 - f as f64, 6.0));
            }
            frame(&objs)
        };
        let cfg = TrackerConfig {
            search_every_frames: 10,
            ..Default::default()
        };
        let mut live = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        let mut replay = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        let mut found = [None, None];
        for f in 0..40u64 {
            let img = scene(f);
            let mut seen = Vec::new();
            for (k, tr) in [&mut live, &mut replay].into_iter().enumerate() {
                if k == 1 && f < 13 {
                    continue;
                }
                let step = tr.step_frame(img.view(), 128, f).unwrap();
                if tr.tracks().len() == 2 && found[k].is_none() {
                    found[k] = Some(f);
                    assert_eq!(step.new, 1);
                }
                let mut xy: Vec<(f64, f64)> =
                    tr.tracks().iter().map(|t| (t.x_px, t.y_px)).collect();
                xy.sort_by(|a, b| a.0.total_cmp(&b.0));
                seen.push(xy);
            }
            if f >= 20 {
                assert_eq!(seen[0], seen[1], "frame {f}");
            }
        }
        assert_eq!(found, [Some(20), Some(20)]);
        // Numbered by the calls, the same schedule.
        let mut counted = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        let first_two = (0..40u64).find(|&f| {
            counted.step(scene(f).view(), 128).unwrap();
            counted.tracks().len() == 2
        });
        assert_eq!(first_two, Some(20));
    }

    /// A periodic search labels the whole frame only when something bright lies outside the
    /// windows: with nothing new it reads the frame and labels only the windows; a new object
    /// far from the others is found as before; one that appears inside another's window is
    /// found too (the windows' union held every blob).
    #[test]
    fn a_search_labels_the_frame_only_when_something_is_outside_the_windows() {
        let cfg = TrackerConfig {
            search_every_frames: 10,
            ..Default::default()
        };
        let pixels = 320 * 240;
        let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        let first = tr
            .step_frame(frame(&[(60.0, 80.0, 5.0)]).view(), 128, 0)
            .unwrap();
        assert_eq!(first.extract.pixels_scanned, pixels);
        for f in 1..10u64 {
            tr.step_frame(frame(&[(60.0, 80.0, 5.0)]).view(), 128, f)
                .unwrap();
        }
        // Frame 10 opens a search period; nothing new: only the window is labelled.
        let s = tr
            .step_frame(frame(&[(60.0, 80.0, 5.0)]).view(), 128, 10)
            .unwrap();
        assert!(
            s.full_frame && s.extract.pixels_scanned < pixels / 10,
            "{s:?}"
        );
        assert_eq!((s.new, tr.tracks().len()), (0, 1));
        // A second object 12 px away, inside the first one's window, at the next search.
        let two = [(60.0, 80.0, 5.0), (72.0, 80.0, 3.0)];
        let w = tr.tracks()[0].window;
        assert!(w.contains(72.0, 80.0), "{w:?}");
        let s = tr.step_frame(frame(&two).view(), 128, 20).unwrap();
        assert!(s.extract.pixels_scanned < pixels / 10, "{s:?}");
        assert_eq!((s.new, tr.tracks().len()), (1, 2));
        // A third far away: the frame is labelled whole and it is found.
        let three = [(60.0, 80.0, 5.0), (72.0, 80.0, 3.0), (250.0, 200.0, 5.0)];
        let s = tr.step_frame(frame(&three).view(), 128, 30).unwrap();
        assert_eq!(s.extract.pixels_scanned, pixels);
        assert_eq!((s.new, tr.tracks().len()), (1, 3));
    }

    /// A search that reads every 3rd row finds an object 3 rows tall at the first search it
    /// is in, and one a single row tall (a line of 8 pixels) at the search whose rows cross
    /// it: the phase moves by one row a search, with the period number.
    #[test]
    fn a_sampled_search_finds_tall_objects_at_once_and_a_one_row_object_in_turn() {
        let first_found = |row_step: Option<u32>, rows: std::ops::Range<usize>| {
            let cfg = TrackerConfig {
                search_every_frames: 10,
                search_row_step: row_step,
                ..Default::default()
            };
            let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
            (0..60u64).find(|&f| {
                let mut img = frame(&[(60.0, 80.0, 5.0)]);
                if f >= 5 {
                    for y in rows.clone() {
                        img.as_mut_slice()[y * 320 + 200..y * 320 + 208].fill(210);
                    }
                }
                tr.step_frame(img.view(), 128, f).unwrap();
                tr.tracks().len() == 2
            })
        };
        // Row 101 is read in periods 2, 5, …; row 102 in 0, 3, … (period 3 is frame 30).
        assert_eq!(first_found(Some(3), 101..102), Some(20));
        assert_eq!(first_found(Some(3), 102..103), Some(30));
        assert_eq!(first_found(Some(3), 100..103), Some(10));
        assert_eq!(first_found(Some(1), 102..103), Some(10));
        // By default every 2nd row up to 1619 rows, every 3rd from 1620, every 4th at 4K.
        let tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        let steps = [1, 240, 1079, 1080, 1620, 2160].map(|h| tr.search_rows(h, 5, 50, false));
        assert_eq!(
            steps.map(|r| (r.step, r.phase)),
            [(2, 1), (2, 1), (2, 1), (2, 1), (3, 2), (4, 1)]
        );
        // A lost object's own searches read every other row of those.
        let lost = [1, 240, 1080, 1620, 2160].map(|h| tr.search_rows(h, 5, 53, true));
        assert_eq!(
            lost.map(|r| (r.step, r.phase)),
            [(4, 0), (4, 0), (4, 0), (6, 2), (8, 0)]
        );
        let zero = TrackerConfig {
            search_row_step: Some(0),
            ..Default::default()
        };
        assert!(Tracker::new(zero, ExtractConfig::default()).is_err());
    }

    /// A lost object whose window has grown to the frame is searched for by the test outside
    /// the other windows first: while it stays hidden (nothing bright outside them) only those
    /// windows are labelled, not the whole frame; when it shows again outside them the frame
    /// is labelled whole and the object taken back under its id. Consecutive such searches
    /// read rows of every phase.
    #[test]
    fn a_hidden_lost_object_is_searched_for_without_labelling_the_frame() {
        let (w, h) = (320u64, 240u64);
        let mut tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        let a = (100.0, 120.0, 5.0);
        for f in 0..5 {
            tr.step_frame(frame(&[a, (220.0, 60.0, 4.0)]).view(), 100, f)
                .unwrap();
        }
        assert_eq!(tr.tracks().len(), 2);
        let b_id = tr.tracks()[1].id;
        let mut tested = 0;
        for f in 5..25 {
            let step = tr.step_frame(frame(&[a]).view(), 100, f).unwrap();
            let b = &tr.tracks()[1];
            assert_eq!((b.id, b.status), (b_id, TrackStatus::Lost), "frame {f}");
            if b.window.width() as u64 * b.window.height() as u64 == w * h {
                // Searched, but only object A's window labelled.
                assert!(step.full_frame, "frame {f}");
                assert!(
                    step.extract.pixels_scanned < w * h / 4,
                    "frame {f}: {step:?}"
                );
                tested += 1;
            }
        }
        assert!(
            tested >= 15,
            "only {tested} frames searched for the lost object"
        );
        // The lost object shows again, far from where it was lost.
        let step = tr
            .step_frame(frame(&[a, (40.0, 200.0, 4.0)]).view(), 100, 25)
            .unwrap();
        assert!(step.full_frame);
        assert_eq!(step.extract.pixels_scanned, w * h);
        assert_eq!(tr.tracks().len(), 2);
        let b = &tr.tracks()[1];
        assert_eq!((b.id, b.status), (b_id, TrackStatus::Tracked));
        assert!((b.x_px - 40.0).abs() < 0.5 && (b.y_px - 200.0).abs() < 0.5);
        // At 1080p (every 2nd row by default) the searches of frames 11, 12 read rows of
        // either phase.
        let rows = [11, 12].map(|f| tr.search_rows(1080, f / 10, f, true).phase);
        assert_ne!(rows[0], rows[1]);
    }

    /// A lost object's search reads every 4th row by default (twice the periodic search's
    /// step), from a row one on each frame: a lost object that shows again 4 rows tall is
    /// found at the first frame, wherever it lies; one a single row tall within 4 frames,
    /// later where the rows read miss it (so the reads are really halved), and under its id.
    #[test]
    fn a_lost_objects_search_reads_every_4th_row_and_finds_a_thin_one_in_turn() {
        let a = (100.0, 120.0, 5.0);
        // Frames from the one where the object (rows `y..y + tall` of columns 200..208) shows
        // again until it is tracked.
        let frames_to_find = |y: usize, tall: usize| {
            let mut tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
            for f in 0..5 {
                tr.step_frame(frame(&[a, (204.0, 60.0, 4.0)]).view(), 100, f)
                    .unwrap();
            }
            let b_id = tr.tracks()[1].id;
            // Lost until its window has covered the frame for a while (frames 11 to 19 hold
            // no periodic search: they are the lost object's alone).
            for f in 5..13 {
                tr.step_frame(frame(&[a]).view(), 100, f).unwrap();
            }
            let b = &tr.tracks()[1];
            assert_eq!((b.window.width(), b.window.height()), (320, 240));
            (13..19u64)
                .find(|&f| {
                    let mut img = frame(&[a]);
                    for row in y..y + tall {
                        img.as_mut_slice()[row * 320 + 200..row * 320 + 208].fill(210);
                    }
                    tr.step_frame(img.view(), 100, f).unwrap();
                    let b = &tr.tracks()[1];
                    assert_eq!(b.id, b_id);
                    b.status != TrackStatus::Lost
                })
                .map(|f| f - 13 + 1)
        };
        for y in 180..184 {
            assert_eq!(frames_to_find(y, 4), Some(1), "4 rows from row {y}");
        }
        let thin: Vec<_> = (180..184).map(|y| frames_to_find(y, 1)).collect();
        assert!(thin.iter().all(|f| f.is_some_and(|f| f <= 4)), "{thin:?}");
        assert!(thin.iter().any(|&f| f > Some(2)), "{thin:?}");
    }

    #[test]
    fn any_foreground_outside_sees_only_what_no_window_covers() {
        let img = frame(&[(100.0, 100.0, 4.0)]);
        let v = img.view();
        let around = PixelRect {
            x0: 90,
            y0: 90,
            x1: 110,
            y1: 110,
        };
        let beside = PixelRect {
            x0: 90,
            y0: 90,
            x1: 99,
            y1: 110,
        };
        let all = RowSample::ALL;
        assert!(any_foreground_outside(&v, 128, &[], all));
        assert!(!any_foreground_outside(&v, 128, &[around], all));
        assert!(any_foreground_outside(&v, 128, &[beside], all));
        // Two windows that together cover it.
        let rest = PixelRect { x0: 100, ..around };
        assert!(!any_foreground_outside(&v, 128, &[rest, beside], all));
        assert!(!any_foreground_outside(&v, 255, &[], all));
    }

    #[test]
    fn rounding_matches_the_library_round() {
        for c in [
            0.0,
            0.49999999999999994,
            0.5,
            1.5,
            2.5,
            -0.5,
            -1.5,
            -2.4,
            1e300,
            -1e300,
            4e18,
            1919.5,
        ] {
            assert_eq!(round_half_away(c), c.round() as i64, "{c}");
        }
        let mut rng = stereoscope_numeric::SplitMix64::new(3);
        for _ in 0..10_000 {
            let c = (rng.uniform() - 0.5) * 1e4;
            assert_eq!(round_half_away(c), c.round() as i64, "{c}");
        }
    }

    #[test]
    fn window_follows_eq_5_1_and_stays_in_the_frame() {
        assert_eq!(
            clamp_window(100.0, 100.0, 30, 320, 240),
            PixelRect {
                x0: 70,
                y0: 70,
                x1: 130,
                y1: 130
            }
        );
        assert_eq!(
            clamp_window(5.0, 235.0, 30, 320, 240),
            PixelRect {
                x0: 0,
                y0: 179,
                x1: 60,
                y1: 239
            }
        );
        assert_eq!(
            clamp_window(5.0, 5.0, 500, 320, 240),
            PixelRect::full(320, 240)
        );
        assert_eq!(clamp_window(f64::NAN, 5.0, 10, 320, 240).width(), 21);
        let t = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        let mut track = Track {
            id: 1,
            status: TrackStatus::Tracked,
            x_px: 0.0,
            y_px: 0.0,
            vx_px: 0.0,
            vy_px: 0.0,
            area_px: 400,
            usual_area_px: 400.0,
            merged: false,
            inside_merged: None,
            resting: false,
            merge_offset_px: (0.0, 0.0),
            window: PixelRect::full(1, 1),
            lost_frames: 0,
            blob: None,
            shape: None,
            heading: HeadingUpdate {
                heading_deg: 0.0,
                step_deg: 0.0,
                status: HeadingStatus::Initial,
            },
            heading_tracker: HeadingTracker::new(HeadingConfig::default()),
        };
        assert_eq!(t.half_width(&track, 320), 46); // 2.3 · 20
        track.area_px = 9;
        assert_eq!(t.half_width(&track, 320), 30); // floor
        track.lost_frames = 2;
        assert_eq!(t.half_width(&track, 320), 120); // doubled twice
        track.lost_frames = 5;
        assert_eq!(t.half_width(&track, 320), 320);
    }

    #[test]
    fn tracks_three_crossing_objects_keeping_ids() {
        let mut tr = Tracker::new(
            TrackerConfig {
                max_objects: 3,
                ..Default::default()
            },
            ExtractConfig::default(),
        )
        .unwrap();
        let mut ids_at_start = Vec::new();
        for f in 0..60 {
            let t = f as f64;
            // Two objects cross at frame 30 with offset rows; a third moves slowly.
            let objs = [
                (40.0 + 4.0 * t, 100.0, 6.0),
                (280.0 - 4.0 * t, 118.0, 5.0),
                (160.0, 30.0 + t, 7.0),
            ];
            let img = frame(&objs);
            let step = tr.step(img.view(), 110).unwrap();
            if f == 0 {
                assert!(step.full_frame);
                assert_eq!(step.new, 3);
                ids_at_start = objs
                    .iter()
                    .map(|o| {
                        tr.tracks()
                            .iter()
                            .find(|k| (k.x_px - o.0).abs() < 1.0 && (k.y_px - o.1).abs() < 1.0)
                            .unwrap()
                            .id
                    })
                    .collect();
            } else {
                assert!(!step.full_frame, "frame {f} should be windowed");
                assert_eq!(step.tracked, 3, "frame {f}");
            }
            // Each blob's shape is kept as the heading took it, for the worker to report.
            for k in tr.tracks() {
                let c = k.blob.as_ref().unwrap().best_central();
                let axis = c.axis_shape(tr.config().par);
                assert_eq!(k.shape, Some(BlobShape { central: c, axis }), "frame {f}");
            }
            for (o, id) in objs.iter().zip(&ids_at_start) {
                let k = tr.tracks().iter().find(|k| k.id == *id).unwrap();
                assert!(
                    (k.x_px - o.0).abs() < 0.5 && (k.y_px - o.1).abs() < 0.5,
                    "frame {f} id {id}: ({}, {}) vs {:?}",
                    k.x_px,
                    k.y_px,
                    o
                );
            }
        }
    }

    #[test]
    fn lost_object_grows_its_window_then_reacquires_from_the_full_frame() {
        let mut tr = Tracker::new(
            TrackerConfig {
                max_objects: 1,
                ..Default::default()
            },
            ExtractConfig::default(),
        )
        .unwrap();
        tr.step(frame(&[(50.0, 50.0, 5.0)]).view(), 110).unwrap();
        tr.step(frame(&[(52.0, 50.0, 5.0)]).view(), 110).unwrap();
        let id = tr.tracks()[0].id;
        let w0 = tr.tracks()[0].window;
        // Gone for a few frames: the window doubles each time, moving with the prediction.
        let mut widths = vec![w0.width()];
        let empty = frame(&[]);
        let mut went_full = false;
        for _ in 0..4 {
            let s = tr.step(empty.view(), 110).unwrap();
            assert_eq!(tr.tracks()[0].status, TrackStatus::Lost);
            assert_eq!(
                tr.tracks()[0].shape,
                None,
                "a lost track has no blob's shape"
            );
            widths.push(tr.tracks()[0].window.width());
            went_full |= s.full_frame;
        }
        assert!(widths.windows(2).all(|p| p[1] >= p[0]), "{widths:?}");
        assert!(went_full);
        // It comes back far away: the full-frame search finds it with the same id.
        let s = tr.step(frame(&[(250.0, 200.0, 5.0)]).view(), 110).unwrap();
        assert!(s.full_frame);
        assert_eq!(tr.tracks()[0].id, id);
        assert_eq!(tr.tracks()[0].status, TrackStatus::Tracked);
        assert!((tr.tracks()[0].x_px - 250.0).abs() < 0.5);
    }

    #[test]
    fn two_tracks_never_share_a_blob_when_windows_overlap() {
        let mut tr = Tracker::new(
            TrackerConfig {
                max_objects: 2,
                ..Default::default()
            },
            ExtractConfig::default(),
        )
        .unwrap();
        tr.step(
            frame(&[(100.0, 100.0, 5.0), (120.0, 100.0, 5.0)]).view(),
            110,
        )
        .unwrap();
        assert_eq!(tr.tracks().len(), 2);
        // One object disappears: its overlapping window sees the other's blob, but only one
        // track may take it.
        tr.step(frame(&[(120.0, 100.0, 5.0)]).view(), 110).unwrap();
        let tracked: Vec<_> = tr
            .tracks()
            .iter()
            .filter(|t| t.status == TrackStatus::Tracked)
            .collect();
        assert_eq!(tracked.len(), 1);
        assert!((tracked[0].x_px - 120.0).abs() < 0.5);
    }

    #[test]
    fn drops_long_lost_tracks_and_rejects_bad_config() {
        let mut tr = Tracker::new(
            TrackerConfig {
                max_objects: 1,
                drop_after_lost_frames: 3,
                ..Default::default()
            },
            ExtractConfig::default(),
        )
        .unwrap();
        tr.step(frame(&[(50.0, 50.0, 5.0)]).view(), 110).unwrap();
        let empty = frame(&[]);
        let mut dropped = 0;
        for _ in 0..5 {
            dropped += tr.step(empty.view(), 110).unwrap().dropped;
        }
        assert_eq!(dropped, 1);
        assert!(tr.tracks().is_empty());
        for cfg in [
            TrackerConfig {
                magic_factor: -1.0,
                ..Default::default()
            },
            TrackerConfig {
                max_objects: 0,
                ..Default::default()
            },
            TrackerConfig {
                par: 0.0,
                ..Default::default()
            },
            TrackerConfig {
                search_every_frames: 0,
                ..Default::default()
            },
        ] {
            assert!(Tracker::new(cfg, ExtractConfig::default()).is_err());
        }
    }

    #[test]
    fn per_window_thresholds_follow_local_light() {
        // Left half dim background, right half bright background: one frame threshold cannot
        // serve both, per-window histograms can.
        let mut img = GrayImage::filled(320, 240, 10u8).unwrap();
        for y in 0..240 {
            for x in 160..320 {
                img.set(x, y, 120);
            }
        }
        draw_ellipse(
            &mut img,
            &Ellipse::disc(80.0, 120.0, 6.0),
            1.0,
            10.0,
            100.0,
            4,
        );
        draw_ellipse(
            &mut img,
            &Ellipse::disc(240.0, 120.0, 6.0),
            1.0,
            120.0,
            230.0,
            4,
        );
        let cfg = TrackerConfig {
            max_objects: 2,
            search_every_frames: 1000,
            window_threshold: Some(ThresholdMethod::Otsu),
            ..Default::default()
        };
        let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        // Acquire with a frame threshold that only sees the right object's surroundings...
        tr.step(img.view(), 160).unwrap();
        assert_eq!(tr.tracks().len(), 1);
        // ...and with a low one that sees both blobs (the right half is all foreground then,
        // but the left disc is whole).
        let mut tr2 = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        tr2.step(img.view(), 55).unwrap();
        let left = tr2
            .tracks()
            .iter()
            .find(|t| (t.x_px - 80.0).abs() < 1.0)
            .map(|t| t.id);
        assert!(left.is_some());
        // Windowed frames then threshold each window by its own histogram.
        for _ in 0..3 {
            tr2.step(img.view(), 55).unwrap();
        }
        assert!(tr2.windows().iter().all(|w| w.threshold.is_some()));
        let t = tr2.tracks().iter().find(|t| Some(t.id) == left).unwrap();
        assert_eq!(t.status, TrackStatus::Tracked);
        assert!((t.x_px - 80.0).abs() < 0.3);
    }

    /// Two markers whose images merge: the blob holding both is flagged merged (its centroid
    /// is between them), the other track is lost meanwhile; apart again, neither is flagged.
    #[test]
    fn merged_images_are_flagged() {
        // Apart, closing in (touching at frame 6: one blob of twice the area), apart again.
        let gaps = [40u32, 30, 20, 12, 6, 2, 0, 0, 6, 20, 30];
        let frames: Vec<Vec<(u32, u32, u32)>> = gaps
            .iter()
            .map(|gap| vec![(40 - gap / 2, 25, 10), (50 + gap - gap / 2, 25, 10)])
            .collect();
        let seen = merged_frames(&frames);
        for (k, gap) in gaps.iter().enumerate() {
            if *gap == 0 {
                assert_eq!(seen[k].1, 1, "frame {k}: one blob");
            }
        }
        let flagged: Vec<bool> = seen.iter().map(|f| f.0).collect();
        assert_eq!(
            flagged,
            [
                false, false, false, false, false, false, true, true, false, false, false
            ],
            "frames whose blob was flagged merged"
        );
    }

    /// Per frame of a scene of squares (`(x0, y0, side)` each): whether any blob was flagged
    /// merged, and how many tracks had a blob.
    fn merged_frames(frames: &[Vec<(u32, u32, u32)>]) -> Vec<(bool, usize)> {
        let (w, h) = (160u32, 60u32);
        let mut t = Tracker::new(
            TrackerConfig {
                search_every_frames: 1,
                ..TrackerConfig::default()
            },
            ExtractConfig::default(),
        )
        .unwrap();
        let mut flags = Vec::new();
        for (k, squares) in frames.iter().enumerate() {
            let mut img = vec![0u8; (w * h) as usize];
            for &(x0, y0, side) in squares {
                for y in y0..y0 + side {
                    for x in x0..x0 + side {
                        img[(y * w + x) as usize] = 200;
                    }
                }
            }
            let view = crate::image::GrayView::new(&img, w, h, w as usize).unwrap();
            t.step_frame(view, 100, k as u64).unwrap();
            let with_blob: Vec<&Track> = t.tracks().iter().filter(|t| t.blob.is_some()).collect();
            flags.push((with_blob.iter().any(|t| t.merged), with_blob.len()));
        }
        flags
    }

    /// Two markers merged and moving on together: the blob stays flagged after the lost
    /// track's last place falls behind it; apart again, neither is flagged.
    #[test]
    fn a_merged_pair_stays_merged_as_it_moves_on() {
        let mut frames = Vec::new();
        for gap in [40u32, 30, 20, 12, 6, 2] {
            frames.push(vec![(40 - gap / 2, 25, 10), (50 + gap - gap / 2, 25, 10)]);
        }
        // Touching, then carried 8 px a frame to the right together.
        for k in 0..6u32 {
            frames.push(vec![(40 + 8 * k, 25, 10), (50 + 8 * k, 25, 10)]);
        }
        frames.push(vec![(70, 25, 10), (110, 25, 10)]);
        let flags: Vec<bool> = merged_frames(&frames).iter().map(|f| f.0).collect();
        assert!(!flags[..6].iter().any(|f| *f), "{flags:?}");
        assert!(flags[6..12].iter().all(|f| *f), "{flags:?}");
        assert!(!flags[12], "{flags:?}");
    }

    /// A small marker's image swallowed by a big one's: the big blob grows by less than 1.6
    /// times but by the small one's area, with the small track lost inside: flagged.
    #[test]
    fn a_small_image_swallowed_by_a_big_one_is_flagged() {
        let mut frames = Vec::new();
        for x in [20u32, 30, 40, 48, 54] {
            frames.push(vec![(60, 20, 16), (x, 26, 5)]);
        }
        // Inside the big square's edge: one blob of 256 + 20 pixels.
        frames.push(vec![(60, 20, 16), (57, 26, 5)]);
        frames.push(vec![(60, 20, 16), (57, 26, 5)]);
        let flags: Vec<bool> = merged_frames(&frames).iter().map(|f| f.0).collect();
        assert!(!flags[..5].iter().any(|f| *f), "{flags:?}");
        assert!(flags[5..].iter().all(|f| *f), "{flags:?}");
    }

    /// A marker whose image merges into another's rests while it is inside the merged blob:
    /// no window of its own is read and the frame is not searched for it except on each
    /// search period's first frame (as for new objects); the first frame the two images are
    /// apart it takes its blob back under its id, with no new object made.
    #[test]
    fn a_marker_inside_a_merged_blob_rests_and_comes_back_out_under_its_id() {
        let (w, h) = (320u64, 240u64);
        let a = (100.0, 120.0, 5.0);
        // The second marker comes in from the right, overlaps the first 6 px from its centre
        // (one blob of about 1.7 times the area) on frames 4 to 16, and leaves again.
        let bx = |f: u64| match f {
            0..4 => 140.0 - 10.0 * f as f64,
            4..17 => 106.0,
            _ => 106.0 + 8.0 * (f - 16) as f64,
        };
        let mut tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        let mut ids = Vec::new();
        let mut rested = 0;
        for f in 0..18u64 {
            let resting_before = tr.tracks().iter().any(|t| t.inside_merged.is_some());
            let step = tr
                .step_frame(frame(&[a, (bx(f), 120.0, 5.0)]).view(), 100, f)
                .unwrap();
            if f == 3 {
                ids = tr.tracks().iter().map(|t| t.id).collect();
                assert_eq!(ids.len(), 2);
            }
            if (5..17).contains(&f) {
                // One track on the merged blob, the other lost inside it.
                let lost: Vec<_> = tr
                    .tracks()
                    .iter()
                    .filter(|t| t.status == TrackStatus::Lost)
                    .collect();
                assert_eq!(lost.len(), 1, "frame {f}");
                let host = tr.tracks().iter().find(|t| t.merged).map(|t| t.id);
                assert!(host.is_some(), "frame {f}");
                assert_eq!(lost[0].inside_merged, host, "frame {f}");
                assert!(resting_before, "frame {f}");
                if f % 10 == 0 {
                    // The search period's first frame searches the frame for it.
                    assert!(step.full_frame, "frame {f}");
                } else {
                    assert!(!step.full_frame, "frame {f}");
                    assert!(
                        step.extract.pixels_scanned < w * h / 50,
                        "frame {f}: {step:?}"
                    );
                    rested += 1;
                }
            }
            if f == 17 {
                // The first frame with the two images apart (16 px between centres), and not a
                // search's: both are followed again, under their ids, at their discs.
                assert_eq!(tr.tracks().len(), 2);
                for t in tr.tracks() {
                    assert_eq!(t.status, TrackStatus::Tracked);
                    assert!(t.inside_merged.is_none());
                }
                let mut now: Vec<u32> = tr.tracks().iter().map(|t| t.id).collect();
                now.sort();
                ids.sort();
                assert_eq!(now, ids);
                let mut xs: Vec<f64> = tr.tracks().iter().map(|t| t.x_px).collect();
                xs.sort_by(f64::total_cmp);
                assert!((xs[0] - 100.0).abs() < 0.5, "{xs:?}");
                assert!((xs[1] - bx(f)).abs() < 0.5, "{xs:?}");
            }
        }
        assert_eq!(rested, 11);
    }

    /// Two markers merge and part while a third, gone out of the frame, is still lost with a
    /// window grown to the frame: the parted image goes back to the marker that was inside
    /// the merged blob (it competes for the merged track's core), not to the lost third,
    /// and each track is on its own disc again.
    #[test]
    fn a_parted_image_goes_back_to_the_marker_inside_not_to_a_lost_one() {
        let a = (100.0, 120.0, 5.0);
        let bx = |f: u64| match f {
            0..4 => 140.0 - 10.0 * f as f64,
            4..17 => 106.0,
            _ => 106.0 + 8.0 * (f - 16) as f64,
        };
        // The third leaves through the top edge on frame 2 and stays out.
        let c = |f: u64| (200.0, 6.0 - 8.0 * f as f64, 4.0);
        let mut tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        let (mut id_a, mut id_b, mut id_c) = (0, 0, 0);
        for f in 0..20u64 {
            let discs = [a, (bx(f), 120.0, 5.0), c(f)];
            tr.step_frame(frame(&discs).view(), 100, f).unwrap();
            let near = |x: f64, y: f64| {
                tr.tracks()
                    .iter()
                    .find(|t| (t.x_px - x).abs() < 1.0 && (t.y_px - y).abs() < 1.0)
                    .map(|t| t.id)
            };
            if f == 0 {
                (id_a, id_b, id_c) = (
                    near(a.0, a.1).unwrap(),
                    near(bx(0), 120.0).unwrap(),
                    near(200.0, 6.0).unwrap(),
                );
            }
            if f == 12 {
                let b = tr.tracks().iter().find(|t| t.id == id_b).unwrap();
                assert_eq!(b.inside_merged, Some(id_a), "frame {f}");
                let c = tr.tracks().iter().find(|t| t.id == id_c).unwrap();
                assert_eq!(c.status, TrackStatus::Lost);
                assert!(c.window.width() == 320 && c.window.height() == 240);
            }
            if f >= 17 {
                // Apart again: each id on its own disc; the lost third still lost.
                assert_eq!(near(a.0, a.1), Some(id_a), "frame {f}: {:?}", tr.tracks());
                assert_eq!(
                    near(bx(f), 120.0),
                    Some(id_b),
                    "frame {f}: {:?}",
                    tr.tracks()
                );
                let c = tr.tracks().iter().find(|t| t.id == id_c).unwrap();
                assert_eq!(c.status, TrackStatus::Lost, "frame {f}");
                assert!(tr.tracks().iter().all(|t| !t.merged), "frame {f}");
            }
        }
    }

    /// A merge lasts while a lost track is inside it: a marker hidden behind another that
    /// grew (came nearer) is dropped after `drop_after_lost_frames`, and the other's blob is
    /// a measurement again from then on, its usual area following it.
    #[test]
    fn a_merge_ends_when_the_marker_inside_it_is_dropped() {
        let cfg = TrackerConfig::default();
        let drop_after = cfg.drop_after_lost_frames as u64;
        let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        // B beside A, then behind it from frame 4 on, while A's image grows to radius 7.
        let discs = |f: u64| match f {
            0..4 => vec![(100.0, 120.0, 5.0), (112.0 - 2.0 * f as f64, 120.0, 4.0)],
            _ => vec![(100.0, 120.0, 7.0)],
        };
        let last = drop_after + 20;
        let mut merged_frames = 0;
        for f in 0..=last {
            tr.step_frame(frame(&discs(f)).view(), 100, f).unwrap();
            let a = tr
                .tracks()
                .iter()
                .filter(|t| t.status != TrackStatus::Lost)
                .min_by(|p, q| (p.x_px - 100.0).abs().total_cmp(&(q.x_px - 100.0).abs()))
                .unwrap();
            merged_frames += u32::from(a.merged);
            if f == 10 {
                assert!(a.merged, "frame {f}: {:?}", tr.tracks());
            }
            if f == last {
                assert_eq!(tr.tracks().len(), 1, "the hidden one dropped");
                assert!(!a.merged, "frame {f}: {a:?}");
                let area = a.blob.unwrap().area_px() as f64;
                assert!((a.usual_area_px - area).abs() < 0.1 * area, "{a:?}");
            }
        }
        assert!(merged_frames as u64 <= drop_after + 2, "{merged_frames}");
    }
}
