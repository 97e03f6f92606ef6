//! The windowed step's cores: each object found in the last frame is read first where its
//! blob must be, and its whole Eq. 5.1 window only when that does not settle the frame.
//!
//! Thesis: chapter 5, Eq. 5.1–5.3 (the windows this reads less of, and the motion that moves
//! each core); not a thesis method itself — the thesis read every window whole.

use super::{Track, Tracker, round_half_away};
use crate::extract::Window;
use crate::image::{GrayView, Pixel, PixelRect};
use stereoscope_numeric::cheapest_allowed;

/// The windowed step's reading of the cores
/// ([`TrackerConfig::core_scan`](super::TrackerConfig::core_scan)).
///
/// An object's Eq. 5.1 window is about 4.6 √area wide, some 20 times the object's own area:
/// room for it to move. Where it was found in the last frame, its next blob lies near its last
/// box moved by its motion, and reading that core instead of the window reads a fifth of the
/// pixels. What the window holds outside the core is left unread only when it cannot change
/// what the step does: the cores settle a frame when no region found touches a core's edge
/// inside the frame (every blob found is whole, the same blob the windows would give), every
/// object read in its core has a blob in its window, no two objects have the same nearest blob
/// (so the minimum-cost assignment gives each its nearest), and each nearest centroid is
/// nearer its object's prediction than any edge of its core inside the frame. A blob outside
/// the cores has its pixels, and so its centroid, beyond those edges — unless it wraps round a
/// core on opposite sides without touching it, the one case the windows would see and the
/// cores not. Otherwise the windows are read as without cores. A search (periodic, or a lost
/// object's) reads the cores when its test finds nothing bright outside them (every blob
/// there is then in them, in the rows it reads), and they settle its frame when no region
/// touches a core's edge inside the frame. Per-window thresholds read the windows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CoreScan {
    /// The windows were read (a search that found something outside the cores, a lost
    /// object only, per-window thresholds, or `core_scan` off).
    #[default]
    Windows,
    /// The cores settled the frame; the windows were not read.
    Settled,
    /// The cores were read and did not settle the frame; the windows were read after them.
    Widened,
}

/// A core's margin around the last box moved by the motion: this many pixels, plus half
/// the motion (`|vx| + |vy|`) and an eighth of the box's longer side.
pub const CORE_MARGIN_PX: i64 = 3;

/// A track's core for this frame ([`CoreScan`]): its last blob's box moved by its motion,
/// widened by [`CORE_MARGIN_PX`] plus half the motion and an eighth of the box's longer
/// side, inside its window. `None` for a track not found in the last frame.
pub(super) fn core_rect(t: &Track) -> Option<PixelRect> {
    if t.lost_frames > 0 {
        return None;
    }
    let bb = t.blob.as_ref()?.bbox;
    let (dx, dy) = (round_half_away(t.vx_px), round_half_away(t.vy_px));
    let side = bb.width().max(bb.height()) as i64;
    let margin = CORE_MARGIN_PX
        .saturating_add(dx.saturating_abs().saturating_add(dy.saturating_abs()) / 2)
        .saturating_add(side / 8);
    let win = t.window;
    let lo = |edge: u32, shift: i64, bound: u32| {
        (edge as i64)
            .saturating_add(shift)
            .saturating_sub(margin)
            .max(bound as i64)
    };
    let hi = |edge: u32, shift: i64, bound: u32| {
        (edge as i64)
            .saturating_add(shift)
            .saturating_add(margin)
            .min(bound as i64)
    };
    let (x0, x1) = (lo(bb.x0, dx, win.x0), hi(bb.x1, dx, win.x1));
    let (y0, y1) = (lo(bb.y0, dy, win.y0), hi(bb.y1, dy, win.y1));
    // Inside the window, so inside the frame: the bounds fit in u32.
    (x0 <= x1 && y0 <= y1).then_some(PixelRect {
        x0: x0 as u32,
        y0: y0 as u32,
        x1: x1 as u32,
        y1: y1 as u32,
    })
}

