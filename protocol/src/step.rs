//! The f32 record of one environment step inside a trajectory chunk (`[f32]` slice payload).
//!
//! A chunk of `n_steps` steps is `n_steps × record_len()` floats, records back to back. One
//! record holds, in this order (dims from [`StepLayout`]):
//!
//! | field           | len          | meaning                                                        |
//! |-----------------|--------------|----------------------------------------------------------------|
//! | `obs`           | `obs_dim`    | s_t                                                            |
//! | `next_obs`      | `obs_dim`    | s_{t+1}                                                        |
//! | `phi`           | `latent_dim` | φ(s_t), computed at collection with the header's φ version     |
//! | `next_phi`      | `latent_dim` | φ(s_{t+1}) at collection (low reward and "reached", Eq. 2)     |
//! | `subgoal`       | `latent_dim` | absolute subgoal sg held during this step                      |
//! | `high_action`   | `latent_dim` | stored high action sg − φ(s_t) on decision steps, else zeros   |
//! | `action`        | `action_dim` | low-level action applied                                       |
//! | `goal`          | `goal_dim`   | env goal g                                                     |
//! | `achieved_goal` | `goal_dim`   | achieved goal after the step (xy, or rootx/rootz)              |
//! | `reward`        | 1            | env reward of this step                                        |
//! | `decision`      | 1            | [`DecisionKind`] code; non-zero on high-level decision steps   |
//! | `success`       | 1            | env success after the step (0/1)                               |
//! | `terminated`    | 1            | 0/1                                                            |
//! | `truncated`     | 1            | 0/1                                                            |
//!
//! Invariant: every value is finite and flags are exactly 0.0 or 1.0; encoding and decoding both
//! check this and return a [`ProtocolError`] naming the field, never panic. Steps that hit a
//! physics failure are not recorded (the chunk header carries the flag instead).

use std::ops::Range;

use crate::error::ProtocolError;

/// How a high-level subgoal was chosen; `None` on steps that are not decision steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum DecisionKind {
    /// Not a high-level decision step (the subgoal is held).
    None = 0,
    /// Sampled from the high-level policy.
    Policy = 1,
    /// Uniform random high action (first `random_episodes`).
    Random = 2,
    /// HESS novelty/potential exploration subgoal.
    Explore = 3,
    /// FR navigation: a waypoint along the route to the frontier.
    FrontierRoute = 4,
    /// FR count mode: the least-visited candidate near φ(s_t).
    FrontierCount = 5,
    /// Deterministic evaluation policy.
    Evaluation = 6,
}

impl DecisionKind {
    /// The wire code (stored as f32 in records).
    pub fn code(self) -> u32 {
        self as u32
    }

    /// Whether this step is a high-level decision step.
    pub fn is_decision(self) -> bool {
        self != DecisionKind::None
    }
}

impl TryFrom<u32> for DecisionKind {
    type Error = ProtocolError;
    fn try_from(code: u32) -> Result<Self, Self::Error> {
        Ok(match code {
            0 => DecisionKind::None,
            1 => DecisionKind::Policy,
            2 => DecisionKind::Random,
            3 => DecisionKind::Explore,
            4 => DecisionKind::FrontierRoute,
            5 => DecisionKind::FrontierCount,
            6 => DecisionKind::Evaluation,
            _ => {
                return Err(ProtocolError::UnknownCode {
                    what: "decision kind",
                    code,
                })
            }
        })
    }
}

/// One step, owned. Field meanings as in the module table.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRecord {
    /// s_t.
    pub obs: Vec<f32>,
    /// s_{t+1}.
    pub next_obs: Vec<f32>,
    /// φ(s_t) at collection.
    pub phi: Vec<f32>,
    /// φ(s_{t+1}) at collection.
    pub next_phi: Vec<f32>,
    /// Absolute subgoal held during the step.
    pub subgoal: Vec<f32>,
    /// Stored high action (delta) on decision steps, zeros otherwise.
    pub high_action: Vec<f32>,
    /// Low-level action.
    pub action: Vec<f32>,
    /// Env goal.
    pub goal: Vec<f32>,
    /// Achieved goal after the step.
    pub achieved_goal: Vec<f32>,
    /// Env reward.
    pub reward: f32,
    /// How the subgoal was chosen, `None` if not a decision step.
    pub decision: DecisionKind,
    /// Env success after the step.
    pub success: bool,
    /// The episode terminated at this step.
    pub terminated: bool,
    /// The episode was truncated at this step.
    pub truncated: bool,
}

