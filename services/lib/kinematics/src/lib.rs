//! Kinematic recovery (thesis §5.3, Figs. 5.10–5.11): a robot or a limb as a tree of links
//! joined by joints, markers on its links, and its joint values recovered each frame from the
//! triangulated markers by one constrained fit of the whole chain. `docs/models.md` is the
//! reference: joint kinds, the fit, what is flagged, the figures.
//!
//! - [`model`]: the tree, its checks and its forward kinematics;
//! - [`urdf`]: models read from URDF (`urdf-rs`), markers placed on its links by name;
//! - [`fit`]: the chain fit (Levenberg–Marquardt, analytic Jacobians, limits, warm start,
//!   determined / undetermined joints);
//! - [`synthetic`]: a six-joint arm and a leg with known motion, the truth for tests.
//!
//! Pure: no I/O, no IPC. Units: metres and radians.

pub mod define;
pub mod fit;
pub mod model;
pub mod synthetic;
pub mod urdf;

pub use define::{
    DefineError, DefineOptions, Defined, MovedTogether, Track, define_model, moved_together,
};
pub use fit::{ChainFit, ChainState, FitError, FitOptions, JointFit, fit_chain, initial_state};
pub use model::{
    Base, Joint, JointKind, JointSpec, JointValue, Limits, Link, Marker, MarkerSpec, Model,
    ModelError, Swing,
};
pub use urdf::{UrdfError, model_from_urdf};

#[cfg(test)]
mod define_tests;
#[cfg(test)]
mod tests;
