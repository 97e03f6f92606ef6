//! `stereoscope-fusion`: the fusion service's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Fuse every camera's observations into 3D poses")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_fusion::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_fusion::cli::main(Cli::parse().args))
}
