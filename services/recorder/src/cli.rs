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
    /// Stop by itself after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    pub seconds: Option<f64>,
}

/// Records until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("recorder");
    let shutdown = Shutdown::on_signals()?;
    if let Some(s) = args.seconds {
        if !(s.is_finite() && s > 0.0 && s <= 1e9) {
            anyhow::bail!("--seconds {s} must be a number of seconds above zero");
        }
        let stop = shutdown.clone();
        std::thread::spawn(move || {
            stop.sleep(std::time::Duration::from_secs_f64(s));
            stop.request();
        });
    }
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
