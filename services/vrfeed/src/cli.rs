//! The VR feed's command line, shared by its own binary and `stereoscope service vrfeed`.

use crate::{VrFeedConfig, run};
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Stop after this many pose frames.
    #[arg(long)]
    pub max_frames: Option<u64>,
}

impl ServiceArgs for Args {
    const NAME: &'static str = "vrfeed";
    const ABOUT: &'static str = "Send rigid bodies over VRPN, OSC (VMT, VMC) and opentrack's UDP";

    /// Runs the service until SIGINT/SIGTERM.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let s = run(
            VrFeedConfig {
                ctx: self.common.resolve()?,
                max_frames: self.max_frames,
            },
            shutdown,
        )?;
        let mut l = s.latency_us.clone();
        l.sort_by(f64::total_cmp);
        let q = |p: f64| l.get(((l.len().max(1) - 1) as f64 * p).round() as usize);
        Ok(match (q(0.5), q(0.99), l.last()) {
            (Some(p50), Some(p99), Some(max)) => format!(
                "{} frames; frame published → sent: p50 {p50:.0} µs, p99 {p99:.0} µs, max {max:.0} µs (last {})",
                s.frames,
                l.len()
            ),
            _ => format!("{} frames; none sent", s.frames),
        })
    }
}
