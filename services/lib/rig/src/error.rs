//! The one error type of a rig file: which file, which key, what is wrong with its value.

use std::path::PathBuf;

/// What kind of problem a [`RigError`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RigErrorKind {
    /// The file could not be read.
    Read,
    /// Not TOML, or a key or value the schema does not have (the message carries the line).
    Syntax,
    /// A value out of its range, or keys that contradict each other.
    Value,
    /// The command line does not fit the rig (`--host`, `--camera`).
    Arguments,
}

/// A problem in a rig file: the file, the key path (`camera[1].moments.threshold`) and a message
/// that quotes the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}{key}{}{message}", file_prefix(.file), if .key.is_empty() { "" } else { ": " })]
pub struct RigError {
    pub kind: RigErrorKind,
    /// The rig file, when the rig came from one.
    pub file: Option<PathBuf>,
    /// The key path; empty for a file that could not be read or parsed.
    pub key: String,
    pub message: String,
}

fn file_prefix(file: &Option<PathBuf>) -> String {
    file.as_ref()
        .map(|f| format!("{}: ", f.display()))
        .unwrap_or_default()
}

impl RigError {
    /// The same error, naming `file`.
    pub fn in_file(mut self, file: &std::path::Path) -> Self {
        self.file = Some(file.to_path_buf());
        self
    }
}

/// A value error at `key`.
pub fn err(key: impl Into<String>, message: impl Into<String>) -> RigError {
    RigError {
        kind: RigErrorKind::Value,
        file: None,
        key: key.into(),
        message: message.into(),
    }
}
