//! `stereoscope-fusion`: the fusion service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_fusion::cli::Args>()
}
