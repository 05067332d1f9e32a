//! The network set of one agent: [`NetsSpec`] (sizes and choices), [`PolicySet`] (what an actor
//! needs: φ, high policy, low policy) and the critics the learner adds.
//!
//! Parameter names are fixed by the prefixes in [`prefix`]; a `PolicySet` built on the root of
//! a `VarMap` therefore has the same names (and layout hash) on the learner and every actor.
//!
//! Input layouts (the caller concatenates along the feature axis, in this order):
//! - encoder φ: `obs` (`obs_dim`)
//! - high policy: `[obs, goal]` (`obs_dim + goal_dim`) → delta (`latent_dim`)
//! - high critic: `[obs, goal, delta]`
//! - low policy: `[obs, φ(obs), subgoal]` (`obs_dim + 2·latent_dim`) → action (`action_dim`)
//! - low critic: `[obs, φ(obs), action, subgoal]`; the deterministic variant's reference code
//!   divides the action by its scale first (digest §3.2).

use candle_core::Tensor;
use candle_nn::VarBuilder;
use serde::{Deserialize, Serialize};

use crate::critic::{DistanceCritic, TwinCritic};
use crate::encoder::Encoder;
use crate::error::{NetsError, Result};
use crate::init::LinearInit;
use crate::policy::{DeterministicActor, GaussianPolicy};

/// Parameter-name prefixes of each network.
pub mod prefix {
    /// Encoder φ.
    pub const ENCODER: &str = "encoder";
    /// High-level policy.
    pub const HIGH_POLICY: &str = "high_policy";
    /// Low-level policy.
    pub const LOW_POLICY: &str = "low_policy";
    /// High-level critic.
    pub const HIGH_CRITIC: &str = "high_critic";
    /// Low-level critic.
    pub const LOW_CRITIC: &str = "low_critic";
    /// Everything an actor needs (the `PolicySet`).
    pub const ACTOR_SIDE: [&str; 3] = [ENCODER, HIGH_POLICY, LOW_POLICY];
}

/// Which low-level algorithm the networks serve (`learner.low.algo`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LowVariant {
    /// SAC: tanh-Gaussian policy and twin critics (SPEC §5 default).
    Sac,
    /// The reference code's DDPG-style level: deterministic actor and γ-distance critic.
    Deterministic,
}

/// Sizes and choices of every network. Dims are feature counts; scales are action bounds in
/// the action's own unit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetsSpec {
    /// Observation size. Default 29 (Ant); 18 for the cheetah.
    pub obs_dim: usize,
    /// Size of the env goal given to the high policy. Default 2 (maze xy).
    pub goal_dim: usize,
    /// Size of φ-space: encoder output, high action (delta) and subgoal. Default 2.
    pub latent_dim: usize,
    /// Low-level action size. Default 8 (Ant torques).
    pub action_dim: usize,
    /// Encoder hidden widths. Default [100, 100] (reference code; the supplement says one layer).
    pub encoder_hidden: Vec<usize>,
    /// High policy and high critic hidden widths. Default [256, 256] (reference SAC).
    pub high_hidden: Vec<usize>,
    /// Low policy hidden widths. Default [256, 256] (SAC); reference deterministic 4 × 400.
    pub low_hidden: Vec<usize>,
    /// Low critic hidden widths. Default [256, 256] (SAC); reference deterministic 5 × 400.
    pub low_critic_hidden: Vec<usize>,
    /// High action bound `abs_range`, φ units. Default 10 (reference code).
    pub high_action_scale: f64,
    /// Low action bound, env action units. Default 16 (Ant torque limit, N·m).
    pub low_action_scale: f64,
    /// Low-level algorithm. Default SAC (SPEC §5).
    pub low_variant: LowVariant,
}

impl Default for NetsSpec {
    fn default() -> Self {
        Self {
            obs_dim: 29,
            goal_dim: 2,
            latent_dim: 2,
            action_dim: 8,
            encoder_hidden: vec![100, 100],
            high_hidden: vec![256, 256],
            low_hidden: vec![256, 256],
            low_critic_hidden: vec![256, 256],
            high_action_scale: 10.0,
            low_action_scale: 16.0,
            low_variant: LowVariant::Sac,
        }
    }
}

impl NetsSpec {
    /// The reference code's deterministic low level: actor 4 × 400, critic 5 × 400
    /// (digest §3.2); other fields unchanged.
    pub fn with_deterministic_low(mut self) -> Self {
        self.low_variant = LowVariant::Deterministic;
        self.low_hidden = vec![400; 4];
        self.low_critic_hidden = vec![400; 5];
        self
    }