/// One step, borrowed: from a received slice (zero-copy, produced by [`StepLayout::view`]), or
/// from an actor's buffers to be written into a chunk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepView<'a> {
    /// s_t.
    pub obs: &'a [f32],
    /// s_{t+1}.
    pub next_obs: &'a [f32],
    /// φ(s_t) at collection.
    pub phi: &'a [f32],
    /// φ(s_{t+1}) at collection.
    pub next_phi: &'a [f32],
    /// Absolute subgoal.
    pub subgoal: &'a [f32],
    /// Stored high action.
    pub high_action: &'a [f32],
    /// Low-level action.
    pub action: &'a [f32],
    /// Env goal.
    pub goal: &'a [f32],
    /// Achieved goal after the step.
    pub achieved_goal: &'a [f32],
    /// Env reward.
    pub reward: f32,
    /// How the subgoal was chosen.
    pub decision: DecisionKind,
    /// Env success after the step.
    pub success: bool,
    /// Terminated at this step.
    pub terminated: bool,
    /// Truncated at this step.
    pub truncated: bool,
}

impl StepView<'_> {
    /// Copies the view into an owned record.
    pub fn to_record(&self) -> StepRecord {
        StepRecord {
            obs: self.obs.to_vec(),
            next_obs: self.next_obs.to_vec(),
            phi: self.phi.to_vec(),
            next_phi: self.next_phi.to_vec(),
            subgoal: self.subgoal.to_vec(),
            high_action: self.high_action.to_vec(),
            action: self.action.to_vec(),
            goal: self.goal.to_vec(),
            achieved_goal: self.achieved_goal.to_vec(),
            reward: self.reward,
            decision: self.decision,
            success: self.success,
            terminated: self.terminated,
            truncated: self.truncated,
        }
    }
}

/// Number of trailing scalar slots: reward, decision, success, terminated, truncated.
const N_SCALARS: usize = 5;

/// Dimensions of one step record; gives field offsets and encodes/decodes records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StepLayout {
    /// Observation length (29 Ant, 18 cheetah).
    pub obs_dim: usize,
    /// Low-level action length (8 Ant, 6 cheetah, 2 point).
    pub action_dim: usize,
    /// Env goal length (2).
    pub goal_dim: usize,
    /// Latent (φ) length (2).
    pub latent_dim: usize,
}

impl StepLayout {
    /// A layout; every dimension must be at least 1.
    pub fn new(
        obs_dim: usize,
        action_dim: usize,
        goal_dim: usize,
        latent_dim: usize,
    ) -> Result<Self, ProtocolError> {
        let layout = StepLayout {
            obs_dim,
            action_dim,
            goal_dim,
            latent_dim,
        };
        if [obs_dim, action_dim, goal_dim, latent_dim].contains(&0) {
            return Err(ProtocolError::InvalidDims(format!(
                "every dimension must be >= 1, got {layout:?}"
            )));
        }
        Ok(layout)
    }

    /// Floats per step record.
    pub fn record_len(&self) -> usize {
        2 * self.obs_dim + 4 * self.latent_dim + self.action_dim + 2 * self.goal_dim + N_SCALARS
    }

