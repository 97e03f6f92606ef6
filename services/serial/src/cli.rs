//! The serial service's command line, shared by its own binary and `stereoscope service
//! serial`.

use crate::{SerialConfig, run};
use stereoscope_proto::serial::SerialMode;
use stereoscope_rig::CommonArgs;
use stereoscope_transport::{Shutdown, init_logging};

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

/// Runs the service until SIGINT/SIGTERM.
pub fn main(args: Args) -> anyhow::Result<()> {
    init_logging("serial");
    let shutdown = Shutdown::on_signals()?;
    let n = run(
        SerialConfig {
            ctx: args.common.resolve()?,
            port: args.port,
            baud: args.baud,
            mode: args.mode,
            objects: args.objects,
            max_packets: args.max_packets,
        },
        shutdown,
    )?;
    tracing::info!(packets = n, "serial output stopped");
    Ok(())
}
