//! `stereoscope-viewer`: the viewer's thin binary (see the library).

use clap::Parser;

#[derive(Parser, Debug)]
#[command(about = "Serve the live view: 3D scene, camera monitors and health in a browser")]
struct Cli {
    #[command(flatten)]
    args: stereoscope_viewer::cli::Args,
}

fn main() -> std::process::ExitCode {
    stereoscope_rig::exit::exit_code(stereoscope_viewer::cli::main(Cli::parse().args))
}
