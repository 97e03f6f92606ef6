//! Merged images: two objects whose blobs joined in this view. The track that keeps the blob
//! is flagged merged (its centroid is between the two and measures neither); the one lost
//! inside it rests — no window of its own, no whole-frame search but on each search period's
//! first frame — and takes back the blob that comes out of the merged one (module docs of
//! `tracker`).
//!
//! Thesis: chapter 5 (the windows and the search these spare); not a thesis method itself —
//! the thesis tracked objects that never crossed in the image.

use super::{TrackStatus, TrackStep, Tracker};
use crate::image::PixelRect;

/// A blob this many times its track's usual area, with another track lost inside it the same
/// frame, holds both objects' images (two markers whose images merged in this view).
pub const MERGE_AREA_RATIO: f64 = 1.6;

/// A blob grown by this share of a lost track's usual area, with that track inside it, holds
/// the lost track's image too.
pub const MERGE_SHARE: f64 = 0.5;

/// A merged blob stays merged while its area is at least this many times its track's usual
/// area.
pub const MERGE_KEEP_RATIO: f64 = 1.3;

/// Whether `(x, y)` lies in box `r` widened by 2 pixels: a lost track's place inside a blob.
fn near_box(r: &PixelRect, x: f64, y: f64) -> bool {
    x >= r.x0 as f64 - 2.0
        && x <= r.x1 as f64 + 2.0
        && y >= r.y0 as f64 - 2.0
        && y <= r.y1 as f64 + 2.0
}

impl Tracker {
    /// After the assignment: each resting track (inside a merged blob, left out of it) takes
    /// back the blob nearest its prediction of those in the merged track's window that no
    /// track took — its image come out of the merged one (a blob that touches no core's edge,
    /// when the cores settled the frame) — or is lost another frame.
    pub(super) fn take_back_resting(&mut self, step: &mut TrackStep) {
        let blobs = self.extractor.blobs();
        let (par, skew) = (self.cfg.par, self.cfg.direction_min_skewness);
        for i in 0..self.tracks.len() {
            if !self.tracks[i].resting {
                continue;
            }
            let host = self.tracks[i].inside_merged;
            let window = self
                .tracks
                .iter()
                .find(|t| Some(t.id) == host)
                .map(|t| t.window);
            let (px, py) = self.tracks[i].predicted();
            let distance = |j: usize| {
                let (x, y) = self.centroids[j];
                (x - px).powi(2) + (y - py).powi(2)
            };
            let nearest = window.and_then(|win| {
                (0..blobs.len())
                    .filter(|&j| {
                        let (x, y) = self.centroids[j];
                        !self.taken[j] && win.contains(x, y)
                    })
                    .min_by(|&a, &b| distance(a).total_cmp(&distance(b)))
            });
            let t = &mut self.tracks[i];
            match nearest {
                Some(j) => {
                    self.taken[j] = true;
                    t.take(&blobs[j], self.centroids[j], par, skew);
                    step.tracked += 1;
                }
                None => {
                    t.lose();
                    step.lost += 1;
                }
            }
        }
    }

    /// After the assignment: which blobs are merged, each track's usual area, and which lost
    /// tracks are inside a merged blob.
    ///
    /// A blob is merged when another track is lost inside it and it grew by at least half that
    /// track's usual area (a small marker swallowed by a big blob moves its centroid as much as
    /// two alike) or far above its own usual area; it stays merged while it stays above its
    /// usual area (the lost track's last place falls behind as the pair moves on). Such a
    /// track keeps its usual area (a merge is not growth). A lost track is inside a merged blob
    /// while the one it went into stays merged (its own prediction runs on past it
    /// meanwhile), or newly at its last or predicted place.
    pub(super) fn flag_merged(&mut self) {
        // Where each lost track was last seen, where it was predicted to be, and its area.
        let lost: Vec<(f64, f64, f64)> = self
            .tracks
            .iter()
            .filter(|t| t.status == TrackStatus::Lost)
            .flat_map(|t| {
                let (px, py) = t.predicted();
                [(t.x_px, t.y_px, t.usual_area_px), (px, py, t.usual_area_px)]
            })
            .collect();
        for t in &mut self.tracks {
            let Some(b) = &t.blob else { continue };
            let area = b.area_px() as f64;
            let usual = t.usual_area_px;
            let r = b.bbox;
            let still = t.merged && area >= MERGE_KEEP_RATIO * usual;
            t.merged = usual > 0.0
                && (still
                    || lost.iter().any(|&(x, y, lost_area)| {
                        near_box(&r, x, y)
                            && (area >= MERGE_AREA_RATIO * usual
                                || area >= usual + MERGE_SHARE * lost_area)
                    }));
            if !t.merged {
                t.usual_area_px = if t.usual_area_px > 0.0 {
                    0.7 * t.usual_area_px + 0.3 * area
                } else {
                    area
                };
            }
        }
        if lost.is_empty() {
            for t in &mut self.tracks {
                t.inside_merged = None;
            }
            return;
        }
        // Each merged track's id and blob box.
        let merged: Vec<_> = self
            .tracks
            .iter()
            .filter(|m| m.merged)
            .filter_map(|m| Some((m.id, m.blob.as_ref()?.bbox)))
            .collect();
        for t in &mut self.tracks {
            let places = [(t.x_px, t.y_px), t.predicted()];
            let inside = (t.status == TrackStatus::Lost)
                .then(|| {
                    merged
                        .iter()
                        .find(|(id, _)| Some(*id) == t.inside_merged)
                        .or_else(|| {
                            merged
                                .iter()
                                .find(|(_, r)| places.iter().any(|&(x, y)| near_box(r, x, y)))
                        })
                })
                .flatten()
                .map(|(id, _)| *id);
            t.inside_merged = inside;
        }
    }
}
