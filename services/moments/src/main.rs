//! `stereoscope-moments`: the moment worker's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Track one camera's blobs and publish observations")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_moments::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_moments::cli::main(Cli::parse().args))
}
