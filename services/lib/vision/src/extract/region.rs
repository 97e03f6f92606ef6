//! The region an extraction scans: the union of the tracking windows (or the whole frame) as
//! bands of rows with identical horizontal segments, each segment with its threshold (thesis
//! ch. 5 windows; the overlap counted once). Part of `extract` (module docs there).

use super::*;

// ---------------------------------------------------------------------------------------------
// The region to scan: rows grouped into bands of identical horizontal segments.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Seg {
    pub(super) x0: u32,
    pub(super) x1: u32,
    pub(super) threshold: u32,
    /// The pixel left of `x0` is inside the frame but outside the region.
    pub(super) open_left: bool,
    /// The pixel right of `x1` is inside the frame but outside the region.
    pub(super) open_right: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Band {
    pub(super) y0: u32,
    /// Exclusive.
    pub(super) y1: u32,
    pub(super) segs: (usize, usize),
    /// Row y0 − 1 is not fully covered where this band is (runs on row y0 need a check).
    pub(super) check_top: bool,
    pub(super) check_bottom: bool,
}

#[derive(Debug, Default, Clone)]
pub(super) struct Region {
    pub(super) bands: Vec<Band>,
    pub(super) segs: Vec<Seg>,
    pub(super) width: u32,
    pub(super) height: u32,
    // Scratch for building.
    pub(super) ys: Vec<u32>,
    pub(super) xs: Vec<u32>,
    /// The windows over one band: x extent (end exclusive) and threshold.
    pub(super) active: Vec<(u32, u32, u32)>,
}

pub(super) fn covers(segs: &[Seg], x0: u32, x1: u32) -> bool {
    let mut need = x0;
    for s in segs {
        if s.x1 < need {
            continue;
        }
        if s.x0 > need {
            return false;
        }
        need = s.x1 + 1;
        if need > x1 {
            return true;
        }
    }
    false
}

pub(super) fn check_threshold<P: Pixel>(threshold: u32) -> Result<u32, VisionError> {
    if threshold > P::MAX_VALUE {
        return Err(VisionError::ThresholdOutOfRange {
            threshold,
            bits: P::BITS,
            max: P::MAX_VALUE,
        });
    }
    Ok(threshold)
}

impl Region {
    pub(super) fn full(&mut self, width: u32, height: u32, threshold: u32) {
        self.bands.clear();
        self.segs.clear();
        self.width = width;
        self.height = height;
        self.segs.push(Seg {
            x0: 0,
            x1: width - 1,
            threshold,
            open_left: false,
            open_right: false,
        });
        self.bands.push(Band {
            y0: 0,
            y1: height,
            segs: (0, 1),
            check_top: false,
            check_bottom: false,
        });
    }
}

/// Checks windows before any is used: each must be non-empty, start inside the frame and have
/// a threshold the pixel type can hold. (Windows may reach past the frame's right and bottom
/// edges: they are clipped.)
pub(super) fn check_windows<P: Pixel>(
    windows: &[Window],
    width: u32,
    height: u32,
) -> Result<(), VisionError> {
    for (index, w) in windows.iter().enumerate() {
        let r = w.rect;
        if r.x1 < r.x0 || r.y1 < r.y0 {
            return Err(VisionError::EmptyWindow {
                index,
                x0: r.x0,
                y0: r.y0,
                x1: r.x1,
                y1: r.y1,
            });
        }
        if r.x0 >= width || r.y0 >= height {
            return Err(VisionError::WindowOutsideFrame {
                index,
                x0: r.x0,
                y0: r.y0,
                x1: r.x1,
                y1: r.y1,
                width,
                height,
            });
        }
        if let Some(t) = w.threshold {
            check_threshold::<P>(t)?;
        }
    }
    Ok(())
}

impl Region {
    /// The union of `windows` (checked by [`check_windows`]), clipped to the frame, as bands
    /// of segments.
    pub(super) fn set_windows(
        &mut self,
        windows: &[Window],
        width: u32,
        height: u32,
        threshold: u32,
    ) {
        self.bands.clear();
        self.segs.clear();
        self.width = width;
        self.height = height;
        // One window (a tracked marker's cluster, the common case): one band of one segment,
        // open wherever the frame goes on past it — what the sweep below gives it.
        if let [win] = windows {
            let r = win.rect;
            let (x1, y1) = (r.x1.min(width - 1), r.y1.min(height - 1));
            self.segs.push(Seg {
                x0: r.x0,
                x1,
                threshold: win.threshold.unwrap_or(threshold),
                open_left: r.x0 > 0,
                open_right: x1 + 1 < width,
            });
            self.bands.push(Band {
                y0: r.y0,
                y1: y1 + 1,
                segs: (0, 1),
                check_top: r.y0 > 0,
                check_bottom: y1 + 1 < height,
            });
            return;
        }
        self.sweep(windows, width, height, threshold, true);
    }

