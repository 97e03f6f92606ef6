//! Everything that crosses a process boundary in Stereoscope, defined once.
//!
//! So far: the JSON that `stereoscope blobs --json` prints, one object per image per line
//! (`docs/protocol.md`), the rig file every service reads (`docs/rig.md`), the commands'
//! JSON reports, and the serial-link packets with their decoders. Services' shared-memory frames, observation and pose messages, and
//! the serial packet codec join this crate as they are built.

pub mod blobs;
pub mod reports;
pub mod rig;
pub mod serial;
