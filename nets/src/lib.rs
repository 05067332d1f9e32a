//! nets crate.