    /// [`Region::set_windows`] for any number of windows: the rows where a window starts or
    /// ends cut the frame into bands, each band's elementary x intervals into segments. With
    /// `merge_uniform`, a band whose windows all have one threshold takes the union of their
    /// x extents (what its elementary intervals join into) without cutting it into intervals.
    /// (`bands` and `segs` start empty.)
    fn sweep(
        &mut self,
        windows: &[Window],
        width: u32,
        height: u32,
        threshold: u32,
        merge_uniform: bool,
    ) {
        self.ys.clear();
        for w in windows {
            let r = w.rect;
            self.ys.push(r.y0);
            self.ys.push(r.y1.min(height - 1) + 1);
        }
        self.ys.sort_unstable();
        self.ys.dedup();
        let uniform = merge_uniform && {
            let first = windows.first().map(|w| w.threshold.unwrap_or(threshold));
            windows
                .iter()
                .all(|w| Some(w.threshold.unwrap_or(threshold)) == first)
        };
        for yi in 0..self.ys.len().saturating_sub(1) {
            let (ya, yb) = (self.ys[yi], self.ys[yi + 1]);
            // The windows covering row ya: x extent (end exclusive) and threshold.
            self.active.clear();
            for w in windows {
                let r = w.rect;
                if r.y0 <= ya && r.y1 >= ya {
                    let xe = r.x1.min(width - 1) + 1;
                    self.active
                        .push((r.x0, xe, w.threshold.unwrap_or(threshold)));
                }
            }
            if self.active.is_empty() {
                continue;
            }
            let start = self.segs.len();
            if uniform {
                // One threshold: the segments are the extents' union, touching extents joined
                // (contiguous intervals of one threshold join below too).
                self.active.sort_unstable();
                for &(x0, xe, thr) in &self.active {
                    let in_band = self.segs.len() > start;
                    match self.segs.last_mut() {
                        Some(last) if in_band && x0 <= last.x1 + 1 => {
                            last.x1 = last.x1.max(xe - 1);
                        }
                        _ => self.segs.push(Seg {
                            x0,
                            x1: xe - 1,
                            threshold: thr,
                            open_left: false,
                            open_right: false,
                        }),
                    }
                }
            } else {
                self.band_intervals(start);
            }
            let end = self.segs.len();
            for i in start..end {
                let contiguous_left = i > start && self.segs[i - 1].x1 + 1 == self.segs[i].x0;
                let contiguous_right = i + 1 < end && self.segs[i].x1 + 1 == self.segs[i + 1].x0;
                let s = &mut self.segs[i];
                s.open_left = s.x0 > 0 && !contiguous_left;
                s.open_right = s.x1 + 1 < width && !contiguous_right;
            }
            self.bands.push(Band {
                y0: ya,
                y1: yb,
                segs: (start, end),
                check_top: false,
                check_bottom: false,
            });
        }
        // A band's top row needs a per-run coverage check unless the band above ends right
        // there and covers everything this band covers; likewise at the bottom.
        for b in 0..self.bands.len() {
            let band = self.bands[b];
            let own = &self.segs[band.segs.0..band.segs.1];
            let above_covers = b > 0 && {
                let up = self.bands[b - 1];
                up.y1 == band.y0
                    && own
                        .iter()
                        .all(|s| covers(&self.segs[up.segs.0..up.segs.1], s.x0, s.x1))
            };
            let below_covers = b + 1 < self.bands.len() && {
                let down = self.bands[b + 1];
                down.y0 == band.y1
                    && own
                        .iter()
                        .all(|s| covers(&self.segs[down.segs.0..down.segs.1], s.x0, s.x1))
            };
            self.bands[b].check_top = band.y0 > 0 && !above_covers;
            self.bands[b].check_bottom = band.y1 < height && !below_covers;
        }
    }

    /// One band's segments from the elementary x intervals of its windows (`active`), each
    /// at the least threshold of the windows over it, pushed to `segs` from `start`.
    fn band_intervals(&mut self, start: usize) {
        self.xs.clear();
        for &(x0, xe, _) in &self.active {
            self.xs.push(x0);
            self.xs.push(xe);
        }
        self.xs.sort_unstable();
        self.xs.dedup();
        for xi in 0..self.xs.len() - 1 {
            let (xa, xb) = (self.xs[xi], self.xs[xi + 1]);
            let mut thr: Option<u32> = None;
            for &(x0, xe, t) in &self.active {
                if x0 <= xa && xe >= xb {
                    thr = Some(thr.map_or(t, |u| u.min(t)));
                }
            }
            let Some(thr) = thr else { continue };
            let in_band = self.segs.len() > start;
            match self.segs.last_mut() {
                Some(last) if in_band && last.x1 + 1 == xa && last.threshold == thr => {
                    last.x1 = xb - 1;
                }
                _ => self.segs.push(Seg {
                    x0: xa,
                    x1: xb - 1,
                    threshold: thr,
                    open_left: false,
                    open_right: false,
                }),
            }
        }
    }

