//! No code: this crate's dependencies only unify features between CI's two passes (see its
//! Cargo.toml).
