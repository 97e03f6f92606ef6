//! The fusion service's command line, shared by its own binary and `stereoscope service
//! fusion`.

use crate::{FusionConfig, run};
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Stop after this many pose frames.
    #[arg(long)]
    pub max_sets: Option<u64>,
}

/// Runs fusion until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("fusion");
    let shutdown = Shutdown::on_signals()?;
    let n = run(
        FusionConfig {
            ctx: args.common.resolve()?,
            max_sets: args.max_sets,
        },
        shutdown,
    )?;
    tracing::info!(sets = n, "fusion stopped");
    Ok(())
}
