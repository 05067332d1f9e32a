//! Configuration errors, and the [`Checker`] that collects every problem before reporting.
//!
//! Invariant: a [`ConfigErrors`] is never empty; each [`ConfigIssue`] names the dotted field
//! path, the offending value as the user wrote it (TOML syntax), and how to fix it.

use std::fmt;
use std::path::PathBuf;

/// One problem found in a configuration: where, what value, and what to do about it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigIssue {
    /// Dotted path of the field, e.g. `learner.high.gamma`.
    pub path: String,
    /// The offending value rendered as TOML, or `(missing)` / `(unknown key)` context.
    pub value: String,
    /// What is wrong and how to fix it, e.g. `must be in (0, 1)`.
    pub message: String,
}

impl fmt::Display for ConfigIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} = {}: {}", self.path, self.value, self.message)
    }
}

/// Every problem found in one configuration, reported together.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigErrors {
    /// The problems, in the order they were found (parse problems first, then validation).
    pub issues: Vec<ConfigIssue>,
}

impl ConfigErrors {
    /// Whether an issue for exactly this field path is present (useful in tests and tools).
    pub fn has_path(&self, path: &str) -> bool {
        self.issues.iter().any(|issue| issue.path == path)
    }
}

impl fmt::Display for ConfigErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.issues.len();
        write!(
            f,
            "invalid configuration ({n} problem{}):",
            if n == 1 { "" } else { "s" }
        )?;
        for issue in &self.issues {
            write!(f, "\n  - {issue}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigErrors {}

/// Why a configuration could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The TOML file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file that was asked for.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The TOML text is not valid TOML (before any field is looked at).
    #[error("{origin} is not valid TOML: {message}")]
    Syntax {
        /// Where the text came from: a file path or `--set <arg>`.
        origin: String,
        /// The TOML parser's message, with line and column.
        message: String,
    },
    /// A `--set` argument is not of the form `dotted.key=value`.
    #[error("bad override `{arg}`: {reason} (expected `section.field=value`, e.g. `learner.high.gamma=0.98`)")]
    Override {
        /// The argument as given.
        arg: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Unknown keys, wrong types and out-of-range values, all at once.
    #[error(transparent)]
    Invalid(#[from] ConfigErrors),
    /// The configuration could not be serialized (a bug: every field is TOML-representable).
    #[error("cannot serialize configuration to TOML: {0}")]
    Serialize(String),
}

/// Collects [`ConfigIssue`]s while walking a configuration; see [`Checker::finish`].
#[derive(Debug, Default)]
pub struct Checker {
    issues: Vec<ConfigIssue>,
}

impl Checker {
    /// An empty checker.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records a problem with `path` whose value is `value` (rendered with `Debug`-like TOML).
    pub fn issue(&mut self, path: &str, value: impl fmt::Display, message: impl Into<String>) {
        self.issues.push(ConfigIssue {
            path: path.to_owned(),
            value: value.to_string(),
            message: message.into(),
        });
    }

    /// Records a prepared issue.
    pub fn push(&mut self, issue: ConfigIssue) {
        self.issues.push(issue);
    }

    /// Requires `lo < value < hi`.
    pub fn open_interval(&mut self, path: &str, value: f64, lo: f64, hi: f64) {
        if !(value > lo && value < hi) {
            self.issue(path, value, format!("must be in ({lo}, {hi})"));
        }
    }

    /// Requires `lo <= value <= hi`.
    pub fn closed_interval(&mut self, path: &str, value: f64, lo: f64, hi: f64) {
        if !(value >= lo && value <= hi) {
            self.issue(path, value, format!("must be in [{lo}, {hi}]"));
        }
    }

    /// Requires `0 < value <= 1`.
    pub fn fraction(&mut self, path: &str, value: f64) {
        if !(value > 0.0 && value <= 1.0) {
            self.issue(path, value, "must be in (0, 1]");
        }
    }

    /// Requires a finite `value > 0`.
    pub fn positive(&mut self, path: &str, value: f64) {
        if !(value.is_finite() && value > 0.0) {
            self.issue(path, value, "must be a finite number > 0");
        }
    }

    /// Requires a finite `value >= 0`.
    pub fn non_negative(&mut self, path: &str, value: f64) {
        if !(value.is_finite() && value >= 0.0) {
            self.issue(path, value, "must be a finite number >= 0");
        }
    }

    /// Requires an integer count `value >= 1`.
    pub fn at_least_one(&mut self, path: &str, value: u64) {
        if value == 0 {
            self.issue(path, value, "must be at least 1");
        }
    }

    /// Requires a non-empty list of layer widths, each at least 1.
    pub fn layer_sizes(&mut self, path: &str, sizes: &[usize]) {
        if sizes.is_empty() || sizes.contains(&0) {
            self.issue(
                path,
                format!("{sizes:?}"),
                "must list at least one layer, each of width >= 1, e.g. [256, 256]",
            );
        }
    }

    /// Requires an inclusive integer range `[lo, hi]` with `1 <= lo <= hi`.
    pub fn int_range(&mut self, path: &str, range: [u32; 2]) {
        if range[0] == 0 || range[0] > range[1] {
            self.issue(
                path,
                format!("{range:?}"),
                "must be [lo, hi] with 1 <= lo <= hi",
            );
        }
    }

    /// Returns `Ok` when no problem was recorded, else all of them.
    pub fn finish(self) -> Result<(), ConfigErrors> {
        if self.issues.is_empty() {
            Ok(())
        } else {
            Err(ConfigErrors {
                issues: self.issues,
            })
        }
    }

    /// The issues recorded so far (consumes the checker).
    pub fn into_issues(self) -> Vec<ConfigIssue> {
        self.issues
    }
}
