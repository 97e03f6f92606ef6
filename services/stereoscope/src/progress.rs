//! Progress lines on standard error: rewritten in place (`\r`) on a terminal, a few times a
//! second; on a pipe or a log file, whole lines ending in a newline, every few seconds and at
//! the end, so a log reads as lines and is not flooded.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// One progress line being updated.
#[derive(Debug)]
pub struct Progress {
    terminal: bool,
    last: Option<Instant>,
    shown: bool,
}

impl Default for Progress {
    fn default() -> Self {
        Self::new()
    }
}

impl Progress {
    pub fn new() -> Self {
        Progress {
            terminal: std::io::stderr().is_terminal(),
            last: None,
            shown: false,
        }
    }

    /// Shows `line` if it is time to (always when `last` is true, the final state).
    pub fn update(&mut self, line: &str, last: bool) {
        let every = if self.terminal {
            Duration::from_millis(100)
        } else {
            Duration::from_secs(2)
        };
        if !last && self.last.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        self.last = Some(Instant::now());
        let mut err = std::io::stderr().lock();
        let _ = if self.terminal {
            write!(err, "\r{line}")
        } else {
            writeln!(err, "{line}")
        };
        let _ = err.flush();
        self.shown = self.terminal;
    }

    /// Ends the line on a terminal.
    pub fn finish(&mut self) {
        if self.shown {
            eprintln!();
            self.shown = false;
        }
    }
}
