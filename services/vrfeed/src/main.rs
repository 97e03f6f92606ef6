//! `stereoscope-vrfeed`: the VR feed's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Send rigid bodies over VRPN, OSC (VMT, VMC) and opentrack's UDP")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_vrfeed::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_vrfeed::cli::main(Cli::parse().args))
}
