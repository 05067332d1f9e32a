//! learner crate.
