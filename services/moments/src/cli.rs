//! The moment worker's command line, shared by its own binary and `stereoscope service
//! moments`.

use crate::{MomentsConfig, run};
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

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

impl ServiceArgs for Args {
    const NAME: &'static str = "moments";
    const ABOUT: &'static str = "Track one camera's blobs and publish observations";

    /// Runs the worker until SIGINT/SIGTERM.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let n = run(
            MomentsConfig {
                ctx: self.common.resolve()?,
                camera: self.camera,
                max_frames: self.max_frames,
            },
            shutdown,
        )?;
        Ok(format!("{n} frames"))
    }
}
