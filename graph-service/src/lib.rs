//! graph-service crate.
