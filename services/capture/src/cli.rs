//! The capture service's command line, shared by its own binary and `stereoscope service
//! capture`.

use crate::{CaptureConfig, run};
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

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

/// Runs the service until SIGINT/SIGTERM or the end of its source.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("capture");
    let shutdown = Shutdown::on_signals()?;
    let summary = run(
        CaptureConfig {
            ctx: args.common.resolve()?,
            camera: args.camera,
            max_frames: args.max_frames,
            realtime: args.as_fast_as_possible.then_some(false),
        },
        shutdown,
    )?;
    tracing::info!(
        frames = summary.frames,
        bad = summary.bad_frames,
        "capture stopped"
    );
    Ok(())
}
