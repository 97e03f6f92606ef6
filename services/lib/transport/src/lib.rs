//! How Stereoscope's services reach each other, in one place: iceoryx2 nodes and services under
//! a per-PC prefix (with event-driven waiting), Zenoh sessions on chosen endpoints, health
//! reports with liveliness, shutdown on SIGINT/SIGTERM, and logging.
//!
//! Names and sizes come from `stereoscope_proto::names`; nothing here knows what a frame or a
//! pose means.

pub mod health;
pub mod inlet;
pub mod iox;
pub mod net;
pub mod service;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

pub use health::{Counters, HealthReporter};
pub use inlet::{Inlet, Refusal};
pub use net::{ZenohMode, ZenohSpec};
pub use service::{Exclusive, Flow, NodeSpec, Outlet, Service, ServiceNode, drive};

/// A shared "please stop" flag: set by SIGINT/SIGTERM ([`Shutdown::on_signals`]) or by a
/// caller ([`Shutdown::request`]); services poll it between bounded waits.
#[derive(Debug, Clone, Default)]
pub struct Shutdown(Arc<AtomicBool>);

impl Shutdown {
    pub fn new() -> Self {
        Self::default()
    }

    /// A flag that SIGINT and SIGTERM set.
    pub fn on_signals() -> std::io::Result<Self> {
        let s = Self::new();
        signal_hook::flag::register(signal_hook::consts::SIGINT, s.0.clone())?;
        signal_hook::flag::register(signal_hook::consts::SIGTERM, s.0.clone())?;
        Ok(s)
    }

    pub fn request(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    pub fn requested(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }

    /// Sleeps up to `d`, waking early (every 20 ms at most) when shutdown is requested; returns
    /// whether it was.
    pub fn sleep(&self, d: std::time::Duration) -> bool {
        let end = std::time::Instant::now() + d;
        loop {
            if self.requested() {
                return true;
            }
            let now = std::time::Instant::now();
            if now >= end {
                return false;
            }
            std::thread::sleep((end - now).min(std::time::Duration::from_millis(20)));
        }
    }
}

/// Logs to standard error through `tracing`, filtered by `RUST_LOG` (default `info`), every
/// line tagged with the service name.
pub fn init_logging(service: &str) {
    use tracing_subscriber::EnvFilter;
    // Our crates at info (a directive's target matches every target it begins: `stereoscope`
    // covers each `stereoscope_*` crate); the libraries (Zenoh's many crates, iceoryx2) only
    // when they fail.
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("error,stereoscope=info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
    // iceoryx2 prints its own warnings (e.g. "no config file was loaded") to stdout.
    iceoryx2::prelude::set_log_level(iceoryx2::prelude::LogLevel::Error);
    tracing::debug!(service, "logging started");
}

/// An error of a library beneath transport (iceoryx2's enums, Zenoh's boxed errors), kept.
pub type BoxError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Errors of the transport layer, naming the service or endpoint concerned and keeping
/// iceoryx2's or Zenoh's own error as the source (print with `{:#}` or walk `source()` to
/// see it; [`error_chain`] joins them).
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// An iceoryx2 call failed.
    #[error("iceoryx2 {what} {name:?}")]
    Iox {
        what: &'static str,
        name: String,
        #[source]
        source: BoxError,
    },
    /// A message too large for its shared-memory sample.
    #[error("iceoryx2 message on {name:?}: {bytes} bytes is more than the {max} a sample holds")]
    MessageTooLarge {
        name: String,
        bytes: usize,
        max: usize,
    },
    /// iceoryx2 refused the frames' 8-byte payload alignment.
    #[error("iceoryx2 frame service {0:?}: no 8-byte payload alignment")]
    Alignment(String),
    /// A Zenoh call failed.
    #[error("zenoh {what}")]
    Zenoh {
        what: String,
        #[source]
        source: ZenohCause,
    },
    /// Not `client`, `peer` or `router`.
    /// Another instance of a service that must be alone already runs (liveliness).
    #[error("{service} already runs on host {host:?} of this rig: stop that one first")]
    AlreadyRunning { service: String, host: String },
    #[error("zenoh mode {0:?} is not client, peer or router")]
    UnknownZenohMode(String),
    /// An iceoryx2 file prefix iceoryx2 does not take.
    #[error("iceoryx2 prefix {0:?} is not a valid file name prefix")]
    BadPrefix(String),
    /// A client cannot reach its router: why, for a person (`net::why_unreachable`).
    #[error("{0}")]
    Unreachable(String),
}

/// Zenoh's own error, kept whole but said without the trailing "at `<source file>:<line>`."
/// that Zenoh appends (a user has no use for a path inside a dependency).
#[derive(Debug)]
pub struct ZenohCause(pub zenoh::Error);

impl std::fmt::Display for ZenohCause {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let text = self.0.to_string();
        let text = match text.rfind(" at ") {
            Some(i) if text[i..].contains(".rs:") => &text[..i],
            _ => text.as_str(),
        };
        f.write_str(text.trim_end_matches('.'))
    }
}

impl std::error::Error for ZenohCause {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

/// An error and its sources, joined by ": " (what `{:#}` prints for an `anyhow::Error`): for
/// health reports and logs, which keep one line.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !s.ends_with(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        cur = c.source();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zenoh_causes_are_said_without_a_dependency_source_path() {
        let e = ZenohCause("Unable to connect. Timeout! at /root/.cargo/registry/src/zenoh-1.10.2/src/net/x.rs:388.".into());
        assert_eq!(e.to_string(), "Unable to connect. Timeout!");
        let plain = ZenohCause("no path here".into());
        assert_eq!(plain.to_string(), "no path here");
        let t = TransportError::Zenoh {
            what: "open client session".into(),
            source: e,
        };
        assert_eq!(
            error_chain(&t),
            "zenoh open client session: Unable to connect. Timeout!"
        );
    }
}
