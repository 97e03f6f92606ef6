//! Everything that crosses a process boundary in Stereoscope, defined once.
//!
//! - [`frame`]: the shared-memory frame header (iceoryx2 user header) and its checks;
//! - [`messages`]: observations, poses, ground truth and health, as JSON (Zenoh) and postcard
//!   (iceoryx2);
//! - [`names`]: iceoryx2 service names with their sizes, Zenoh key expressions;
//! - [`serial`]: the serial-link packets with their decoders;
//! - [`blobs`], [`reports`]: the commands' JSON output.
//!
//! Every message and key is documented in `docs/protocol.md`.

pub mod blobs;
pub mod frame;
pub mod messages;
pub mod names;
pub mod reports;
pub mod serial;
