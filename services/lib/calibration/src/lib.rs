//! A rig's calibration steps past the camera solvers (`docs/calibration.md`): the world's floor
//! ([`floor`]) from an L-frame lying on it or from markers on it, found among the steady markers
//! of a recording, the masks of what is bright but no marker ([`mask`]), and the wand calibration's acceptance
//! and report card ([`wand`]). Pure functions with typed errors: the command line reads the files, writes
//! the rig and reports; the edge cases are unit tests here.

pub mod floor;
pub mod mask;
pub mod wand;
