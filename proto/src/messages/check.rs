//! How every received message is checked before it changes anything (`docs/protocol.md`,
//! "Limits"): the bounds, the decode errors naming the field, and the checker the messages'
//! `validate` walk their fields with.

use super::SCHEMA_VERSION;

/// Bounds every received message is held to before it changes anything
/// (`docs/protocol.md`, "Limits").
pub mod limits {
    /// Largest encoded message a receiver decodes, bytes.
    pub const MAX_MESSAGE_BYTES: usize = 1 << 20;
    /// Longest rig, camera, host or service name, bytes.
    pub const MAX_NAME_BYTES: usize = 64;
    /// Most blobs in one observation (what a worker reports at most: a full-body marker set
    /// for several people and their props in one view).
    pub const MAX_BLOBS: usize = 512;
    /// Most poses (objects) in one pose frame, and targets in one truth message.
    pub const MAX_POSES: usize = 1024;
    /// Most cameras named in one pose frame or pose.
    pub const MAX_CAMERAS: usize = 64;
    /// Largest image side, pixels (the rig's own bound).
    pub const MAX_IMAGE_SIDE_PX: u32 = 8192;
    /// Longest free text (a health report's last error, a detail value), bytes.
    pub const MAX_TEXT_BYTES: usize = 512;
    /// Most bodies in one pose frame (a rig defines at most this many).
    pub const MAX_BODIES: usize = 32;
    /// Most kinematic models in one pose frame, joints of one model, links of one model (the
    /// rig's own bounds).
    pub const MAX_MODELS: usize = 8;
    pub const MAX_MODEL_JOINTS: usize = 64;
    pub const MAX_MODEL_LINKS: usize = MAX_MODEL_JOINTS + 1;
    /// Most `detail` entries in a health report.
    pub const MAX_DETAIL_ENTRIES: usize = 32;
    /// Largest preview side, pixels, and largest reduction.
    pub const MAX_PREVIEW_SIDE_PX: u32 = 1024;
    pub const MAX_PREVIEW_SCALE: u32 = 64;
}

/// What is wrong with a field of a message that decoded.
#[derive(Debug, Clone, PartialEq)]
pub enum Invalid {
    NotFinite,
    TooLong {
        bytes: usize,
        max: usize,
    },
    TooMany {
        count: usize,
        max: usize,
    },
    Empty,
    OutOfRange {
        value: f64,
        min: f64,
        max: f64,
    },
    /// An identifier that must be unique within the message appears again.
    Repeated {
        value: u64,
        first: usize,
    },
}

impl std::fmt::Display for Invalid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Invalid::NotFinite => write!(f, "is not a finite number"),
            Invalid::TooLong { bytes, max } => write!(f, "is {bytes} bytes long, over {max}"),
            Invalid::TooMany { count, max } => write!(f, "has {count} entries, over {max}"),
            Invalid::Empty => write!(f, "is empty"),
            Invalid::OutOfRange { value, min, max } => {
                write!(f, "{value} is outside {min}–{max}")
            }
            Invalid::Repeated { value, first } => {
                write!(f, "repeats {value}, first at entry {first}")
            }
        }
    }
}

/// Why a message could not be decoded.
#[derive(Debug)]
pub enum DecodeError {
    Json(serde_json::Error),
    Binary(postcard::Error),
    Schema {
        found: u32,
    },
    /// The encoded message is larger than [`limits::MAX_MESSAGE_BYTES`]; not parsed.
    TooLarge {
        bytes: usize,
    },
    /// It decoded, but a field is outside [`limits`] (`field` is its path: `blobs[3].x_px`).
    Invalid {
        field: String,
        problem: Invalid,
    },
}

