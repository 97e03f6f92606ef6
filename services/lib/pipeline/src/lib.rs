//! The pipeline's stages, as libraries below the services (`docs/architecture.md`): what a
//! moment worker does to one frame ([`worker`]), how fusion pairs observations in time
//! ([`pairing`]), turns one set into points and poses with ids ([`fuser`]), and follows rigid
//! bodies over sets ([`bodies`]), fits kinematic models ([`models`]), and fusion's whole step over one set ([`fusion`]). No IPC:
//! the services are adapters that feed these from iceoryx2 and Zenoh and publish what they
//! return, and replay, the ghost sweep and the benches run the same code in process.

pub mod bodies;
pub mod fuser;
pub mod fusion;
pub mod models;
pub mod pairing;
pub mod worker;

pub use fusion::{Fusion, FusionSettings};
