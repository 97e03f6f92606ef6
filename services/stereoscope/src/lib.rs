//! The `stereoscope` command line, as a library so its commands can be tested in-process.
//! `main.rs` only parses arguments and calls these.

pub mod blobs;
pub mod body;
pub mod calibrate;

pub mod example;
pub mod fitdepth;
pub mod floor;
pub mod grab;
pub mod live;
pub mod mask;
pub mod model;
pub mod process;
pub mod progress;
pub mod sessions;
pub mod target;

pub mod triangulate;
pub mod wand;
pub mod wand_live;