    /// Checks every field; all problems are reported at once.
    pub fn validate(&self) -> Result<()> {
        let mut problems = Vec::new();
        let dims = [
            ("obs_dim", self.obs_dim),
            ("goal_dim", self.goal_dim),
            ("latent_dim", self.latent_dim),
            ("action_dim", self.action_dim),
        ];
        for (name, dim) in dims {
            if dim == 0 {
                problems.push(format!("{name} must be positive, got 0"));
            }
        }
        let widths = [
            ("encoder_hidden", &self.encoder_hidden),
            ("high_hidden", &self.high_hidden),
            ("low_hidden", &self.low_hidden),
            ("low_critic_hidden", &self.low_critic_hidden),
        ];
        for (name, hidden) in widths {
            if hidden.is_empty() || hidden.contains(&0) {
                problems.push(format!(
                    "{name} needs at least one layer, all positive, got {hidden:?}"
                ));
            }
        }
        for (name, scale) in [
            ("high_action_scale", self.high_action_scale),
            ("low_action_scale", self.low_action_scale),
        ] {
            if !(scale.is_finite() && scale > 0.0) {
                problems.push(format!("{name} must be finite and positive, got {scale}"));
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(NetsError::Spec(problems.join("; ")))
        }
    }

    /// High policy input: `[obs, goal]`.
    pub fn high_policy_in(&self) -> usize {
        self.obs_dim + self.goal_dim
    }

    /// High critic input: `[obs, goal, delta]`.
    pub fn high_critic_in(&self) -> usize {
        self.high_policy_in() + self.latent_dim
    }

    /// Low policy input: `[obs, φ(obs), subgoal]`.
    pub fn low_policy_in(&self) -> usize {
        self.obs_dim + 2 * self.latent_dim
    }

    /// Low critic input: `[obs, φ(obs), action, subgoal]`.
    pub fn low_critic_in(&self) -> usize {
        self.low_policy_in() + self.action_dim
    }

    /// Init of the low-level nets: Xavier for SAC (the same SAC networks as the high level,
    /// reference `algos/sac`), PyTorch default for the reference deterministic nets.
    pub fn low_init(&self) -> LinearInit {
        match self.low_variant {
            LowVariant::Sac => LinearInit::XavierUniform,
            LowVariant::Deterministic => LinearInit::TorchDefault,
        }
    }

    /// Builds the high-level twin critic under `vb` (the caller picks the prefix, e.g.
    /// [`prefix::HIGH_CRITIC`], on the learner's critic or target-critic `VarMap`).
    pub fn high_critic(&self, vb: &VarBuilder) -> Result<TwinCritic> {
        self.validate()?;
        TwinCritic::new(
            vb,
            self.high_critic_in(),
            &self.high_hidden,
            LinearInit::XavierUniform,
        )
    }

    /// Builds the low-level critic of the configured variant under `vb`.
    pub fn low_critic(&self, vb: &VarBuilder) -> Result<LowCritic> {
        self.validate()?;
        let (input, hidden, init) = (
            self.low_critic_in(),
            &self.low_critic_hidden,
            self.low_init(),
        );
        Ok(match self.low_variant {
            LowVariant::Sac => LowCritic::Twin(TwinCritic::new(vb, input, hidden, init)?),
            LowVariant::Deterministic => {
                LowCritic::Distance(DistanceCritic::new(vb, input, hidden, init)?)
            }
        })
    }
}

/// The low-level policy of either variant.
#[derive(Clone, Debug)]
pub enum LowPolicy {
    /// SAC tanh-Gaussian policy.
    Gaussian(GaussianPolicy),
    /// Reference deterministic actor.
    Deterministic(DeterministicActor),
}

impl LowPolicy {
    /// The noise-free action, `[batch, action_dim]`: `scale · tanh(μ)` or the actor's output.
    pub fn deterministic(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            Self::Gaussian(p) => p.deterministic(x),
            Self::Deterministic(p) => p.forward(x),
        }
    }

    /// Action bound.
    pub fn scale(&self) -> f64 {
        match self {
            Self::Gaussian(p) => p.scale(),
            Self::Deterministic(p) => p.scale(),
        }
    }
}

/// The low-level critic of either variant.
#[derive(Clone, Debug)]
pub enum LowCritic {
    /// SAC twin Q networks.
    Twin(TwinCritic),
    /// Reference γ-distance critic.
    Distance(DistanceCritic),
}

/// Everything an actor runs: φ, the high policy and the low policy, named under
/// [`prefix::ACTOR_SIDE`]. The learner trains the very same modules.
#[derive(Clone, Debug)]
pub struct PolicySet {
    /// Encoder φ (`encoder.*`).
    pub encoder: Encoder,
    /// High policy (`high_policy.*`), tanh-Gaussian, actions in `[−high_action_scale, …]`.
    pub high: GaussianPolicy,
    /// Low policy (`low_policy.*`).
    pub low: LowPolicy,
}

impl PolicySet {
    /// Builds (or fetches) all three networks under `vb` (normally the root of a `VarMap`).
    pub fn new(spec: &NetsSpec, vb: &VarBuilder) -> Result<Self> {
        spec.validate()?;
        let encoder = Encoder::new(
            &vb.pp(prefix::ENCODER),
            spec.obs_dim,
            &spec.encoder_hidden,
            spec.latent_dim,
        )?;
        let high = GaussianPolicy::new(
            &vb.pp(prefix::HIGH_POLICY),
            spec.high_policy_in(),
            &spec.high_hidden,
            spec.latent_dim,
            spec.high_action_scale,
            LinearInit::XavierUniform,
        )?;
        let low = build_low_policy(spec, &vb.pp(prefix::LOW_POLICY))?;
        Ok(Self { encoder, high, low })
    }
}

fn build_low_policy(spec: &NetsSpec, vb: &VarBuilder) -> Result<LowPolicy> {
    let (input, hidden, init) = (spec.low_policy_in(), &spec.low_hidden, spec.low_init());
    let scale = spec.low_action_scale;
    Ok(match spec.low_variant {
        LowVariant::Sac => LowPolicy::Gaussian(GaussianPolicy::new(
            vb,
            input,
            hidden,
            spec.action_dim,
            scale,
            init,
        )?),
        LowVariant::Deterministic => LowPolicy::Deterministic(DeterministicActor::new(
            vb,
            input,
            hidden,
            spec.action_dim,
            scale,
            init,
        )?),
    })
}
