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
    #[arg(long, required_unless_present = "into", conflicts_with = "into")]
    pub out: Option<PathBuf>,
    /// Make a new session folder in this one, named after the rig and the start time (how
    /// the launcher runs a supervised recorder: every restart records a new session).
    #[arg(long)]
    pub into: Option<PathBuf>,
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
    let ctx = args.common.resolve()?;
    let out = match (args.out, args.into) {
        (Some(out), _) => out,
        (None, Some(folder)) => crate::session::new_session_folder(&folder, &ctx.rig.name),
        (None, None) => anyhow::bail!("give --out SESSION or --into FOLDER"),
    };
    let (p, o) = run(
        RecorderConfig {
            ctx,
            out,
            flush_interval: Duration::from_millis(args.flush_ms.max(1)),
            frames: args.frames,
        },
        shutdown,
    )?;
    tracing::info!(pose_frames = p, observations = o, "recorder stopped");
    Ok(())
}
