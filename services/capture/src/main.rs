//! `stereoscope-capture`: the capture service's thin binary (see the library).

use clap::Parser;
use stereoscope_capture::{CaptureConfig, run};
use stereoscope_transport::{CommonArgs, Shutdown, init_logging};

#[derive(Parser, Debug)]
#[command(about = "Publish one camera's frames into shared memory")]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    /// The camera's id in the rig file.
    #[arg(long)]
    camera: String,
    #[arg(long)]
    max_frames: Option<u64>,
    /// Read files as fast as the reader takes them instead of at their frame rate.
    #[arg(long)]
    as_fast_as_possible: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    init_logging("capture");
    let shutdown = Shutdown::on_signals()?;
    let ctx = args.common.resolve()?;
    let summary = run(
        CaptureConfig {
            ctx,
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
