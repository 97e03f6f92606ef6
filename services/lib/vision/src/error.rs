//! The vision library's typed errors. Each names the offending value so a caller can say
//! exactly what was wrong with its input.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum VisionError {
    #[error("image is empty ({width}×{height} pixels)")]
    EmptyImage { width: u32, height: u32 },
    #[error("image {width}×{height} is larger than the supported {max}×{max}")]
    ImageTooLarge { width: u32, height: u32, max: u32 },
    #[error("row stride {stride} is smaller than the image width {width}")]
    StrideTooSmall { stride: usize, width: u32 },
    #[error(
        "pixel buffer holds {len} pixels but a {width}×{height} image with stride {stride} needs {needed}"
    )]
    BufferTooShort {
        len: usize,
        needed: usize,
        width: u32,
        height: u32,
        stride: usize,
    },
    #[error("threshold {threshold} is out of range for {bits}-bit pixels (0..={max})")]
    ThresholdOutOfRange { threshold: u32, bits: u32, max: u32 },
    #[error("window {index} has zero size (x {x0}..={x1}, y {y0}..={y1})")]
    EmptyWindow {
        index: usize,
        x0: u32,
        y0: u32,
        x1: u32,
        y1: u32,
    },
    #[error(
        "window {index} (x {x0}..={x1}, y {y0}..={y1}) lies outside the {width}×{height} frame"
    )]
    WindowOutsideFrame {
        index: usize,
        x0: u32,
        y0: u32,
        x1: u32,
        y1: u32,
        width: u32,
        height: u32,
    },
    #[error(
        "background level {background} must be below the threshold {threshold} for intensity-weighted moments"
    )]
    BackgroundNotBelowThreshold { background: u32, threshold: u32 },
    #[error("pixel aspect ratio {par} must be a finite number above zero")]
    InvalidPixelAspectRatio { par: f64 },
    #[error("invalid tracker setting {field} = {value}: {reason}")]
    InvalidTrackerConfig {
        field: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("histogram is empty: no pixels were counted")]
    EmptyHistogram,
}
