//! `stereoscope-capture`: the capture service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_capture::cli::Args>()
}
