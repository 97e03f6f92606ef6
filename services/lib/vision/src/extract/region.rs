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

#[derive(Debug, Clone, Copy)]
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
        self.ys.clear();
        for w in windows {
            let r = w.rect;
            self.ys.push(r.y0);
            self.ys.push(r.y1.min(height - 1) + 1);
        }
        self.ys.sort_unstable();
        self.ys.dedup();
        for yi in 0..self.ys.len().saturating_sub(1) {
            let (ya, yb) = (self.ys[yi], self.ys[yi + 1]);
            // Elementary x intervals of the windows covering row ya.
            self.xs.clear();
            for w in windows {
                let r = w.rect;
                if r.y0 <= ya && r.y1 >= ya {
                    self.xs.push(r.x0);
                    self.xs.push(r.x1.min(width - 1) + 1);
                }
            }
            if self.xs.is_empty() {
                continue;
            }
            self.xs.sort_unstable();
            self.xs.dedup();
            let start = self.segs.len();
            for xi in 0..self.xs.len() - 1 {
                let (xa, xb) = (self.xs[xi], self.xs[xi + 1]);
                let mut thr: Option<u32> = None;
                for w in windows {
                    let r = w.rect;
                    if r.y0 <= ya && r.y1 >= ya && r.x0 <= xa && r.x1.min(width - 1) + 1 >= xb {
                        let t = w.threshold.unwrap_or(threshold);
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
