//! Everything that crosses a process boundary in Stereoscope, defined once.
//!
//! So far: the JSON that `stereoscope blobs --json` prints, one object per image per line
//! (`docs/protocol.md`), and the rig file every service reads (`docs/rig.md`). Services' shared-memory frames, observation and pose messages, and
//! the serial packet codec join this crate as they are built.

pub mod blobs;
pub mod reports;
pub mod rig;
