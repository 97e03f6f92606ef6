//! `stereoscope-capture`: the capture service's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Publish one camera's frames into shared memory")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_capture::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_capture::cli::main(Cli::parse().args))
}
