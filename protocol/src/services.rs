//! iceoryx2 service names of one run, all under the namespace `asi/<run-id>/`, so two runs on
//! one machine never see each other's data.
//!
//! | service                        | pattern           | payload                                   |
//! |--------------------------------|-------------------|-------------------------------------------|
//! | `asi/<run-id>/trajectories`    | pub-sub           | `[f32]` step records + [`TrajectoryHeader`] |
//! | `asi/<run-id>/weights`         | pub-sub, history 1| `[u8]` safetensors + [`WeightsHeader`]      |
//! | `asi/<run-id>/graph`           | request–response  | `[u8]` postcard + graph headers             |
//! | `asi/<run-id>/metrics`         | pub-sub           | [`MetricsSample`]                           |
//! | `asi/<run-id>/control`         | pub-sub           | [`ControlMessage`]                          |
//!
//! [`TrajectoryHeader`]: crate::payload::TrajectoryHeader
//! [`WeightsHeader`]: crate::payload::WeightsHeader
//! [`MetricsSample`]: crate::payload::MetricsSample
//! [`ControlMessage`]: crate::payload::ControlMessage

use std::fmt;

use serde::{Deserialize, Serialize};

/// Prefix of every service and node name this system creates.
pub const NAMESPACE_ROOT: &str = "asi";

/// Longest accepted run id (iceoryx2 allows 255-byte service names; this leaves ample room).
pub const MAX_RUN_ID_LEN: usize = 64;

/// Why a string is not a valid [`RunId`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RunIdError {
    /// The id is empty.
    #[error("run id is empty; use e.g. \"antmaze-u-seed0\"")]
    Empty,
    /// The id is longer than [`MAX_RUN_ID_LEN`].
    #[error("run id is {len} characters long; at most {max} are allowed")]
    TooLong {
        /// Its length in bytes.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// The id contains a character outside `A-Z a-z 0-9 _ -`.
    #[error(
        "run id {id:?} contains {found:?} at position {position}; only A-Z a-z 0-9 _ - are allowed"
    )]
    BadChar {
        /// The rejected id.
        id: String,
        /// The first offending character.
        found: char,
        /// Its character position.
        position: usize,
    },
    /// The id does not start with a letter or digit.
    #[error("run id {0:?} must start with a letter or digit")]
    BadStart(String),
}

/// A validated run identifier: 1–64 characters of `A-Z a-z 0-9 _ -`, starting with a letter or
/// digit. It names the run's iceoryx2 namespace and is safe in file names.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct RunId(String);

impl RunId {
    /// Validates `id`.
    pub fn new(id: &str) -> Result<RunId, RunIdError> {
        if id.is_empty() {
            return Err(RunIdError::Empty);
        }
        if id.len() > MAX_RUN_ID_LEN {
            return Err(RunIdError::TooLong {
                len: id.len(),
                max: MAX_RUN_ID_LEN,
            });
        }
        let allowed = |ch: char| ch.is_ascii_alphanumeric() || ch == '_' || ch == '-';
        if let Some((position, found)) = id.chars().enumerate().find(|(_, ch)| !allowed(*ch)) {
            return Err(RunIdError::BadChar {
                id: id.to_owned(),
                found,
                position,
            });
        }
        if !id.starts_with(|ch: char| ch.is_ascii_alphanumeric()) {
            return Err(RunIdError::BadStart(id.to_owned()));
        }
        Ok(RunId(id.to_owned()))
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The run's namespace prefix, `asi/<run-id>`.
    pub fn namespace(&self) -> String {
        format!("{NAMESPACE_ROOT}/{}", self.0)
    }

    /// The full service name of `service` in this run, e.g. `asi/run1/trajectories`.
    pub fn service_name(&self, service: Service) -> String {
        format!("{}/{}", self.namespace(), service.suffix())
    }

    /// An iceoryx2 node name for a process of this run, e.g. `asi/run1/actor-3`.
    pub fn node_name(&self, role: &str) -> String {
        format!("{}/{role}", self.namespace())
    }
}

impl fmt::Display for RunId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl TryFrom<String> for RunId {
    type Error = RunIdError;
    fn try_from(value: String) -> Result<Self, Self::Error> {
        RunId::new(&value)
    }
}

impl From<RunId> for String {
    fn from(value: RunId) -> Self {
        value.0
    }
}

impl std::str::FromStr for RunId {
    type Err = RunIdError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RunId::new(s)
    }
}

/// The services of one run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Service {
    /// Actors → learner and graph-service: trajectory chunks.
    Trajectories,
    /// Learner → actors and graph-service: policy and φ weights (history 1).
    Weights,
    /// Actors and learner ↔ graph-service: requests and responses.
    Graph,
    /// All → launcher: metrics samples.
    Metrics,
    /// Launcher → all: stop, checkpoint.
    Control,
    /// Learner → actors: replay-ratio throttle state ([`crate::payload::ProgressMessage`], history 1).
    Progress,
}

impl Service {
    /// Every service, in a fixed order (useful for cleanup and listings).
    pub const ALL: [Service; 6] = [
        Service::Trajectories,
        Service::Weights,
        Service::Graph,
        Service::Metrics,
        Service::Control,
        Service::Progress,
    ];

    /// The last component of the service name.
    pub fn suffix(self) -> &'static str {
        match self {
            Service::Trajectories => "trajectories",
            Service::Weights => "weights",
            Service::Graph => "graph",
            Service::Metrics => "metrics",
            Service::Control => "control",
            Service::Progress => "progress",
        }
    }
}
