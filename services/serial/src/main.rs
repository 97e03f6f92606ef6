//! `stereoscope-serial`: the serial output's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Send poses over a serial link")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_serial::cli::Args,
}

fn main() -> anyhow::Result<()> {
    stereoscope_serial::cli::main(Cli::parse().args)
}
