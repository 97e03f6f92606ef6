//! `stereoscope-serial`: the serial service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_serial::cli::Args>()
}
