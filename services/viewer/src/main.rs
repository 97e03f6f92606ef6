//! `stereoscope-viewer`: the viewer service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_viewer::cli::Args>()
}
