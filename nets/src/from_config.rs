//! The one mapping from the run's [`protocol::Config`] and the task's dimensions to a
//! [`NetsSpec`], so the learner and every actor build networks with identical names and shapes
//! (and hence the same layout hash).

use protocol::config::LowAlgo;
use protocol::Config;

use crate::error::Result;
use crate::set::{LowVariant, NetsSpec};

/// Dimensions that come from the environment, not the config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskDims {
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub action_dim: usize,
    /// Symmetric low-level action bound (env action units, e.g. 16 N·m for the Ant).
    pub action_scale: f64,
}

/// Builds and validates the network spec of a run.
pub fn spec_from_config(config: &Config, task: TaskDims) -> Result<NetsSpec> {
    let (low_variant, low_hidden, low_critic_hidden) = match config.learner.low.algo {
        LowAlgo::Sac => (
            LowVariant::Sac,
            config.learner.low.hidden.clone(),
            config.learner.low.hidden.clone(),
        ),
        LowAlgo::Deterministic => (
            LowVariant::Deterministic,
            config.learner.low.deterministic.actor_hidden.clone(),
            config.learner.low.deterministic.critic_hidden.clone(),
        ),
    };
    let spec = NetsSpec {
        obs_dim: task.obs_dim,
        goal_dim: task.goal_dim,
        latent_dim: config.encoder.out_dim,
        action_dim: task.action_dim,
        encoder_hidden: config.encoder.hidden.clone(),
        high_hidden: config.learner.high.hidden.clone(),
        low_hidden,
        low_critic_hidden,
        high_action_scale: config.hierarchy.abs_range,
        low_action_scale: task.action_scale,
        low_variant,
    };
    spec.validate()?;
    Ok(spec)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ANT: TaskDims = TaskDims {
        obs_dim: 29,
        goal_dim: 2,
        action_dim: 8,
        action_scale: 16.0,
    };

    #[test]
    fn the_default_config_gives_the_default_ant_spec() {
        let spec = spec_from_config(&Config::default(), ANT).unwrap();
        assert_eq!(spec, NetsSpec::default());
    }

    #[test]
    fn the_deterministic_variant_takes_its_own_widths() {
        let mut config = Config::default();
        config.learner.low.algo = LowAlgo::Deterministic;
        let spec = spec_from_config(&config, ANT).unwrap();
        assert_eq!(spec, NetsSpec::default().with_deterministic_low());
    }
}
