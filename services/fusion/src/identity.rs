//! Identity across restarts: the pose sequence and object ids of one session never go back or
//! repeat, however often fusion is restarted (kill -9 included). A session is one run of the
//! launcher, named by `STEREOSCOPE_SESSION` in the services' environment (the launcher's start
//! time). Numbers are handed out from blocks reserved in a small state file before any is
//! used: after a crash, fusion continues above the last reserved block, so at most one block
//! of numbers is skipped and none is reused. Without a session (a fusion run by hand) the
//! numbers start at 0 and 1 as before.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use stereoscope_proto::names::SESSION_ENV;
/// Pose sequence numbers reserved at a time (about 80 s at 120 sets/s).
pub const SEQUENCE_BLOCK: u64 = 10_000;
/// Object ids reserved at a time.
pub const ID_BLOCK: u32 = 1_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
struct State {
    /// Sequence numbers below this may have been used.
    sequence_reserved: u64,
    /// Object ids below this may have been used.
    id_reserved: u32,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct StateFile {
    session: String,
    state: State,
}

/// Why the reservations could not be written (fusion then refuses to go on: it could not
/// promise unique numbers).
#[derive(Debug, thiserror::Error)]
#[error("fusion: the identity state file {}", .file.display())]
pub struct IdentityError {
    pub file: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// The numbers of one session, reserved ahead in `file`.
#[derive(Debug)]
pub struct Reservations {
    file: Option<(PathBuf, String)>,
    state: State,
}

impl Reservations {
    /// No session: nothing persisted, numbers from 0 and 1.
    pub fn none() -> Self {
        Reservations {
            file: None,
            state: State {
                sequence_reserved: u64::MAX,
                id_reserved: u32::MAX,
            },
        }
    }

    /// Session `session`, state in `file`: returns the reservations and where to continue
    /// (first sequence number, first object id). A file of another session, or one that does
    /// not read, starts the session afresh.
    pub fn open(file: &Path, session: &str) -> Result<(Self, u64, u32), IdentityError> {
        let previous = std::fs::read(file)
            .ok()
            .and_then(|b| serde_json::from_slice::<StateFile>(&b).ok())
            .filter(|s| s.session == session)
            .map(|s| s.state);
        let (sequence, id) = previous
            .map(|s| (s.sequence_reserved, s.id_reserved.max(1)))
            .unwrap_or((0, 1));
        let mut r = Reservations {
            file: Some((file.to_path_buf(), session.to_string())),
            state: State {
                sequence_reserved: sequence,
                id_reserved: id,
            },
        };
        r.reserve(sequence, id)?;
        Ok((r, sequence, id))
    }

    /// The session's state file for a rig on this PC.
    pub fn path(iox_prefix: &str, rig: &str) -> PathBuf {
        std::env::temp_dir()
            .join("stereoscope-state")
            .join(format!("{iox_prefix}{rig}-fusion.json"))
    }

    /// Makes sure `sequence` and `next_id` are inside reserved blocks, writing a new
    /// reservation (through a temporary file, then renamed) when one is not.
    pub fn reserve(&mut self, sequence: u64, next_id: u32) -> Result<(), IdentityError> {
        let Some((file, session)) = &self.file else {
            return Ok(());
        };
        if sequence < self.state.sequence_reserved && next_id < self.state.id_reserved {
            return Ok(());
        }
        let state = State {
            sequence_reserved: sequence.saturating_add(SEQUENCE_BLOCK),
            id_reserved: next_id.saturating_add(ID_BLOCK),
        };
        let io = |source| IdentityError {
            file: file.clone(),
            source,
        };
        if let Some(dir) = file.parent() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let text = serde_json::to_vec(&StateFile {
            session: session.clone(),
            state,
        })
        .unwrap_or_default();
        let tmp = file.with_extension("json.tmp");
        std::fs::write(&tmp, text)
            .and_then(|_| std::fs::rename(&tmp, file))
            .map_err(io)?;
        self.state = state;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Numbers handed out, then a crash at any point: the restarted fusion's first numbers
    /// are above every one used before; a new session starts afresh.
    #[test]
    fn a_restart_never_reuses_a_number_of_its_session() {
        let dir = std::env::temp_dir().join(format!("identity-{}", std::process::id()));
        let file = dir.join("state.json");
        let _ = std::fs::remove_dir_all(&dir);
        let (mut r, seq, id) = Reservations::open(&file, "s1").unwrap();
        assert_eq!((seq, id), (0, 1));
        // 25 000 sets and 1 500 objects, reserving as it goes.
        for s in 0..25_000u64 {
            r.reserve(s, 1 + (s / 17) as u32).unwrap();
        }
        let used = (24_999u64, 1 + 24_999 / 17);
        // kill -9 here: no clean stop.
        drop(r);
        let (_r, seq, id) = Reservations::open(&file, "s1").unwrap();
        assert!(seq > used.0, "{seq}");
        assert!(id > used.1 as u32, "{id}");
        assert!(seq <= used.0 + 1 + SEQUENCE_BLOCK, "{seq}");
        // Another session starts from the beginning.
        let (_r, seq, id) = Reservations::open(&file, "s2").unwrap();
        assert_eq!((seq, id), (0, 1));
        // A file that does not read starts afresh too, and is rewritten.
        std::fs::write(&file, b"{not json").unwrap();
        let (_r, seq, _) = Reservations::open(&file, "s2").unwrap();
        assert_eq!(seq, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
