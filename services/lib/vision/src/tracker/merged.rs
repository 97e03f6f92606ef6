//! Merged images: two objects whose blobs joined in this view. The track that keeps the blob
//! is flagged merged (its centroid is between the two and measures neither); the one lost
//! inside it rests — no window of its own, no whole-frame search but on each search period's
//! first frame — and competes for the blob that comes out of the merged one (module docs of
//! `tracker`). A merge lasts while a lost track is inside it.
//!
//! Thesis: chapter 5 (the windows and the search these spare); not a thesis method itself —
//! the thesis tracked objects that never crossed in the image.

use super::{TrackStatus, Tracker};
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
    /// After the assignment: which blobs are merged, each track's usual area, and which lost
    /// tracks are inside a merged blob.
    ///
    /// A blob is merged when another track is lost inside it and it grew by at least half that
    /// track's usual area (a small marker swallowed by a big blob moves its centroid as much as
    /// two alike) or far above its own usual area; it stays merged while it stays above its
    /// usual area and a lost track is still inside it (the lost track's last place falls
    /// behind as the pair moves on). Such a
    /// track keeps its usual area (a merge is not growth). A lost track is inside a merged blob
    /// while the one it went into stays merged (its own prediction runs on past it
    /// meanwhile), or newly at its last or predicted place; it keeps its offset from that
    /// blob's centroid, where it is predicted while inside.
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
        // The tracks a lost one is still inside (from the last frame's flags): a merge lasts
        // only while it holds one, so a blob flagged once is not flagged for good.
        let holding: Vec<u32> = self
            .tracks
            .iter()
            .filter(|t| t.status == TrackStatus::Lost)
            .filter_map(|t| t.inside_merged)
            .collect();
        for t in &mut self.tracks {
            let Some(b) = &t.blob else { continue };
            let area = b.area_px() as f64;
            let usual = t.usual_area_px;
            let r = b.bbox;
            let still = t.merged && area >= MERGE_KEEP_RATIO * usual && holding.contains(&t.id);
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
        // Each merged track's id, blob box and centroid.
        let merged: Vec<_> = self
            .tracks
            .iter()
            .filter(|m| m.merged)
            .filter_map(|m| Some((m.id, m.blob.as_ref()?.bbox, (m.x_px, m.y_px))))
            .collect();
        for t in &mut self.tracks {
            let places = [(t.x_px, t.y_px), t.predicted()];
            let stays = merged.iter().find(|(id, ..)| Some(*id) == t.inside_merged);
            let inside = (t.status == TrackStatus::Lost)
                .then(|| {
                    stays.or_else(|| {
                        merged
                            .iter()
                            .find(|(_, r, _)| places.iter().any(|&(x, y)| near_box(r, x, y)))
                    })
                })
                .flatten();
            // Newly inside: its place in the merged blob, from that blob's centroid.
            if let Some(&(id, _, (mx, my))) = inside
                && Some(id) != t.inside_merged
            {
                t.merge_offset_px = (t.x_px - mx, t.y_px - my);
            }
            t.inside_merged = inside.map(|(id, ..)| *id);
        }
    }
}