    pub(super) fn rows(&self) -> (u32, u32) {
        match (self.bands.first(), self.bands.last()) {
            (Some(f), Some(l)) => (f.y0, l.y1),
            _ => (0, 0),
        }
    }

    pub(super) fn pixel_count(&self) -> u64 {
        self.bands
            .iter()
            .map(|b| {
                let w: u64 = self.segs[b.segs.0..b.segs.1]
                    .iter()
                    .map(|s| (s.x1 - s.x0 + 1) as u64)
                    .sum();
                w * (b.y1 - b.y0) as u64
            })
            .sum()
    }

    /// Whether a run on row `y` of band `bi` may continue above or below the region.
    pub(super) fn vertically_clipped(&self, bi: usize, y: u32, x0: u32, x1: u32) -> bool {
        let band = &self.bands[bi];
        if band.check_top && y == band.y0 {
            let covered = bi > 0 && {
                let up = &self.bands[bi - 1];
                up.y1 == y && covers(&self.segs[up.segs.0..up.segs.1], x0, x1)
            };
            if !covered {
                return true;
            }
        }
        if band.check_bottom && y + 1 == band.y1 {
            let covered = bi + 1 < self.bands.len() && {
                let down = &self.bands[bi + 1];
                down.y0 == band.y1 && covers(&self.segs[down.segs.0..down.segs.1], x0, x1)
            };
            if !covered {
                return true;
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_window_is_the_band_the_sweep_gives_it() {
        let mut rng = stereoscope_numeric::SplitMix64::new(11);
        let (width, height) = (97u32, 61u32);
        let mut fast = Region::default();
        for i in 0..5000 {
            let pick = |rng: &mut stereoscope_numeric::SplitMix64, n: u32| {
                (rng.uniform() * n as f64) as u32 % n
            };
            let (x0, y0) = (pick(&mut rng, width), pick(&mut rng, height));
            // Windows may reach past the frame's right and bottom edges (clipped).
            let rect = PixelRect {
                x0,
                y0,
                x1: x0 + pick(&mut rng, width + 10 - x0),
                y1: y0 + pick(&mut rng, height + 10 - y0),
            };
            let threshold = (i % 3 == 0).then_some(7 + i % 5);
            let win = [Window { rect, threshold }];
            fast.set_windows(&win, width, height, 100);
            let mut swept = Region::default();
            swept.sweep(&win, width, height, 100, false);
            assert_eq!(fast.segs, swept.segs, "{rect:?}");
            assert_eq!(fast.bands, swept.bands, "{rect:?}");
            assert_eq!(fast.pixel_count(), swept.pixel_count());
        }
    }

    /// Windows of one threshold (the tracker's, unless per-window thresholds are set) give
    /// the segments the elementary intervals give: overlapping, touching, apart, clipped.
    #[test]
    fn one_threshold_bands_are_the_union_the_intervals_give() {
        let mut rng = stereoscope_numeric::SplitMix64::new(29);
        let (width, height) = (80u32, 50u32);
        let pick = |rng: &mut stereoscope_numeric::SplitMix64, n: u32| {
            (rng.uniform() * n as f64) as u32 % n
        };
        let mut merged_bands = 0;
        for i in 0..4000 {
            let n = 2 + i % 6;
            let windows: Vec<Window> = (0..n)
                .map(|_| {
                    let (x0, y0) = (pick(&mut rng, width), pick(&mut rng, height));
                    let rect = PixelRect {
                        x0,
                        y0,
                        x1: x0 + pick(&mut rng, 30),
                        y1: y0 + pick(&mut rng, 25),
                    };
                    // Some with the frame's threshold written out, some left to it.
                    let threshold = (pick(&mut rng, 2) == 0).then_some(40);
                    Window { rect, threshold }
                })
                .collect();
            let (mut merged, mut intervals) = (Region::default(), Region::default());
            merged.sweep(&windows, width, height, 40, true);
            intervals.sweep(&windows, width, height, 40, false);
            assert_eq!(merged.segs, intervals.segs, "{windows:?}");
            assert_eq!(merged.bands, intervals.bands, "{windows:?}");
            merged_bands += merged.bands.len();
        }
        assert!(merged_bands > 4000);
    }
}
