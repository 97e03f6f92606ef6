//! `stereoscope-recorder`: the recorder's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Record poses, observations and frames into a session folder")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_recorder::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_recorder::cli::main(Cli::parse().args))
}
