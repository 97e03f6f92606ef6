//! `stereoscope-fusion`: the fusion service's thin binary (see the library).

use clap::Parser;
use stereoscope_fusion::{FusionConfig, run};
use stereoscope_transport::{CommonArgs, Shutdown, init_logging};

#[derive(Parser, Debug)]
#[command(about = "Fuse every camera's observations into 3D poses")]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
    #[arg(long)]
    max_sets: Option<u64>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    init_logging("fusion");
    let shutdown = Shutdown::on_signals()?;
    let ctx = args.common.resolve()?;
    let n = run(
        FusionConfig {
            ctx,
            max_sets: args.max_sets,
        },
        shutdown,
    )?;
    tracing::info!(sets = n, "fusion stopped");
    Ok(())
}
