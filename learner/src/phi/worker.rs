//! Where φ rounds run: in line with the SAC updates, or on a thread of their own
//! (`encoder.background_rounds`, process mode only).
//!
//! In line (the default, and serial mode), the learner runs a round's steps in slices between
//! its other work and runs no SAC update until the round ends, as the released code does.
//!
//! In the background, a round's start and end stay on the learner's thread, because they touch
//! the store (priorities, freeze, thaw); its steps run on a worker thread that owns the
//! [`PhiTrainer`] meanwhile and reads the round's [`crate::phi::store::StoreView`]. The trainer
//! trains a private copy of the encoder ([`PhiTrainer::with_private_copy`]), so SAC updates,
//! published weights and actors go on with the encoder as it was until the learner collects
//! the finished round ([`PhiRunner::collect`]) and the copy replaces it. The result is the
//! same as in line, step for step (tested); what differs is what else ran meanwhile.

use std::thread::JoinHandle;

use crate::error::LearnerError;
use crate::phi::round::{Advance, PhiStats, PhiTrainer, SliceOutcome};
use crate::phi::store::PhiStore;
use crate::PHI_STEPS_PER_CALL;

/// What a worker thread hands back: the trainer and how its steps went.
type Returned = (Box<PhiTrainer>, Result<Advance, LearnerError>);

enum State {
    /// The trainer is on the learner's thread (no round, or a round run in line).
    Here(Box<PhiTrainer>),
    /// A round's steps run on `worker`; `stats` as they were when it left.
    Away {
        worker: JoinHandle<Returned>,
        stats: PhiStats,
    },
    /// The worker could not start or panicked: the trainer is gone (the learner stops with
    /// the error; a restart resumes from the newest checkpoint).
    Lost(PhiStats),
}

/// The learner's φ trainer and where its rounds run.
pub struct PhiRunner {
    background: bool,
    state: State,
}

impl PhiRunner {
    /// `trainer`'s rounds run in line, or on a worker thread when `background` (then the
    /// trainer must train a private copy, [`PhiTrainer::with_private_copy`]).
    pub fn new(trainer: PhiTrainer, background: bool) -> Self {
        Self {
            background,
            state: State::Here(Box::new(trainer)),
        }
    }

    /// Whether rounds run on a worker thread.
    pub fn is_background(&self) -> bool {
        self.background
    }

    /// Whether a round is in progress (in line or away).
    pub fn is_active(&self) -> bool {
        match &self.state {
            State::Here(trainer) => trainer.is_active(),
            State::Away { .. } => true,
            State::Lost(_) => false,
        }
    }

    /// The statistics; while a round is away, as they were when it left.
    pub fn stats(&self) -> PhiStats {
        match &self.state {
            State::Here(trainer) => trainer.stats(),
            State::Away { stats, .. } | State::Lost(stats) => *stats,
        }
    }

    /// The trainer, unless a round has it on the worker thread (or it was lost).
    pub fn trainer(&self) -> Result<&PhiTrainer, LearnerError> {
        match &self.state {
            State::Here(trainer) => Ok(trainer),
            State::Away { .. } => Err(away()),
            State::Lost(_) => Err(lost()),
        }
    }

    /// The trainer, mutably; see [`PhiRunner::trainer`].
    pub fn trainer_mut(&mut self) -> Result<&mut PhiTrainer, LearnerError> {
        match &mut self.state {
            State::Here(trainer) => Ok(trainer),
            State::Away { .. } => Err(away()),
            State::Lost(_) => Err(lost()),
        }
    }

    /// Starts the next round if `train_episodes` reached it (see
    /// [`PhiTrainer::start_if_due`]); in the background its steps leave for a worker thread.
    /// Returns whether a round is in progress.
    pub fn start_if_due(
        &mut self,
        train_episodes: u64,
        store: &mut PhiStore,
    ) -> Result<bool, LearnerError> {
        if matches!(self.state, State::Away { .. }) {
            return Ok(true);
        }
        let started = self.trainer_mut()?.start_if_due(train_episodes, store)?;
        if started && self.background {
            self.send_away(store)?;
        }
        Ok(started)
    }

