//! Stereoscope's geometry: the camera model, calibration and 3D recovery of the thesis
//! "3D information recovery of multiple mobile objects" (chapters 2 and 4), corrected and
//! extended to any number of calibrated cameras. Pure: no I/O.
//!
//! - [`transform`]: homogeneous transforms (Eq. 2.2–2.3), the camera placement of §2.3.1,
//!   objects in camera coordinates (Eq. 2.13).
//! - [`camera`]: the pinhole camera with distortion (Eq. 2.4–2.8).
//! - [`calibrate`]: calibration of one camera or a rig from target correspondences (§2.2.3).
//! - [`dotgrid`]: a dot-grid target, rendered and detected with the moment engine.
//! - [`lm`]: Levenberg–Marquardt for calibration-shaped problems.
//! - [`depth`]: depth from blob area with one camera (Eq. 4.15–4.27).
//! - [`triangulate`]: N-camera triangulation and the parallel rig (Eq. 4.28–4.38).
//! - [`correspond`]: which blob is which across cameras (epipolar + global assignment).
//! - [`synthetic`]: a reference camera and calibration views with known truth.
//! - [`world_heading`]: heading in the world from blob axes (§4.1.1, generalised).
//! - [`wand`]: where a rig's cameras are, from a wand waved through the volume.
//!
//! Frames, units and conventions: `docs/geometry.md` and `docs/conventions.md`.

pub mod calibrate;
pub mod camera;
pub mod correspond;
pub mod depth;
pub mod dotgrid;
pub mod error;
pub mod lm;
pub mod synthetic;
pub mod transform;
pub mod triangulate;
pub mod wand;
pub mod world_heading;

pub use camera::{Camera, Distortion, Intrinsics};
pub use error::{DotGridProblem, GeometryError};

/// Index of the smallest value (the first one on ties; 0 for an empty sequence).
pub(crate) fn index_of_min(values: impl Iterator<Item = f64>) -> usize {
    values
        .enumerate()
        .fold(
            (0, f64::INFINITY),
            |best, (i, v)| if v < best.1 { (i, v) } else { best },
        )
        .0
}