    /// The vector fields in record order, with their lengths.
    fn vector_fields(&self) -> [(&'static str, usize); 9] {
        [
            ("obs", self.obs_dim),
            ("next_obs", self.obs_dim),
            ("phi", self.latent_dim),
            ("next_phi", self.latent_dim),
            ("subgoal", self.latent_dim),
            ("high_action", self.latent_dim),
            ("action", self.action_dim),
            ("goal", self.goal_dim),
            ("achieved_goal", self.goal_dim),
        ]
    }

    /// Range of field `name` inside a record; `None` for an unknown name. Scalar fields
    /// (`reward`, `decision`, `success`, `terminated`, `truncated`) have length 1.
    pub fn field(&self, name: &str) -> Option<Range<usize>> {
        let mut start = 0;
        for (field, len) in self.vector_fields() {
            if field == name {
                return Some(start..start + len);
            }
            start += len;
        }
        let scalar = ["reward", "decision", "success", "terminated", "truncated"]
            .iter()
            .position(|s| *s == name)?;
        Some(start + scalar..start + scalar + 1)
    }

    /// Offset of the first scalar slot (`reward`).
    fn scalars_start(&self) -> usize {
        self.record_len() - N_SCALARS
    }

    /// Writes `record` into `out`, which must be exactly [`record_len`](Self::record_len) long.
    pub fn encode_into(&self, record: &StepRecord, out: &mut [f32]) -> Result<(), ProtocolError> {
        check_len("step record buffer", self.record_len(), out.len())?;
        let vectors: [&[f32]; 9] = [
            &record.obs,
            &record.next_obs,
            &record.phi,
            &record.next_phi,
            &record.subgoal,
            &record.high_action,
            &record.action,
            &record.goal,
            &record.achieved_goal,
        ];
        let mut start = 0;
        for ((name, len), values) in self.vector_fields().into_iter().zip(vectors) {
            check_len(name, len, values.len())?;
            check_finite(name, values)?;
            out[start..start + len].copy_from_slice(values);
            start += len;
        }
        check_finite("reward", &[record.reward])?;
        let scalars = [
            record.reward,
            record.decision.code() as f32,
            f32::from(u8::from(record.success)),
            f32::from(u8::from(record.terminated)),
            f32::from(u8::from(record.truncated)),
        ];
        out[start..].copy_from_slice(&scalars);
        Ok(())
    }

    /// Encodes several records back to back (a chunk payload).
    pub fn encode_chunk(&self, records: &[StepRecord]) -> Result<Vec<f32>, ProtocolError> {
        let len = self.record_len();
        let mut out = vec![0.0; records.len() * len];
        for (record, slot) in records.iter().zip(out.chunks_exact_mut(len)) {
            self.encode_into(record, slot)?;
        }
        Ok(out)
    }

    /// Borrows one record, checking length, finiteness, flags and the decision code.
    pub fn view<'a>(&self, record: &'a [f32]) -> Result<StepView<'a>, ProtocolError> {
        check_len("step record", self.record_len(), record.len())?;
        let mut fields = [&record[..0]; 9];
        let mut start = 0;
        for (slot, (name, len)) in fields.iter_mut().zip(self.vector_fields()) {
            let values = &record[start..start + len];
            check_finite(name, values)?;
            *slot = values;
            start += len;
        }
        let s = &record[self.scalars_start()..];
        check_finite("reward", &s[..1])?;
        let [obs, next_obs, phi, next_phi, subgoal, high_action, action, goal, achieved_goal] =
            fields;
        Ok(StepView {
            obs,
            next_obs,
            phi,
            next_phi,
            subgoal,
            high_action,
            action,
            goal,
            achieved_goal,
            reward: s[0],
            decision: decode_decision(s[1])?,
            success: decode_flag("success", s[2])?,
            terminated: decode_flag("terminated", s[3])?,
            truncated: decode_flag("truncated", s[4])?,
        })
    }

    /// Decodes one record into an owned [`StepRecord`].
    pub fn decode(&self, record: &[f32]) -> Result<StepRecord, ProtocolError> {
        self.view(record).map(|view| view.to_record())
    }

    /// Borrows every record of a chunk payload of `n_steps` steps.
    pub fn view_chunk<'a>(
        &self,
        payload: &'a [f32],
        n_steps: usize,
    ) -> Result<Vec<StepView<'a>>, ProtocolError> {
        let expected = n_steps.checked_mul(self.record_len()).ok_or_else(|| {
            ProtocolError::InvalidDims(format!(
                "{n_steps} steps × {} floats overflows",
                self.record_len()
            ))
        })?;
        check_len("trajectory chunk payload", expected, payload.len())?;
        payload
            .chunks_exact(self.record_len())
            .map(|record| self.view(record))
            .collect()
    }
}

/// `Err(LengthMismatch)` unless `found == expected`.
pub(crate) fn check_len(what: &str, expected: usize, found: usize) -> Result<(), ProtocolError> {
    if expected == found {
        Ok(())
    } else {
        Err(ProtocolError::LengthMismatch {
            what: what.to_owned(),
            expected,
            found,
        })
    }
}

/// `Err(NonFinite)` at the first NaN or infinity.
fn check_finite(field: &'static str, values: &[f32]) -> Result<(), ProtocolError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(ProtocolError::NonFinite {
            field,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

/// A 0.0/1.0 flag.
fn decode_flag(field: &'static str, value: f32) -> Result<bool, ProtocolError> {
    if value == 0.0 {
        Ok(false)
    } else if value == 1.0 {
        Ok(true)
    } else {
        Err(ProtocolError::InvalidFlag { field, value })
    }
}

/// A decision code stored as an integral f32.
fn decode_decision(value: f32) -> Result<DecisionKind, ProtocolError> {
    let integral =
        value.is_finite() && value >= 0.0 && value.fract() == 0.0 && value <= u32::MAX as f32;
    if !integral {
        return Err(ProtocolError::InvalidFlag {
            field: "decision",
            value,
        });
    }
    DecisionKind::try_from(value as u32)
}