impl DecodeError {
    /// A short name for counting rejections by reason.
    pub fn reason(&self) -> &'static str {
        match self {
            DecodeError::Json(_) | DecodeError::Binary(_) => "undecodable",
            DecodeError::Schema { .. } => "schema",
            DecodeError::TooLarge { .. } => "too_large",
            DecodeError::Invalid { .. } => "invalid",
        }
    }
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DecodeError::Json(e) => write!(f, "not a valid JSON message: {e}"),
            DecodeError::Binary(e) => write!(f, "not a valid binary message: {e}"),
            DecodeError::Schema { found } => {
                write!(f, "schema {found} is not {SCHEMA_VERSION}")
            }
            DecodeError::TooLarge { bytes } => write!(
                f,
                "a message of {bytes} bytes, over the {} accepted",
                limits::MAX_MESSAGE_BYTES
            ),
            DecodeError::Invalid { field, problem } => write!(f, "{field} {problem}"),
        }
    }
}

impl std::error::Error for DecodeError {}

/// Field checks, each naming the field's path on failure.
pub(super) struct Checker {
    path: Vec<String>,
}

pub(super) type Checked = Result<(), DecodeError>;

impl Checker {
    pub(super) fn new() -> Self {
        Checker { path: Vec::new() }
    }

    pub(super) fn fail(&self, field: &str, problem: Invalid) -> DecodeError {
        let mut f = self.path.concat();
        if !f.is_empty() && !field.is_empty() {
            f.push('.');
        }
        f.push_str(field);
        DecodeError::Invalid { field: f, problem }
    }

    pub(super) fn name(&self, field: &str, v: &str) -> Checked {
        if v.is_empty() {
            return Err(self.fail(field, Invalid::Empty));
        }
        self.text(field, v, limits::MAX_NAME_BYTES)
    }

    pub(super) fn text(&self, field: &str, v: &str, max: usize) -> Checked {
        if v.len() > max {
            return Err(self.fail(
                field,
                Invalid::TooLong {
                    bytes: v.len(),
                    max,
                },
            ));
        }
        Ok(())
    }

    /// Each entry of list `list` has a different `field` (its values in `ids`, in order).
    pub(super) fn unique(
        &self,
        list: &str,
        field: &str,
        ids: impl Iterator<Item = u64>,
    ) -> Checked {
        let mut seen: Vec<(u64, usize)> = ids.enumerate().map(|(i, id)| (id, i)).collect();
        seen.sort_unstable();
        match seen.windows(2).find(|w| w[0].0 == w[1].0) {
            Some(w) => Err(self.fail(
                &format!("{list}[{}].{field}", w[1].1),
                Invalid::Repeated {
                    value: w[0].0,
                    first: w[0].1,
                },
            )),
            None => Ok(()),
        }
    }

    pub(super) fn count(&self, field: &str, count: usize, max: usize) -> Checked {
        if count > max {
            return Err(self.fail(field, Invalid::TooMany { count, max }));
        }
        Ok(())
    }

    pub(super) fn finite(&self, field: &str, values: &[f64]) -> Checked {
        if values.iter().any(|v| !v.is_finite()) {
            return Err(self.fail(field, Invalid::NotFinite));
        }
        Ok(())
    }

    pub(super) fn range(&self, field: &str, v: f64, min: f64, max: f64) -> Checked {
        self.finite(field, &[v])?;
        if !(min..=max).contains(&v) {
            return Err(self.fail(field, Invalid::OutOfRange { value: v, min, max }));
        }
        Ok(())
    }

    pub(super) fn names(&self, field: &str, v: &[String]) -> Checked {
        self.count(field, v.len(), limits::MAX_CAMERAS)?;
        v.iter()
            .enumerate()
            .try_for_each(|(i, n)| self.name(&format!("{field}[{i}]"), n))
    }

    /// Runs `f` with `field` (and `[index]`) appended to the path.
    pub(super) fn within(
        &mut self,
        field: String,
        f: impl FnOnce(&mut Self) -> Checked,
    ) -> Checked {
        let sep = if self.path.is_empty() || field.starts_with('[') {
            ""
        } else {
            "."
        };
        self.path.push(format!("{sep}{field}"));
        let r = f(self);
        self.path.pop();
        r
    }
}