impl Tracker {
    /// Each track's core, or its window for a track without one (none for a lost track
    /// whose window covers the `w × h` frame: that is what a search reads; none for a
    /// resting one); `true` when at least one track has a core.
    pub(super) fn set_cores(&mut self, w: u32, h: u32) -> bool {
        self.core_rects.clear();
        self.core_rects.extend(self.tracks.iter().map(core_rect));
        self.cores.clear();
        self.cores
            .extend(
                self.core_rects
                    .iter()
                    .zip(&self.tracks)
                    .filter_map(|(core, t)| match core {
                        Some(c) => Some(Window::new(*c)),
                        None if t.resting => None,
                        None if t.window.width() == w && t.window.height() == h => None,
                        None => Some(Window::new(t.window)),
                    }),
            );
        self.core_rects.iter().any(Option::is_some)
    }

    /// Asks the CPU for every line of the cores' rows before any is read: a core's rows lie
    /// a frame's stride apart, each its own miss when the frame is not in the cache (a
    /// frame just written by another process, or read after others), and asked for
    /// together their fetches overlap instead of each waiting for the last (live bench,
    /// 640 × 480, 9 alternations: 4 % less time a frame with the markers, 12 % with the
    /// targets, from memory). The windows of a search are not asked for: no gain measured.
    pub(super) fn prefetch_cores<P: Pixel>(&self, img: &GrayView<'_, P>) {
        for c in &self.cores {
            img.prefetch_rect(c.rect);
        }
    }

