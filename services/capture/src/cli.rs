//! The capture service's command line, shared by its own binary and `stereoscope service
//! capture`.

use crate::{CaptureConfig, run};
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// The camera's id in the rig file.
    #[arg(long)]
    pub camera: String,
    /// Stop after this many frames.
    #[arg(long)]
    pub max_frames: Option<u64>,
    /// Read files as fast as the reader takes them instead of at their frame rate.
    #[arg(long)]
    pub as_fast_as_possible: bool,
}

impl ServiceArgs for Args {
    const NAME: &'static str = "capture";
    const ABOUT: &'static str = "Publish one camera's frames into shared memory";

    /// Runs the service until SIGINT/SIGTERM or the end of its source.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let summary = run(
            CaptureConfig {
                ctx: self.common.resolve()?,
                camera: self.camera,
                max_frames: self.max_frames,
                realtime: self.as_fast_as_possible.then_some(false),
            },
            shutdown,
        )?;
        Ok(format!(
            "{} frames, {} bad",
            summary.frames, summary.bad_frames
        ))
    }
}
