//! The small numerics every other library shares: minimum-cost assignment, a reproducible random
//! generator, angle wrapping, and the 0–360° heading unwrap (thesis §4.1.1) that both a camera's
//! tracker and fusion's world heading use. Pure: no I/O, no IPC, no dependencies.

pub mod angle;
pub mod assign;
pub mod heading;
pub mod quantiles;
pub mod random;

pub use assign::{Assigner, assign_min_cost, cheapest_allowed};
pub use random::SplitMix64;
