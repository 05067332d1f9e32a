//! actor crate.
