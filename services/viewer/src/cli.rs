//! The viewer's command line, shared by its own binary, `stereoscope view` and
//! `stereoscope service viewer`.

use crate::{ViewerConfig, run};
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Serve on this address and port instead of the rig's `[viewer] listen`
    /// (default 127.0.0.1:8750; port 0 takes a free one, printed at start).
    #[arg(long)]
    pub listen: Option<std::net::SocketAddr>,
}

/// Runs the service until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("viewer");
    let shutdown = Shutdown::on_signals()?;
    let s = run(
        ViewerConfig {
            ctx: args.common.resolve()?,
            listen: args.listen,
        },
        shutdown,
    )?;
    tracing::info!(
        pose_frames = s.pose_frames,
        connections = s.connections,
        "viewer stopped"
    );
    Ok(())
}
