//! Frame sources behind one trait: each knows its frame size and format, and writes the next
//! frame's pixels straight into the shared-memory buffer it is given (no intermediate copy for
//! files and cameras). Pacing (real time or as fast as possible) is the service's, from
//! [`FrameSource::fps`] and [`FrameSource::realtime`].

use stereoscope_proto::frame::PixelFormat;

/// Why a source cannot go on. Each names its file or device; [`SourceError::BadFrame`] is the
/// one a source survives (the frame is skipped and counted).
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// Reading or opening failed (`doing` says at what: "opening", "frame 12").
    #[error("{origin}: {doing}")]
    Io {
        origin: String,
        doing: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: no .pgm or .png files")]
    NoImages { path: String },
    /// The first image of a sequence, which sets its size and depth, does not read.
    #[error("{path}")]
    FirstImage {
        path: String,
        #[source]
        source: stereoscope_imageio::ImageIoError,
    },
    #[error("{path}: the stream header")]
    Y4mHeader {
        path: String,
        #[source]
        source: crate::y4m::Y4mHeaderError,
    },
    #[error("{path}: frame {frame}: expected a FRAME line, found {found:?}")]
    NoFrameLine {
        path: String,
        frame: u64,
        found: String,
    },
    /// The V4L2 camera does not give a format the service reads.
    #[error("{device}: {problem}")]
    Format {
        device: String,
        problem: FormatProblem,
    },
    /// A control the rig sets that the camera lacks, or a value it refuses.
    #[error("{device}: control {control}: {problem}")]
    Control {
        device: String,
        control: String,
        problem: ControlProblem,
    },
    #[error("the rig file has no [synthetic] scene")]
    NoScene,
    #[error("rendering the synthetic scene")]
    Render(#[source] stereoscope_vision::VisionError),
    /// One frame was bad; the source goes on with the next.
    #[error(transparent)]
    BadFrame(#[from] BadFrame),
}

impl SourceError {
    pub(crate) fn io(origin: &str, doing: impl Into<String>, source: std::io::Error) -> Self {
        SourceError::Io {
            origin: origin.to_string(),
            doing: doing.into(),
            source,
        }
    }
}

/// What is wrong with a V4L2 camera's formats.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FormatProblem {
    #[error("format {requested:?} is not GREY, Y16, YUYV or MJPG")]
    Unsupported { requested: String },
    #[error("the camera does not offer {requested}; it offers {offered:?}")]
    NotOffered {
        requested: String,
        offered: Vec<String>,
    },
    #[error("offers none of GREY, Y16, YUYV, MJPG (it offers {offered:?})")]
    NoneUsable { offered: Vec<String> },
    #[error("driver chose format {chosen}")]
    DriverChose { chosen: String },
    #[error("the camera gives {got} fps at {}×{}, not the {requested} fps asked", .size_px.0, .size_px.1)]
    RateRefused {
        requested: f64,
        got: f64,
        size_px: (u32, u32),
    },
}

/// What is wrong with a control the rig sets on a V4L2 camera.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ControlProblem {
    #[error("the camera has no such control; it has {known:?}")]
    Unknown { known: Vec<String> },
    #[error(
        "{item:?} is a menu item's name, and this control is not a menu (a number from {min} to {max})"
    )]
    NotAMenu { item: String, min: i64, max: i64 },
    #[error("no menu item {item:?}; the items are {items:?}")]
    NoSuchItem { item: String, items: Vec<String> },
    #[error("{value} is outside the control's {min} to {max}")]
    OutOfRange { value: String, min: i64, max: i64 },
}

/// Why one frame was skipped.
#[derive(Debug, thiserror::Error)]
pub enum BadFrame {
    #[error("{path}")]
    Image {
        path: String,
        #[source]
        source: stereoscope_imageio::ImageIoError,
    },
    #[error("{path}: {}×{} differs from the sequence's {}×{}", .got_px.0, .got_px.1, .want_px.0, .want_px.1)]
    SizeChanged {
        path: String,
        got_px: (u32, u32),
        want_px: (u32, u32),
    },
    #[error("{path}: bit depth differs from the sequence's first file")]
    DepthChanged { path: String },
    /// A file that ends inside a frame (what a crash while recording leaves): the partial
    /// frame is skipped, and the source ends at its last whole frame (or starts again, when
    /// it repeats).
    #[error("{path}: truncated: frame {frame} has {got} of its {want} {plane} bytes")]
    Truncated {
        path: String,
        frame: u64,
        plane: &'static str,
        got: u64,
        want: u64,
    },
    /// A camera buffer that is not a frame (short, or an MJPEG that does not decode).
    #[error("{device}")]
    Camera {
        device: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
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
    /// Whether each frame should wait until the camera's moment worker has taken the one
    /// before (a replay of recorded frames: every frame must reach fusion, however loaded the
    /// machine; live cameras never wait).
    fn lockstep(&self) -> bool {
        false
    }
    /// Writes frame `index` (0-based, `scene_time_s` = its time since the start) into `out`
    /// (`stride × height` bytes, tight rows).
    fn read(&mut self, index: u64, scene_time_s: f64, out: &mut [u8]) -> Result<Read, SourceError>;
    /// Extra output of the frame just read (a synthetic source's ground truth).
    fn truth(&self) -> Option<Vec<stereoscope_proto::messages::TargetTruth>> {
        None
    }
}

/// The number of the first frame of a camera opened again (V4L2, GenICam): the frame periods since the last
/// frame given, after it (at least the next number), so frames missed while the camera was
/// away count as a gap; 0 for the very first.
pub(crate) fn number_after(
    last: Option<u64>,
    last_ns: Option<u64>,
    now_ns: Option<u64>,
    fps: Option<f64>,
) -> u64 {
    let Some(last) = last else { return 0 };
    let periods = match (last_ns, now_ns, fps) {
        (Some(a), Some(b), Some(f)) if b > a && f > 0.0 => {
            ((b - a) as f64 * f * 1e-9).round().clamp(1.0, 1e12) as u64
        }
        _ => 1,
    };
    last.saturating_add(periods)
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A device opened again numbers on from the last frame by the periods between them.
    #[test]
    fn a_reopened_camera_numbers_on_by_time() {
        let ms = 1_000_000u64;
        assert_eq!(number_after(None, None, Some(5 * ms), Some(30.0)), 0);
        // 1.1 s at 30 fps after frame 24: 33 periods.
        assert_eq!(
            number_after(Some(24), Some(0), Some(1_100 * ms), Some(30.0)),
            57
        );
        // No time or rate known, or time gone back: the next number.
        assert_eq!(
            number_after(Some(24), None, Some(1_100 * ms), Some(30.0)),
            25
        );
        assert_eq!(
            number_after(Some(24), Some(9 * ms), Some(5 * ms), Some(30.0)),
            25
        );
    }
}
