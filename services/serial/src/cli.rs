//! The serial service's command line, shared by its own binary and `stereoscope service
//! serial`.

use crate::{SerialConfig, run};
use stereoscope_proto::serial::SerialMode;
use stereoscope_service::{CommonArgs, ServiceArgs};
use stereoscope_transport::Shutdown;

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub common: CommonArgs,
    /// The serial device, e.g. /dev/ttyUSB0.
    #[arg(long)]
    pub port: String,
    /// Line speed, 8N1 (the thesis: 9600).
    #[arg(long, default_value_t = 9600)]
    pub baud: u32,
    /// legacy (the thesis's 10-byte packet, one object) or framed (id, CRC, COBS).
    #[arg(long, default_value = "framed")]
    pub mode: SerialMode,
    /// Object ids to send, comma-separated (default: every object; legacy: the lowest id).
    #[arg(long, value_delimiter = ',')]
    pub objects: Vec<u32>,
    /// Stop after this many packets.
    #[arg(long)]
    pub max_packets: Option<u64>,
}

impl ServiceArgs for Args {
    const NAME: &'static str = "serial";
    const ABOUT: &'static str = "Send poses over a serial link";

    /// Runs the service until SIGINT/SIGTERM.
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String> {
        let n = run(
            SerialConfig {
                ctx: self.common.resolve()?,
                port: self.port,
                baud: self.baud,
                mode: self.mode,
                objects: self.objects,
                max_packets: self.max_packets,
            },
            shutdown,
        )?;
        Ok(format!("{n} packets"))
    }
}
