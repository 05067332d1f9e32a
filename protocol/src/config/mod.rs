//! The configuration tree: plain serde structs, one per section, each with `impl Default`
//! beside it and a doc on every field (meaning, default, unit, source).
//!
//! Precedence: defaults < TOML file < `--set dotted.key=value` overrides. Loading reports every
//! unknown key, wrong type and out-of-range value in one [`ConfigErrors`], each with its path.
//! The launcher resolves the config once ([`Config::load`]), writes
//! [`Config::to_resolved_toml`] to `run_dir/config.resolved.toml`, and every process reads that
//! file back with [`Config::from_toml_str`] so all of them run with identical settings.
//!
//! Sources named in field docs: *paper* (ASI, AAAI'26), *supplement* (its appendix tables),
//! *code* (the authors' released Python, see `reference/asi-reference-code.md`), *ours*.

mod error;
mod general;
mod learner;
mod load;
mod method;

use std::path::Path;

use serde::{Deserialize, Serialize};

pub use error::{Checker, ConfigError, ConfigErrors, ConfigIssue};
pub use general::{
    EnvConfig, EvalConfig, HierarchyConfig, ReplayConfig, RunConfig, TransportConfig,
    MAX_DEFAULT_ACTORS,
};
pub use learner::{
    DeterministicLowConfig, HighLearnerConfig, LearnerConfig, LowAlgo, LowLearnerConfig,
};
pub use method::{
    AsiConfig, CountModeScore, EncoderConfig, ExplorationConfig, FrPotentialReports, FrProbStep,
    FutureCountAveraging, GraphConfig, NearFrontier, NodePosition, StableWeighting,
};

/// File name of the resolved configuration inside the run directory.
pub const RESOLVED_CONFIG_FILE: &str = "config.resolved.toml";

/// The whole configuration of a run.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// Run name, seed, budgets, bookkeeping intervals.
    pub run: RunConfig,
    /// Task selection.
    pub env: EnvConfig,
    /// The two-level structure (c, action box, low reward).
    pub hierarchy: HierarchyConfig,
    /// SAC (and the deterministic low-level variant) for both levels.
    pub learner: LearnerConfig,
    /// Replay capacity and the actor throttle.
    pub replay: ReplayConfig,
    /// Representation φ training.
    pub encoder: EncoderConfig,
    /// HESS novelty/potential exploration.
    pub exploration: ExplorationConfig,
    /// Latent subgoal graph.
    pub graph: GraphConfig,
    /// Frontier-reaching and self-imitation.
    pub asi: AsiConfig,
    /// Periodic evaluation.
    pub eval: EvalConfig,
    /// iceoryx2 sizing and timing.
    pub transport: TransportConfig,
}

impl Config {
    /// Loads defaults, then `file` (if any), then each `--set` override in order, and
    /// validates the result. All key, type and range problems come back together.
    pub fn load(file: Option<&Path>, overrides: &[String]) -> Result<Config, ConfigError> {
        let mut table = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                    path: path.to_owned(),
                    source,
                })?;
                load::parse_table(&text, &path.display().to_string())?
            }
            None => toml::Table::new(),
        };
        for arg in overrides {
            load::apply_override(&mut table, arg)?;
        }
        load::table_to_config(table)
    }

    /// Parses and validates TOML text (e.g. a resolved config); `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Config, ConfigError> {
        load::table_to_config(load::parse_table(text, origin)?)
    }

    /// The full configuration as TOML, every field written out, for
    /// `run_dir/config.resolved.toml`. [`Config::from_toml_str`] reads it back to an equal value.
    pub fn to_resolved_toml(&self) -> Result<String, ConfigError> {
        let body = toml::to_string(self).map_err(|err| ConfigError::Serialize(err.to_string()))?;
        Ok(format!(
            "# Resolved ASI configuration (protocol version {}).\n\
             # Written by the launcher; every process of the run reads this file.\n\n{body}",
            crate::PROTOCOL_VERSION
        ))
    }

    /// Checks every field and the cross-field rules; returns all problems at once.
    pub fn validate(&self) -> Result<(), ConfigErrors> {
        let mut c = Checker::new();
        let subgoal_interval = self.hierarchy.c;
        self.run.check(&mut c);
        self.env.check(&mut c, subgoal_interval);
        self.hierarchy.check(&mut c);
        self.learner.check(&mut c);
        self.replay.check(&mut c, subgoal_interval);
        self.encoder.check(&mut c);
        self.exploration.check(&mut c);
        self.graph.check(&mut c);
        self.asi.check(&mut c);
        self.eval.check(&mut c);
        self.transport.check(&mut c, self.run.n_actors);
        c.finish()
    }

    /// Settings that are valid but probably not what was meant, one sentence each (the
    /// launcher prints them as notes); empty for the shipped configs.
    pub fn notes(&self) -> Vec<String> {
        let mut notes = Vec::new();
        if self.asi.frontier_reaching
            && self.asi.fr_start_episode < self.encoder.first_round_episode
        {
            notes.push(format!(
                "asi.fr_start_episode = {} is before encoder.first_round_episode = {}: until the \
                 first φ round there is no graph built with a trained φ (an empty one in a \
                 fresh or serially resumed run, one of the untrained φ after a graph-service \
                 restart), so FR episodes before it find no frontier or take the start as one",
                self.asi.fr_start_episode, self.encoder.first_round_episode
            ));
        }
        notes
    }
}
