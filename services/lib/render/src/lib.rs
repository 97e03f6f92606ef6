//! Stereoscope's synthetic cameras: what a rig's calibrated cameras would see of moving bright
//! targets, with ground truth for every frame — for the capture service's synthetic source,
//! the tests and the benchmarks. Pure: no I/O.
//!
//! - [`scene`]: targets (spheres, the thesis's double ping-pong ball, discs, rectangles,
//!   multi-marker bodies), distractors, background light.
//! - [`render`]: ray-cast, supersampled rendering through `stereoscope_geometry::Camera`,
//!   occlusion, shading, blur, noise; truth per target.
//! - [`motion`]: scripted, seeded trajectories.
//!
//! Conventions: `docs/conventions.md`, `docs/geometry.md`; what it renders: `docs/render.md`.

pub mod motion;
pub mod render;
pub mod scene;

pub use motion::{Actor, Blink, Motion, State, scene_at};
pub use render::{Frame, RenderOptions, TargetTruth, render_u8, render_u16};
pub use scene::{Background, Distractor, Light, Scene, Shape, Target};

#[cfg(test)]
mod tests;
