//! The fusion service's command line, shared by its own binary and `stereoscope service
//! fusion`.

use crate::{FusionConfig, run};
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Stop after this many pose frames.
    #[arg(long)]
    pub max_sets: Option<u64>,
}

impl ServiceArgs for Args {
    const NAME: &'static str = "fusion";
    const ABOUT: &'static str = "Fuse every camera's observations into 3D poses";

    /// Runs fusion until SIGINT/SIGTERM.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let n = run(
            FusionConfig {
                ctx: self.common.resolve()?,
                max_sets: self.max_sets,
            },
            shutdown,
        )?;
        Ok(format!("{n} pose frames"))
    }
}
