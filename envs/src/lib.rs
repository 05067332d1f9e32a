//! envs crate.
