//! The viewer's command line, shared by its own binary, `stereoscope view` and
//! `stereoscope service viewer`.

use crate::{ViewerConfig, run};
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Serve on this address and port instead of the rig's `[viewer] listen`
    /// (default 127.0.0.1:8750; port 0 takes a free one, printed at start).
    #[arg(long)]
    pub listen: Option<std::net::SocketAddr>,
}

impl ServiceArgs for Args {
    const NAME: &'static str = "viewer";
    const ABOUT: &'static str =
        "Serve the live view: 3D scene, camera monitors and health in a browser";

    /// Runs the service until SIGINT/SIGTERM.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let s = run(
            ViewerConfig {
                ctx: self.common.resolve()?,
                listen: self.listen,
            },
            shutdown,
        )?;
        Ok(format!(
            "{} pose frames, {} connections",
            s.pose_frames, s.connections
        ))
    }
}
