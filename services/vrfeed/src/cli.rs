//! The VR feed's command line, shared by its own binary and `stereoscope service vrfeed`.

use crate::{VrFeedConfig, run};
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Stop after this many pose frames.
    #[arg(long)]
    pub max_frames: Option<u64>,
}

/// Runs the service until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("vrfeed");
    let shutdown = Shutdown::on_signals()?;
    let s = run(
        VrFeedConfig {
            ctx: args.common.resolve()?,
            max_frames: args.max_frames,
        },
        shutdown,
    )?;
    let mut l = s.latency_us.clone();
    l.sort_by(f64::total_cmp);
    let q = |p: f64| {
        l.get(((l.len().max(1) - 1) as f64 * p).round() as usize)
            .copied()
    };
    tracing::info!(
        frames = s.frames,
        "VR feed stopped; frame published → sent, µs: p50 {:?}, p99 {:?}, max {:?} (last {})",
        q(0.5),
        q(0.99),
        l.last(),
        l.len()
    );
    Ok(())
}
