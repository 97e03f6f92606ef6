//! How a service starts (`docs/architecture.md`, "Adding a service"): the flags every service
//! shares ([`CommonArgs`]) resolved against the rig into its [`Context`], its PC's router as
//! the rig describes it ([`router`]), one generic `main` ([`main`], [`run`]) so that a
//! service's binary is one line, and the exit statuses its supervisor reads ([`exit`]).
//!
//! A service implements [`ServiceArgs`] on its command line: its name, what it does, and how
//! its flags become its configuration and a run. Its binary is then
//! `fn main() -> ExitCode { stereoscope_service::main::<Args>() }`, and `stereoscope service
//! NAME` runs the same through [`run`].

pub mod context;
pub mod exit;
pub mod router;

pub use context::{CommonArgs, Context, DEFAULT_IOX_PREFIX, HostArgs, TlsArgs};
use std::process::ExitCode;
use stereoscope_transport::{Shutdown, init_logging};

/// A service's command line: its flags (with [`CommonArgs`] flattened in) and how they run it.
pub trait ServiceArgs: clap::Args {
    /// The service's name in its log lines (`moments`, `fusion`).
    const NAME: &'static str;
    /// What its binary says it does (`--help`).
    const ABOUT: &'static str;

    /// Runs the service until `shutdown` (or its own end) and says what it did, for the log's
    /// last line ("1234 frames").
    fn run(self, shutdown: Shutdown) -> anyhow::Result<String>;
}

/// Runs a service from parsed flags: logging, SIGINT/SIGTERM as the shutdown, the service,
/// and its summary logged as it stops.
pub fn run<A: ServiceArgs>(args: A) -> anyhow::Result<()> {
    init_logging(A::NAME);
    let shutdown = Shutdown::on_signals()?;
    let summary = args.run(shutdown)?;
    tracing::info!("{} stopped: {summary}", A::NAME);
    Ok(())
}

/// A service binary's whole `main`: parses the process's arguments (printing help or a usage
/// error as clap does), runs the service, and exits with the status [`exit::exit_code`]
/// gives (78 for a configuration error, which the launcher does not restart).
pub fn main<A: ServiceArgs>() -> ExitCode {
    let name = std::env::args()
        .next()
        .and_then(|a| {
            std::path::Path::new(&a)
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
        })
        .unwrap_or_else(|| format!("stereoscope-{}", A::NAME));
    let command = A::augment_args(clap::Command::new(A::NAME).bin_name(name).about(A::ABOUT));
    let matches = command.get_matches();
    match A::from_arg_matches(&matches) {
        Ok(args) => exit::exit_code(run(args)),
        Err(e) => e.exit(),
    }
}
