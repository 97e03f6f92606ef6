//! `stereoscope-recorder`: the recorder service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_recorder::cli::Args>()
}