    /// Whether the cores just read settle the frame ([`CoreScan`]), from the costs of their
    /// blobs in a `w × h` frame; each track's nearest blob goes into `nearest` (complete when
    /// this is true: the step's assignment then).
    pub(super) fn cores_settle(&mut self, w: u32, h: u32) -> bool {
        if self.extractor.stats().clipped_regions > 0 {
            return false;
        }
        let n = self.centroids.len();
        self.nearest_taken.clear();
        self.nearest_taken.resize(n, false);
        self.nearest.clear();
        for (i, t) in self.tracks.iter().enumerate() {
            let row = &self.cost[i * n..(i + 1) * n];
            let nearest = cheapest_allowed(row).map(|j| (j, &row[j]));
            self.nearest.push(nearest.map(|(j, _)| j));
            let core = self.core_rects[i];
            let Some((j, &cost)) = nearest else {
                // A track read in its whole window may stay lost; one read in its core not.
                if core.is_some() {
                    return false;
                }
                continue;
            };
            if std::mem::replace(&mut self.nearest_taken[j], true) {
                return false;
            }
            if let Some(core) = core {
                let (px, py) = t.predicted();
                let mut r = f64::INFINITY;
                if core.x0 > 0 {
                    r = r.min(px - core.x0 as f64);
                }
                if core.x1 + 1 < w {
                    r = r.min(core.x1 as f64 - px);
                }
                if core.y0 > 0 {
                    r = r.min(py - core.y0 as f64);
                }
                if core.y1 + 1 < h {
                    r = r.min(core.y1 as f64 - py);
                }
                if !(r > 0.0 && cost < r * r) {
                    return false;
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::super::{TrackStatus, TrackerConfig};
    use super::*;
    use crate::extract::{ExtractConfig, Weighting};
    use crate::image::GrayImage;
    use crate::raster::{Ellipse, draw_ellipse};

    /// A 640 × 480 frame of discs `(x, y, radius)`.
    fn frame(discs: &[(f64, f64, f64)]) -> GrayImage<u8> {
        super::super::tests::discs_frame(640, 480, 12, 220, discs)
    }

    /// Frame `f` of a scene with what the cores must handle: steady motion, a circle (the
    /// motion turns every frame), a double ball turning (a heading), two markers crossing
    /// (merged, one lost inside the other), a marker hidden for six frames, one that reverses
    /// at once, one that appears at frame 25, and a bright blob no track may take (one more
    /// than `max_objects`) sweeping through the others' windows.
    fn scene(f: u64) -> Vec<(f64, f64, f64)> {
        let t = f as f64;
        let (s, c) = (0.09 * t).sin_cos();
        let (hs, hc) = (0.05 * t).sin_cos();
        let mut d = vec![
            (60.0 + 4.0 * t, 60.0 + 1.5 * t, 6.0),
            (320.0 + 120.0 * c, 240.0 + 120.0 * s, 5.0),
            (480.0 + 0.5 * t, 380.0, 9.0),
            (480.0 + 0.5 * t + 12.0 * hc, 380.0 + 12.0 * hs, 4.0),
            (100.0 + 5.0 * t, 300.0, 5.0),
            (400.0 - 5.0 * t, 303.0, 5.0),
        ];
        if !(40..46).contains(&f) {
            d.push((560.0, 100.0 + 2.0 * t, 6.0));
        }
        let jump = if f < 30 { 6.0 * t } else { 360.0 - 6.0 * t };
        d.push((200.0 + jump, 420.0, 5.0));
        if f >= 25 {
            d.push((40.0, 440.0, 7.0));
        }
        d.push((150.0 + 6.0 * t, 80.0 + 3.0 * t, 4.0));
        d
    }

    /// The cores change nothing the step does: the same tracks — ids, states, centroids,
    /// blobs, headings, windows — on every frame as with the windows read whole, for binary
    /// and coverage moments; most frames are settled by the cores and some are not.
    #[test]
    fn cores_give_the_tracks_the_whole_windows_give() {
        for weighting in [
            Weighting::Binary,
            Weighting::Coverage {
                background: 12,
                full: 200,
            },
        ] {
            let extract = ExtractConfig {
                weighting,
                ..ExtractConfig::default()
            };
            let cfg = TrackerConfig {
                max_objects: 9,
                ..TrackerConfig::default()
            };
            let mut cored = Tracker::new(cfg, extract).unwrap();
            let mut whole = Tracker::new(
                TrackerConfig {
                    core_scan: false,
                    ..cfg
                },
                extract,
            )
            .unwrap();
            let (mut settled, mut widened, mut lost) = (0, 0, 0);
            let mut settled_in_search = 0;
            for f in 0..90 {
                let img = frame(&scene(f));
                let a = cored.step_frame(img.view(), 110, f).unwrap();
                let b = whole.step_frame(img.view(), 110, f).unwrap();
                assert_eq!(b.cores, CoreScan::Windows);
                assert_eq!(
                    (a.full_frame, a.tracked, a.lost, a.new, a.dropped),
                    (b.full_frame, b.tracked, b.lost, b.new, b.dropped),
                    "frame {f}"
                );
                assert_eq!(
                    format!("{:?}", cored.tracks()),
                    format!("{:?}", whole.tracks()),
                    "frame {f}"
                );
                match a.cores {
                    CoreScan::Settled => {
                        settled += 1;
                        // Less than half the pixels, but for a lost object's window (read
                        // whole in either, growing).
                        let (pa, pb) = (a.extract.pixels_scanned, b.extract.pixels_scanned);
                        assert!(pa <= pb, "frame {f}: {a:?} {b:?}");
                        assert!(a.lost > 0 || pa * 2 < pb, "frame {f}: {a:?} {b:?}");
                        settled_in_search += usize::from(a.full_frame);
                    }
                    CoreScan::Widened => widened += 1,
                    CoreScan::Windows => {}
                }
                lost += a.lost;
            }
            assert_eq!(cored.tracks().len(), 9);
            assert!(lost > 0, "the scene loses objects");
            assert!(settled >= 50, "{settled} frames settled");
            assert!(widened >= 3, "{widened} frames widened");
            // Searches that found nothing outside the cores read only those.
            assert!(
                settled_in_search >= 5,
                "{settled_in_search} searches settled"
            );
        }
    }

    /// A search that finds nothing outside the cores reads only them, but not when a blob
    /// reaches a core's edge: a streak from a marker down past its core, out of it only on a
    /// row the search does not read, makes the step read the windows, which find it whole.
    #[test]
    fn a_search_in_the_cores_widens_for_a_blob_a_core_cuts() {
        let cfg = TrackerConfig {
            max_objects: 4,
            search_every_frames: 10,
            ..TrackerConfig::default()
        };
        let mut tested = 0;
        for y in [100.0, 101.0] {
            let discs = [(100.0, y, 5.0), (300.0, 300.0, 5.0)];
            let mut cored = Tracker::new(cfg, ExtractConfig::default()).unwrap();
            let mut whole = Tracker::new(
                TrackerConfig {
                    core_scan: false,
                    ..cfg
                },
                ExtractConfig::default(),
            )
            .unwrap();
            for f in 0..10 {
                cored.step_frame(frame(&discs).view(), 110, f).unwrap();
                whole.step_frame(frame(&discs).view(), 110, f).unwrap();
            }
            // Frame 10's search reads the odd rows (period 1, every 2nd row at 480 rows).
            let core = core_rect(&cored.tracks()[0]).unwrap();
            let below = core.y1 as usize + 1;
            if below % 2 == 1 {
                continue;
            }
            let mut img = frame(&discs);
            for row in y as usize..=below {
                img.as_mut_slice()[row * 640 + 100] = 220;
            }
            let a = cored.step_frame(img.view(), 110, 10).unwrap();
            let b = whole.step_frame(img.view(), 110, 10).unwrap();
            assert!(a.full_frame && b.full_frame);
            assert_eq!(a.cores, CoreScan::Widened);
            assert_eq!(
                format!("{:?}", cored.tracks()),
                format!("{:?}", whole.tracks())
            );
            // The same frame without the streak's last row: the cores settle it.
            img.as_mut_slice()[below * 640 + 100] = 12;
            let a = cored.step_frame(img.view(), 110, 20).unwrap();
            assert!(a.full_frame);
            assert_eq!(a.cores, CoreScan::Settled);
            tested += 1;
        }
        assert_eq!(tested, 1);
    }

    /// Each way the cores may fail to settle a frame, alone: a blob cut by a core's edge,
    /// a track with no blob in its core, two tracks with the same nearest blob, and a nearest
    /// blob further from the prediction than the core's edge.
    #[test]
    fn each_unsettled_case_reads_the_windows() {
        let cfg = TrackerConfig {
            max_objects: 2,
            search_every_frames: 1000,
            ..TrackerConfig::default()
        };
        let run = |frames: &[Vec<(f64, f64, f64)>]| {
            let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
            let mut last = CoreScan::Windows;
            for (f, d) in frames.iter().enumerate() {
                last = tr.step_frame(frame(d).view(), 110, f as u64).unwrap().cores;
            }
            (last, tr)
        };
        let still = vec![(100.0, 100.0, 5.0), (300.0, 300.0, 5.0)];
        // Settled while nothing moves.
        let (s, _) = run(&[still.clone(), still.clone(), still.clone()]);
        assert_eq!(s, CoreScan::Settled);
        // A jump of 12 pixels: the blob is cut by its core's edge (the core is the last box
        // widened by 3 + 1 px), found whole in the window.
        let jumped = vec![(112.0, 100.0, 5.0), (300.0, 300.0, 5.0)];
        let (s, tr) = run(&[still.clone(), still.clone(), jumped]);
        assert_eq!(s, CoreScan::Widened);
        assert!(tr.tracks().iter().all(|t| t.status == TrackStatus::Tracked));
        assert!((tr.tracks()[0].x_px - 112.0).abs() < 0.1);
        // A jump of 25 pixels: the core holds nothing, the window the whole blob.
        let far = vec![(125.0, 100.0, 5.0), (300.0, 300.0, 5.0)];
        let (s, tr) = run(&[still.clone(), still.clone(), far]);
        assert_eq!(s, CoreScan::Widened);
        assert!((tr.tracks()[0].x_px - 125.0).abs() < 0.1);
        // The object gone, a dot inside its core 14 px below the prediction and one outside
        // it 11 px to the right: the windows give the track the nearer, outside one.
        let tall = |img: &mut GrayImage<u8>| {
            let e = Ellipse {
                semi_major: 12.0,
                semi_minor: 3.0,
                angle_deg: 90.0,
                ..Ellipse::disc(100.0, 100.0, 1.0)
            };
            draw_ellipse(img, &e, 1.0, 12.0, 220.0, 4);
        };
        let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        for f in 0..2 {
            let mut img = frame(&still[1..]);
            tall(&mut img);
            tr.step_frame(img.view(), 110, f).unwrap();
        }
        let core = core_rect(&tr.tracks()[0]).unwrap();
        assert!(core.contains(100.0, 114.0) && !core.contains(111.0, 100.0));
        let img = frame(&[(100.0, 114.0, 1.0), (111.0, 100.0, 1.0), still[1]]);
        let s = tr.step_frame(img.view(), 110, 2).unwrap().cores;
        assert_eq!(s, CoreScan::Widened);
        assert!(
            (tr.tracks()[0].x_px - 111.0).abs() < 0.1,
            "{:?}",
            tr.tracks()[0]
        );
        // Two tracks side by side, both objects gone and one dot between them, in both cores:
        // the same nearest blob for both.
        let near = vec![(100.0, 100.0, 4.0), (114.0, 100.0, 4.0)];
        let mut tr = Tracker::new(cfg, ExtractConfig::default()).unwrap();
        for f in 0..2 {
            tr.step_frame(frame(&near).view(), 110, f).unwrap();
        }
        let (a, b) = (
            core_rect(&tr.tracks()[0]).unwrap(),
            core_rect(&tr.tracks()[1]).unwrap(),
        );
        assert!(a.contains(107.0, 100.0) && b.contains(107.0, 100.0));
        let s = tr
            .step_frame(frame(&[(107.0, 100.0, 1.0)]).view(), 110, 2)
            .unwrap()
            .cores;
        assert_eq!(s, CoreScan::Widened);
    }

    /// A core is the last box moved by the motion and widened, inside the window, and only
    /// for a track found in the last frame.
    #[test]
    fn a_core_is_the_moved_box_widened_inside_the_window() {
        let mut tr = Tracker::new(TrackerConfig::default(), ExtractConfig::default()).unwrap();
        tr.step_frame(frame(&[(100.0, 100.0, 5.0)]).view(), 110, 0)
            .unwrap();
        tr.step_frame(frame(&[(108.0, 100.0, 5.0)]).view(), 110, 1)
            .unwrap();
        let t = &tr.tracks()[0];
        let bb = t.blob.unwrap().bbox;
        assert_eq!(bb.width(), 11);
        // Motion (8, 0): shifted by 8, widened by 3 + 8 / 2 + 11 / 8 = 8.
        let core = core_rect(t).unwrap();
        assert_eq!(
            (core.x0, core.x1, core.y0, core.y1),
            (bb.x0 + 8 - 8, bb.x1 + 8 + 8, bb.y0 - 8, bb.y1 + 8)
        );
        let mut lost = t.clone();
        lost.lost_frames = 1;
        assert_eq!(core_rect(&lost), None);
        // Clipped to the window, also for a motion far beyond it.
        let mut wild = t.clone();
        wild.vx_px = 1e12;
        let c = core_rect(&wild).unwrap_or(t.window);
        assert!(c.x0 >= t.window.x0 && c.x1 <= t.window.x1);
    }
}
