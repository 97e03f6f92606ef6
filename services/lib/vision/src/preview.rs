//! A frame reduced for people to look at (the viewer's camera monitors, `docs/viewer.md`). Not
//! an algorithm of the thesis and never used for measuring: each preview pixel is the
//! brightest (or, for dark targets, the darkest) of its `scale × scale` block, so a marker
//! a few pixels wide stays visible at a sixth of the size, and a histogram of the frame's
//! levels is counted on the same sparse grid as the thesis lab's histogram display (Fig.
//! 3.2's threshold choice, shown with its threshold line).

use crate::{GrayView, Pixel};

/// A reduced frame: `width × height` 8-bit levels, row by row, and a 256-bin histogram.
#[derive(Debug, Clone, PartialEq)]
pub struct Reduced {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
    pub histogram: Vec<u32>,
}

/// Frame pixels per preview pixel so that the preview is at most `max_width` wide (at least 1).
pub fn scale_for(width: u32, max_width: u32) -> u32 {
    width.div_ceil(max_width.max(1)).max(1)
}

/// Reduces `img` by `scale` in each direction (the last block of a row or column may be
/// narrower), levels shifted right by `shift` to 8 bits; `darkest` keeps each block's minimum
/// instead of its maximum. The histogram counts every `scale`-th pixel of every `scale`-th row.
pub fn reduce<P: Pixel>(img: &GrayView<'_, P>, scale: u32, shift: u32, darkest: bool) -> Reduced {
    let scale = scale.max(1);
    let (w, h) = (img.width(), img.height());
    let (pw, ph) = (w.div_ceil(scale), h.div_ceil(scale));
    let mut pixels = vec![if darkest { u8::MAX } else { 0 }; (pw as usize) * (ph as usize)];
    let mut histogram = vec![0u32; 256];
    let level = |p: P| (p.value() >> shift).min(255) as u8;
    let s = scale as usize;
    for y in 0..h {
        let row = img.row(y);
        let out_row = (y / scale) as usize * pw as usize;
        let out = &mut pixels[out_row..out_row + pw as usize];
        for (o, block) in out.iter_mut().zip(row.chunks(s)) {
            let v = block.iter().fold(*o, |acc, &p| {
                let l = level(p);
                if darkest { acc.min(l) } else { acc.max(l) }
            });
            *o = v;
        }
        if y % scale == 0 {
            for &p in row.iter().step_by(s) {
                histogram[level(p) as usize] += 1;
            }
        }
    }
    Reduced {
        width: pw,
        height: ph,
        pixels,
        histogram,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-pixel marker survives a reduction by 6; a dark one too with `darkest`; the
    /// histogram counts the sparse grid; a 16-bit frame is shifted to 8 bits.
    #[test]
    fn a_small_marker_stays_visible_in_the_preview() {
        let (w, h) = (64u32, 30u32);
        let mut data = vec![20u8; (w * h) as usize];
        data[(13 * w + 40) as usize] = 250;
        let img = GrayView::new(&data, w, h, w as usize).unwrap();
        let r = reduce(&img, 6, 0, false);
        assert_eq!((r.width, r.height), (11, 5));
        assert_eq!(r.pixels[(2 * 11 + 6) as usize], 250);
        assert_eq!(r.pixels.iter().filter(|&&v| v == 250).count(), 1);
        assert_eq!(r.histogram.iter().sum::<u32>(), 11 * 5);
        assert_eq!(r.histogram[20], 11 * 5);
        let mut dark = vec![200u8; (w * h) as usize];
        dark[(29 * w + 63) as usize] = 3;
        let img = GrayView::new(&dark, w, h, w as usize).unwrap();
        let r = reduce(&img, 6, 0, true);
        assert_eq!(r.pixels[(4 * 11 + 10) as usize], 3);
        let deep: Vec<u16> = data.iter().map(|&v| v as u16 * 256 + 17).collect();
        let img = GrayView::new(&deep, w, h, w as usize).unwrap();
        assert_eq!(reduce(&img, 6, 8, false).pixels[(2 * 11 + 6) as usize], 250);
        assert_eq!(scale_for(1920, 320), 6);
        assert_eq!(scale_for(100, 320), 1);
        assert_eq!(scale_for(100, 0), 100);
    }
}
