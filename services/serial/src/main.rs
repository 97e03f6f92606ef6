//! `stereoscope-serial`: the serial output's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Send poses over a serial link")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_serial::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_serial::cli::main(Cli::parse().args))
}
