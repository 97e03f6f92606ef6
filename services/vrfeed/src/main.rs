//! `stereoscope-vrfeed`: the vrfeed service's binary (see the library).

fn main() -> std::process::ExitCode {
    stereoscope_service::main::<stereoscope_vrfeed::cli::Args>()
}
