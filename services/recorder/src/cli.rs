//! The recorder's command line, shared by its own binary and `stereoscope service recorder`.

use crate::{RecorderConfig, run};
use std::path::PathBuf;
use std::time::Duration;
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// The session folder to create.
    #[arg(long)]
    pub out: PathBuf,
    /// How often to write and sync, milliseconds (what a crash can lose at most).
    #[arg(long, default_value_t = 200)]
    pub flush_ms: u64,
    /// Also record these cameras' raw frames (on this PC) as Y4M, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub frames: Vec<String>,
}

/// Records until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("recorder");
    let shutdown = Shutdown::on_signals()?;
    let (p, o) = run(
        RecorderConfig {
            ctx: args.common.resolve()?,
            out: args.out,
            flush_interval: Duration::from_millis(args.flush_ms.max(1)),
            frames: args.frames,
        },
        shutdown,
    )?;
    tracing::info!(pose_frames = p, observations = o, "recorder stopped");
    Ok(())
}
