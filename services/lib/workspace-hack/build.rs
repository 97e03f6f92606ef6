//! Empty: its build-dependencies only unify features (see Cargo.toml).
fn main() {}
