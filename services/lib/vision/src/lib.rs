//! Stereoscope's moment engine: the low-level image processing of the thesis "3D information
//! recovery of multiple mobile objects" (chapters 3 and 5), done exactly and fast.
//!
//! - [`image`]: borrowed grey views with a stride (8- and 16-bit), never copying a frame.
//! - [`histogram`]: histograms, automatic thresholds (Otsu, triangle), equalisation.
//! - [`extract`]: every connected bright blob with exact moments in one pass (Eq. 3.33–3.43).
//! - [`moments`]: raw and central moments, orientation with PAR (Eq. 3.44 / 4.14b corrected),
//!   third-order direction, grey-level moments (Eq. 3.1).
//! - `stereoscope_numeric::heading`: continuous 0–360° heading from axis angles (§4.1.1, `track_orientation`).
//! - [`tracker`]: self-adaptive tracking windows for several objects (Eq. 5.1–5.3).
//! - `stereoscope_numeric::assign`: minimum-cost assignment.
//! - [`raster`]: anti-aliased test shapes and noise with known truth.
//! - `weights`: a run's grey-level weight sums (Eq. 3.1), vectorised for 8-bit pixels.
//!
//! Pure: no I/O, no IPC, no global state. Pixel conventions: `docs/conventions.md`; what each
//! module computes: `docs/vision.md`.

pub mod error;
pub mod extract;
pub mod histogram;
pub mod image;
pub mod moments;
pub mod preview;
pub mod raster;
pub mod tracker;
mod weights;

pub use error::VisionError;
pub use extract::{
    Blob, BlobFlags, Connectivity, ExtractConfig, ExtractStats, Extractor, RowSample, Weighting,
    Window,
};
pub use histogram::{Histogram, ThresholdMethod};
pub use image::{GrayImage, GrayView, Pixel, PixelRect};
pub use moments::{CentralMoments, RawMoments};
pub use tracker::{BlobShape, CoreScan, Track, TrackStatus, Tracker, TrackerConfig};
