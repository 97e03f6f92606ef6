//! `stereoscope-moments`: the moment worker's thin binary (see the library).

use clap::Parser;
use stereoscope_moments::{MomentsConfig, run};
use stereoscope_transport::{CommonArgs, Shutdown, init_logging};

#[derive(Parser, Debug)]
#[command(about = "Track one camera's blobs and publish observations")]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[arg(long)]
    camera: String,
    #[arg(long)]
    max_frames: Option<u64>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    init_logging("moments");
    let shutdown = Shutdown::on_signals()?;
    let ctx = args.common.resolve()?;
    let n = run(
        MomentsConfig {
            ctx,
            camera: args.camera,
            max_frames: args.max_frames,
        },
        shutdown,
    )?;
    tracing::info!(frames = n, "moment worker stopped");
    Ok(())
}
