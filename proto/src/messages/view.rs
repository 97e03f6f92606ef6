//! The messages only people look at (`docs/viewer.md`): a camera's preview image and a live
//! wand calibration's coverage. Checked like every other message before they are used.

use super::{BlobObservation, Checked, Checker, limits};
use serde::{Deserialize, Serialize};

/// A camera's picture for people to look at (`docs/viewer.md`), a few times a second: the
/// frame reduced `scale` times in each direction to 8 bits, each preview pixel the brightest
/// (with `dark`, the darkest) of its `scale × scale` block so that a marker a few pixels wide
/// stays visible; with the frame's threshold, a histogram of its levels and the blobs and
/// tracking windows the worker found in it. It is an image, so it travels in binary
/// (postcard), not JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Preview {
    pub schema: u32,
    pub rig: String,
    pub camera: String,
    pub sequence: u64,
    pub timestamp_ns: u64,
    /// The frame's size.
    pub width_px: u32,
    pub height_px: u32,
    /// Frame pixels per preview pixel, in each direction.
    pub scale: u32,
    /// The preview's size: the frame's divided by `scale`, rounded up.
    pub preview_width_px: u32,
    pub preview_height_px: u32,
    /// The frame's levels are shifted right by this to make the preview's 8 bits (8 for a
    /// 16-bit frame, 0 for an 8-bit one).
    pub level_shift: u32,
    /// The worker's threshold for the frame, in the frame's levels.
    pub threshold: u32,
    /// The worker looks for dark targets on a bright background.
    pub dark: bool,
    /// The frame's levels (shifted by `level_shift`) counted over every `scale`-th pixel of
    /// every `scale`-th row: [`PREVIEW_HISTOGRAM_BINS`] bins.
    pub histogram: Vec<u32>,
    /// `preview_width_px × preview_height_px` levels, row by row.
    pub pixels: Vec<u8>,
    /// The frame's blobs, in the frame's pixels (`Observation::blobs`).
    pub blobs: Vec<BlobObservation>,
}

/// How much of each camera's image a live wand calibration has seen the wand in
/// (`stereoscope calibrate wand --live`, `docs/calibration.md`): each image cut into
/// `cols × rows` cells, counting the wand samples (views with exactly the wand's markers)
/// whose markers fell in each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WandCoverage {
    pub schema: u32,
    pub rig: String,
    pub published_ns: u64,
    /// The share of cells each camera must reach before the solve starts.
    pub target: f64,
    /// Collecting has ended (covered, or out of time).
    pub done: bool,
    pub cameras: Vec<CameraCoverage>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCoverage {
    pub camera: String,
    pub cols: u32,
    pub rows: u32,
    /// Samples per cell, row by row (`cols × rows`).
    pub counts: Vec<u32>,
    /// Share of cells with a sample.
    pub coverage: f64,
    /// Wand samples (frames with exactly the wand's markers in view).
    pub samples: u64,
}

/// Most cells of a coverage grid.
pub const MAX_COVERAGE_CELLS: usize = 4096;

/// Bins of a preview's histogram (one per 8-bit level).
pub const PREVIEW_HISTOGRAM_BINS: usize = 256;

impl Preview {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.name("camera", &self.camera)?;
        let side = limits::MAX_IMAGE_SIDE_PX as f64;
        c.range("width_px", self.width_px as f64, 1.0, side)?;
        c.range("height_px", self.height_px as f64, 1.0, side)?;
        let scale = self.scale as f64;
        c.range("scale", scale, 1.0, limits::MAX_PREVIEW_SCALE as f64)?;
        // The size follows from the frame's and the scale: checked exactly, so the pixels'
        // length below is bounded by the preview side.
        let w = self.width_px.div_ceil(self.scale) as f64;
        let h = self.height_px.div_ceil(self.scale) as f64;
        let pside = limits::MAX_PREVIEW_SIDE_PX as f64;
        c.range(
            "preview_width_px",
            self.preview_width_px as f64,
            w,
            w.min(pside),
        )?;
        c.range(
            "preview_height_px",
            self.preview_height_px as f64,
            h,
            h.min(pside),
        )?;
        let n = (self.preview_width_px as usize) * (self.preview_height_px as usize);
        c.range("pixels", self.pixels.len() as f64, n as f64, n as f64)?;
        let bins = PREVIEW_HISTOGRAM_BINS as f64;
        c.range("histogram", self.histogram.len() as f64, bins, bins)?;
        c.range("level_shift", self.level_shift as f64, 0.0, 8.0)?;
        c.count("blobs", self.blobs.len(), limits::MAX_BLOBS)?;
        for (i, b) in self.blobs.iter().enumerate() {
            c.within(format!("blobs[{i}]"), |c| b.validate(c))?;
        }
        Ok(())
    }
}

impl WandCoverage {
    pub(super) fn validate(&self, c: &mut Checker) -> Checked {
        c.name("rig", &self.rig)?;
        c.range("target", self.target, 0.0, 1.0)?;
        c.count("cameras", self.cameras.len(), limits::MAX_CAMERAS)?;
        for (i, cam) in self.cameras.iter().enumerate() {
            c.within(format!("cameras[{i}]"), |c| {
                c.name("camera", &cam.camera)?;
                let n = cam.cols as usize * cam.rows as usize;
                c.range("cols", n as f64, 1.0, MAX_COVERAGE_CELLS as f64)?;
                c.range("counts", cam.counts.len() as f64, n as f64, n as f64)?;
                c.range("coverage", cam.coverage, 0.0, 1.0)
            })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::messages::{DecodeError, Message, SCHEMA_VERSION};

    fn preview(width: u32, height: u32, scale: u32) -> Preview {
        let (pw, ph) = (width.div_ceil(scale.max(1)), height.div_ceil(scale.max(1)));
        Preview {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            camera: "c".into(),
            sequence: 1,
            timestamp_ns: 2,
            width_px: width,
            height_px: height,
            scale,
            preview_width_px: pw,
            preview_height_px: ph,
            level_shift: 0,
            threshold: 100,
            dark: false,
            histogram: vec![0; PREVIEW_HISTOGRAM_BINS],
            pixels: vec![7; (pw * ph) as usize],
            blobs: Vec::new(),
        }
    }

    /// A preview's size follows from the frame's and its scale, and its pixels from its size:
    /// a preview claiming more than it carries, or a size it cannot have, is refused by field.
    #[test]
    fn a_preview_is_checked_against_its_own_sizes() {
        let p = preview(1920, 1080, 6);
        assert_eq!((p.preview_width_px, p.preview_height_px), (320, 180));
        let bytes = p.to_binary();
        // An image travels in binary: one byte a pixel, not a JSON number.
        assert!(bytes.len() < 320 * 180 + 400, "{}", bytes.len());
        assert_eq!(Preview::from_binary(&bytes).unwrap(), p);
        let field = |p: Preview| match Preview::from_binary(&p.to_binary()) {
            Err(DecodeError::Invalid { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        let mut short = p.clone();
        short.pixels.pop();
        assert_eq!(field(short), "pixels");
        let mut big = p.clone();
        big.preview_width_px = 100_000;
        assert_eq!(field(big), "preview_width_px");
        let mut hist = p.clone();
        hist.histogram.push(1);
        assert_eq!(field(hist), "histogram");
        assert_eq!(field(preview(64, 48, 0)), "scale");
        // A frame too large to preview at a scale is refused, not allocated.
        assert_eq!(field(preview(8000, 100, 1)), "preview_width_px");
    }
}
