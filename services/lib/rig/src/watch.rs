//! Bodies and models changed on a running rig (`docs/bodies.md`, "Changing bodies while the
//! rig runs"): a service (fusion, the VR feed) looks at its rig file once a second; when it
//! changed, the whole file is loaded and checked as at start, and only then are its `[[body]]`
//! and `[[model]]` tables applied — a file that does not load changes nothing and its error is
//! reported. Other sections changed are reported as needing a restart; they are not applied.

use crate::Rig;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

/// How often the rig file is looked at.
pub const LOOK_EVERY: Duration = Duration::from_secs(1);

/// What a change of the rig file came to.
#[derive(Debug)]
pub enum Change {
    /// The file loads: its bodies and models to apply, and whether other sections differ
    /// from the running rig's (those need a restart).
    Apply { rig: Box<Rig>, others_changed: bool },
    /// The file does not load (its error); nothing changes.
    Refused(String),
}

/// The rig file a service runs from, and the state it was last seen in.
#[derive(Debug)]
pub struct RigWatch {
    path: PathBuf,
    seen: Option<(SystemTime, u64)>,
    /// The text last loaded, so a touched but unchanged file changes nothing.
    text: Option<String>,
    last_look: Instant,
}

fn stamp(path: &PathBuf) -> Option<(SystemTime, u64)> {
    let m = std::fs::metadata(path).ok()?;
    Some((m.modified().ok()?, m.len()))
}

impl RigWatch {
    pub fn new(path: PathBuf) -> RigWatch {
        RigWatch {
            seen: stamp(&path),
            text: std::fs::read_to_string(&path).ok(),
            path,
            last_look: Instant::now(),
        }
    }

    /// At most every [`LOOK_EVERY`]: what changed in the file since last seen, against the
    /// `running` rig; `None` when it did not change (or cannot be read: a file being replaced
    /// is looked at again next time).
    pub fn poll(&mut self, running: &Rig) -> Option<Change> {
        if self.last_look.elapsed() < LOOK_EVERY {
            return None;
        }
        self.last_look = Instant::now();
        let now = stamp(&self.path)?;
        if self.seen == Some(now) {
            return None;
        }
        self.seen = Some(now);
        let text = std::fs::read_to_string(&self.path).ok()?;
        if self.text.as_deref() == Some(text.as_str()) {
            return None;
        }
        self.text = Some(text);
        Some(match Rig::load(&self.path) {
            Ok(rig) => {
                let bare = |r: &Rig| {
                    let mut s = r.spec.clone();
                    s.bodies.clear();
                    s.models.clear();
                    s
                };
                let others_changed = bare(&rig) != bare(running);
                Change::Apply {
                    rig: Box::new(rig),
                    others_changed,
                }
            }
            Err(e) => Change::Refused(e.to_string()),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RIG: &str = include_str!("../../../../deploy/rigs/demo.toml");

    /// A body's change is applied, a file that does not load is refused with its error and
    /// changes nothing, a change elsewhere is told apart, and an unchanged rewrite is no
    /// change.
    #[test]
    fn changes_are_loaded_checked_and_told_apart() {
        let dir = std::env::temp_dir().join(format!("stsc-reload-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rig.toml");
        std::fs::write(&path, RIG).unwrap();
        let running = Rig::load(&path).unwrap();
        let mut w = RigWatch::new(path.clone());
        let look = |w: &mut RigWatch, text: &str| {
            std::fs::write(&path, text).unwrap();
            // The stamp must differ: same length and a coarse clock would hide it.
            w.seen = None;
            w.last_look = Instant::now() - LOOK_EVERY;
            w.poll(&running)
        };
        assert!(look(&mut w, RIG).is_none(), "an unchanged file");
        let tighter = RIG.replacen("tolerance = 1.0", "tolerance = 0.5", 1);
        assert_ne!(tighter, RIG, "the demo rig's body has a tolerance of 1.0");
        match look(&mut w, &tighter) {
            Some(Change::Apply {
                rig,
                others_changed: false,
            }) => assert_eq!(rig.spec.bodies[0].tolerance, Some(0.5)),
            other => panic!("{other:?}"),
        }
        match look(&mut w, &format!("{tighter}\n[[body]]\nname = \"x\"\n")) {
            Some(Change::Refused(e)) => assert!(e.contains("body"), "{e}"),
            other => panic!("{other:?}"),
        }
        let renamed = tighter.replacen("name = \"demo\"", "name = \"demo2\"", 1);
        assert_ne!(renamed, tighter);
        match look(&mut w, &renamed) {
            Some(Change::Apply {
                others_changed: true,
                ..
            }) => {}
            other => panic!("{other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
