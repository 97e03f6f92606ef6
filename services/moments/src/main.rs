//! `stereoscope-moments`: the moments service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_moments::cli::Args>()
}
