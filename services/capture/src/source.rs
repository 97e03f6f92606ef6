//! Frame sources behind one trait: each knows its frame size and format, and writes the next
//! frame's pixels straight into the shared-memory buffer it is given (no intermediate copy for
//! files and cameras). Pacing (real time or as fast as possible) is the service's, from
//! [`FrameSource::fps`] and [`FrameSource::realtime`].

use stereoscope_proto::frame::PixelFormat;

#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The source cannot be opened or read at all (names the file or device).
    #[error("{0}")]
    Fatal(String),
    /// One frame was bad (named); the source can go on.
    #[error("{0}")]
    BadFrame(String),
}

/// What a frame read produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Read {
    /// A frame; `timestamp_ns` when the source knows when it was exposed, `sequence` when it
    /// replays a recording that numbered its frames (the number the live camera gave it).
    Frame {
        timestamp_ns: Option<u64>,
        sequence: Option<u64>,
    },
    /// The source has no more frames.
    End,
}

pub trait FrameSource: Send {
    /// A description for logs and health ("y4m clip.y4m 320×240 30 fps").
    fn describe(&self) -> String;
    fn format(&self) -> PixelFormat;
    fn size(&self) -> (u32, u32);
    /// Frames per second, when the source has a rate.
    fn fps(&self) -> Option<f64>;
    /// Whether the service should pace frames at [`FrameSource::fps`] (cameras pace
    /// themselves and answer false).
    fn realtime(&self) -> bool;
    /// Writes frame `index` (0-based, `scene_time_s` = its time since the start) into `out`
    /// (`stride × height` bytes, tight rows).
    fn read(&mut self, index: u64, scene_time_s: f64, out: &mut [u8]) -> Result<Read, SourceError>;
    /// Extra output of the frame just read (a synthetic source's ground truth).
    fn truth(&self) -> Option<Vec<stereoscope_proto::messages::TargetTruth>> {
        None
    }
}

/// Copies `src` rows (each `row_bytes` long, `src_stride` apart) into tight rows of `out`.
pub fn copy_rows(src: &[u8], src_stride: usize, row_bytes: usize, rows: usize, out: &mut [u8]) {
    for (y, dst) in out.chunks_exact_mut(row_bytes).take(rows).enumerate() {
        let start = y * src_stride;
        if let Some(s) = src.get(start..start + row_bytes) {
            dst.copy_from_slice(s);
        }
    }
}
