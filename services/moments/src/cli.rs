//! The moment worker's command line, shared by its own binary and `stereoscope service
//! moments`.

use crate::{MomentsConfig, run};
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
}

/// Runs the worker until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("moments");
    let shutdown = Shutdown::on_signals()?;
    let n = run(
        MomentsConfig {
            ctx: args.common.resolve()?,
            camera: args.camera,
            max_frames: args.max_frames,
        },
        shutdown,
    )?;
    tracing::info!(frames = n, "moment worker stopped");
    Ok(())
}
