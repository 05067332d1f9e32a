//! Writing step records straight into a chunk's `[f32]` payload, in the layout of
//! [`protocol::step`], without building an owned `StepRecord` per step.
//!
//! Invariant: a record written by [`RecordWriter::write`] decodes with
//! [`StepLayout::decode`]: every value finite (checked here), flags exactly 0/1, a valid
//! decision code. Field offsets come from [`StepLayout::field`], never from our own arithmetic.

use std::ops::Range;

use protocol::{ProtocolError, StepLayout, StepView};

/// A non-finite value found while writing a record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NonFiniteField {
    pub field: &'static str,
    pub index: usize,
    pub value: f32,
}

/// Names of the vector fields, in record order.
const VECTOR_FIELDS: [&str; 9] = [
    "obs",
    "next_obs",
    "phi",
    "next_phi",
    "subgoal",
    "high_action",
    "action",
    "goal",
    "achieved_goal",
];
/// Names of the scalar fields, in record order.
const SCALAR_FIELDS: [&str; 5] = ["reward", "decision", "success", "terminated", "truncated"];

/// Field offsets of one [`StepLayout`].
#[derive(Debug, Clone)]
pub(crate) struct RecordWriter {
    vectors: [Range<usize>; 9],
    scalars: [usize; 5],
}

impl RecordWriter {
    /// Looks up every field's range in `layout`.
    pub fn new(layout: StepLayout) -> Result<Self, ProtocolError> {
        let range = |name: &str| {
            layout.field(name).ok_or_else(|| {
                ProtocolError::InvalidDims(format!("step layout has no field `{name}`"))
            })
        };
        let mut vectors: [Range<usize>; 9] = Default::default();
        for (slot, name) in vectors.iter_mut().zip(VECTOR_FIELDS) {
            *slot = range(name)?;
        }
        let mut scalars = [0; 5];
        for (slot, name) in scalars.iter_mut().zip(SCALAR_FIELDS) {
            *slot = range(name)?.start;
        }
        Ok(Self { vectors, scalars })
    }

    /// Writes `step` (the actor's buffers, borrowed) into `out` (one record long). Lengths are the caller's invariant (the
    /// actor's buffers are sized from the same layout); finiteness is checked.
    pub fn write(&self, step: &StepView<'_>, out: &mut [f32]) -> Result<(), NonFiniteField> {
        let vectors = [
            step.obs,
            step.next_obs,
            step.phi,
            step.next_phi,
            step.subgoal,
            step.high_action,
            step.action,
            step.goal,
            step.achieved_goal,
        ];
        for ((range, values), field) in self.vectors.iter().zip(vectors).zip(VECTOR_FIELDS) {
            check_finite(field, values)?;
            out[range.clone()].copy_from_slice(values);
        }
        check_finite("reward", &[step.reward])?;
        let flag = |b: bool| f32::from(u8::from(b));
        let scalars = [
            step.reward,
            step.decision.code() as f32,
            flag(step.success),
            flag(step.terminated),
            flag(step.truncated),
        ];
        for (offset, value) in self.scalars.iter().zip(scalars) {
            out[*offset] = value;
        }
        Ok(())
    }

    /// The `obs` field of a record.
    pub fn obs<'a>(&self, record: &'a [f32]) -> &'a [f32] {
        &record[self.vectors[0].clone()]
    }

    /// The `next_obs` field of a record.
    pub fn next_obs<'a>(&self, record: &'a [f32]) -> &'a [f32] {
        &record[self.vectors[1].clone()]
    }

    /// Overwrites the φ-space fields of a record (`phi`, `next_phi`, `subgoal`); used when a
    /// new φ version arrives while the record is still buffered.
    pub fn relabel(&self, record: &mut [f32], phi: &[f32], next_phi: &[f32], subgoal: &[f32]) {
        record[self.vectors[2].clone()].copy_from_slice(phi);
        record[self.vectors[3].clone()].copy_from_slice(next_phi);
        record[self.vectors[4].clone()].copy_from_slice(subgoal);
    }
}

fn check_finite(field: &'static str, values: &[f32]) -> Result<(), NonFiniteField> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(NonFiniteField {
            field,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}
