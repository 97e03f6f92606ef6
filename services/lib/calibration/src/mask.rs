//! Masks (`calibrate mask`, `docs/calibration.md`, "Masks"): the places of an image where
//! what is bright is not a marker, as rectangles from the blobs the moment workers report while
//! nothing should be in view — each blob's box grown by a margin, touching ones joined. The
//! command line listens, reports and writes the rig.

use std::collections::BTreeMap;
use stereoscope_proto::messages::{Observation, TrackState};

/// A rectangle `[x0, y0, x1, y1]`, pixels, inclusive.
pub type Rect = [u32; 4];

fn overlap(a: &Rect, b: &Rect) -> bool {
    a[0] <= b[2] + 1 && b[0] <= a[2] + 1 && a[1] <= b[3] + 1 && b[1] <= a[3] + 1
}

/// Joins touching or overlapping rectangles until none touch.
pub fn join(mut rects: Vec<Rect>) -> Vec<Rect> {
    loop {
        let mut joined = false;
        let mut out: Vec<Rect> = Vec::with_capacity(rects.len());
        for r in rects {
            match out.iter_mut().find(|o| overlap(o, &r)) {
                Some(o) => {
                    *o = [
                        o[0].min(r[0]),
                        o[1].min(r[1]),
                        o[2].max(r[2]),
                        o[3].max(r[3]),
                    ];
                    joined = true;
                }
                None => out.push(r),
            }
        }
        rects = out;
        if !joined {
            rects.sort();
            return rects;
        }
    }
}

/// Each camera's blobs of `observations` as grown, joined rectangles inside its image.
pub fn rectangles(
    observations: &[Observation],
    size_of: impl Fn(&str) -> Option<[u32; 2]>,
    grow_px: u32,
) -> BTreeMap<String, Vec<Rect>> {
    let mut per: BTreeMap<String, Vec<Rect>> = BTreeMap::new();
    for o in observations {
        let Some([w, h]) = size_of(&o.camera) else {
            continue;
        };
        let rects = per.entry(o.camera.clone()).or_default();
        for b in o.blobs.iter().filter(|b| b.status != TrackState::Lost) {
            let [x0, y0, x1, y1] = b.bbox_px;
            rects.push([
                x0.saturating_sub(grow_px),
                y0.saturating_sub(grow_px),
                x1.saturating_add(grow_px).min(w - 1),
                y1.saturating_add(grow_px).min(h - 1),
            ]);
        }
    }
    per.into_iter().map(|(k, v)| (k, join(v))).collect()
}

/// Percent of a `w × h` image the rectangles (which do not overlap) cover.
pub fn share_pct(rects: &[Rect], w: u32, h: u32) -> f64 {
    let px: u64 = rects
        .iter()
        .map(|r| (r[2] - r[0] + 1) as u64 * (r[3] - r[1] + 1) as u64)
        .sum();
    100.0 * px as f64 / (w as f64 * h as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{BlobObservation, SCHEMA_VERSION};

    #[test]
    fn touching_rectangles_are_joined() {
        assert_eq!(
            join(vec![
                [0, 0, 4, 4],
                [5, 0, 9, 2],
                [20, 20, 21, 21],
                [3, 3, 6, 6]
            ]),
            vec![[0, 0, 9, 6], [20, 20, 21, 21]]
        );
        assert_eq!(share_pct(&[[0, 0, 9, 9]], 100, 10), 10.0);
    }

    /// Each camera's blobs grown by the margin and kept inside its image; a lost track and a
    /// camera the rig does not have give nothing.
    #[test]
    fn blobs_become_grown_rectangles_inside_the_image() {
        let blob = |bbox_px: [u32; 4], status: TrackState| BlobObservation {
            track_id: 1,
            status,
            area_px: 10.0,
            x_px: 0.0,
            y_px: 0.0,
            mu20: 0.0,
            mu02: 0.0,
            mu11: 0.0,
            orientation_deg: 0.0,
            roundness: 1.0,
            heading_deg: 0.0,
            directed: false,
            heading_ambiguous: false,
            clipped: false,
            merged: false,
            window_px: bbox_px,
            bbox_px,
        };
        let obs = |camera: &str, blobs: Vec<BlobObservation>| Observation {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            camera: camera.into(),
            sequence: 0,
            timestamp_ns: 0,
            frame_published_ns: 0,
            published_ns: 0,
            width_px: 64,
            height_px: 48,
            threshold: 100,
            dark: false,
            full_frame: true,
            dropped_blobs: 0,
            blobs,
        };
        let got = rectangles(
            &[
                obs("cam0", vec![blob([1, 1, 4, 4], TrackState::Tracked)]),
                obs("cam0", vec![blob([60, 40, 63, 47], TrackState::New)]),
                obs("cam0", vec![blob([30, 20, 31, 21], TrackState::Lost)]),
                obs("cam9", vec![blob([1, 1, 2, 2], TrackState::Tracked)]),
            ],
            |c| (c == "cam0").then_some([64, 48]),
            3,
        );
        assert_eq!(got.len(), 1);
        assert_eq!(got["cam0"], vec![[0, 0, 7, 7], [57, 37, 63, 47]]);
    }
}