    /// In line: one slice of the running round ([`PhiTrainer::run_slice`]).
    pub fn run_slice(
        &mut self,
        store: &mut PhiStore,
        max_steps: u64,
    ) -> Result<SliceOutcome, LearnerError> {
        self.trainer_mut()?.run_slice(store, max_steps)
    }

    /// In the background: ends the round whose steps have run away — at once when `wait`,
    /// else only if the worker has finished. Returns whether φ changed (the published encoder
    /// now holds the round's result). Nothing away: `false`.
    pub fn collect(&mut self, store: &mut PhiStore, wait: bool) -> Result<bool, LearnerError> {
        let finished = match &self.state {
            State::Away { worker, .. } => wait || worker.is_finished(),
            _ => false,
        };
        if !finished {
            return Ok(false);
        }
        let stats = self.stats();
        let worker = match std::mem::replace(&mut self.state, State::Lost(stats)) {
            State::Away { worker, .. } => worker,
            other => {
                self.state = other;
                return Ok(false);
            }
        };
        let (mut trainer, steps) = match worker.join() {
            Ok(returned) => returned,
            Err(panic) => {
                store.thaw();
                return Err(LearnerError::PhiWorker(format!(
                    "the round's thread panicked: {}",
                    message(&panic)
                )));
            }
        };
        let result = match steps {
            Ok(advance) if advance.done => trainer.conclude(store),
            Ok(_) => {
                trainer.abandon(store);
                Err(LearnerError::PhiWorker(
                    "the round's thread returned before the round's last step".to_owned(),
                ))
            }
            Err(err) => {
                trainer.abandon(store);
                Err(err)
            }
        };
        self.state = State::Here(trainer);
        result
    }

    /// Hands the trainer, with its round just started, to a worker thread that runs every step.
    fn send_away(&mut self, store: &mut PhiStore) -> Result<(), LearnerError> {
        let stats = self.stats();
        let mut trainer = match std::mem::replace(&mut self.state, State::Lost(stats)) {
            State::Here(trainer) => trainer,
            other => {
                self.state = other;
                return Err(away());
            }
        };
        let spawned = std::thread::Builder::new()
            .name("phi-round".to_owned())
            .spawn(move || {
                let steps = run_to_end(&mut trainer);
                (trainer, steps)
            });
        match spawned {
            Ok(worker) => {
                self.state = State::Away { worker, stats };
                Ok(())
            }
            Err(err) => {
                // The trainer went with the closure; the round's store must not stay frozen.
                store.thaw();
                Err(LearnerError::PhiWorker(format!(
                    "could not start the round's thread: {err}"
                )))
            }
        }
    }
}

/// Every step of `trainer`'s active round, in slices of [`PHI_STEPS_PER_CALL`] as in line,
/// so that the first and last slice's losses (`phi/round_start_loss`, `round_end_loss`) mean
/// the same either way.
fn run_to_end(trainer: &mut PhiTrainer) -> Result<Advance, LearnerError> {
    let mut total = Advance::default();
    loop {
        let slice = trainer.advance(PHI_STEPS_PER_CALL)?;
        total.steps += slice.steps;
        total.skipped_nonfinite += slice.skipped_nonfinite;
        // No step left without the round being done: no round was active.
        if slice.done || slice.steps == 0 {
            total.done = slice.done;
            return Ok(total);
        }
    }
}

fn away() -> LearnerError {
    LearnerError::PhiWorker("a round has the trainer on its thread; collect it first".to_owned())
}

fn lost() -> LearnerError {
    LearnerError::PhiWorker("the trainer was lost with a failed round thread".to_owned())
}

/// The text of a thread's panic payload.
fn message(panic: &Box<dyn std::any::Any + Send>) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".to_owned())
}
