//! The recorder's command line, shared by its own binary and `stereoscope service recorder`.

use crate::{RecorderConfig, run};
use std::path::PathBuf;
use std::time::Duration;
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

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

impl ServiceArgs for Args {
    const NAME: &'static str = "recorder";
    const ABOUT: &'static str = "Record poses, observations and frames into a session folder";

    /// Records until SIGINT/SIGTERM (or `--seconds`).
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        if let Some(s) = self.seconds {
            if !(s.is_finite() && s > 0.0 && s <= 1e9) {
                anyhow::bail!("--seconds {s} must be a number of seconds above zero");
            }
            let stop = shutdown.clone();
            std::thread::spawn(move || {
                stop.sleep(std::time::Duration::from_secs_f64(s));
                stop.request();
            });
        }
        let ctx = self.common.resolve()?;
        let out = match (self.out, self.into) {
            (Some(out), _) => out,
            (None, Some(folder)) => crate::session::new_session_folder(&folder, &ctx.rig.name),
            (None, None) => anyhow::bail!("give --out SESSION or --into FOLDER"),
        };
        let (p, o) = run(
            RecorderConfig {
                ctx,
                out,
                flush_interval: Duration::from_millis(self.flush_ms.max(1)),
                frames: self.frames,
            },
            shutdown,
        )?;
        Ok(format!("{p} pose frames, {o} observations"))
    }
}
