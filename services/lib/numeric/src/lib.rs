//! The small numerics every other library shares: minimum-cost assignment, a reproducible random
//! generator and angle wrapping. Pure: no I/O, no IPC, no dependencies.

pub mod angle;
pub mod assign;
pub mod random;

pub use assign::{Assigner, assign_min_cost};
pub use random::SplitMix64;
