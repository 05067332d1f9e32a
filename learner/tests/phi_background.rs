//! φ rounds in the background (`encoder.background_rounds`): the round's steps run on a
//! thread of their own while SAC updates go on with the published encoder unchanged; the
//! result, collected later, is the in-line round's to the bit, and checkpoints wait for it.

mod common;

use std::time::{Duration, Instant};

use common::*;
use learner::learner::checkpoint::{Checkpoint, CheckpointError};
use learner::Learner;
use protocol::{Config, PhiVersion};

/// [`phi_config`] with rounds in line or in the background.
fn config_with(background: bool) -> Config {
    let mut c = phi_config();
    c.encoder.background_rounds = background;
    c.validate().unwrap();
    c
}

/// A learner on [`config_with`] holding four 10-step episodes: the first round is due.
fn due_learner(background: bool) -> Learner {
    let mut l = Learner::new(&config_with(background), DIMS, 7).unwrap();
    for ep in 0..4 {
        ingest_episode(&mut l, 0, ep, 10, 2, 5);
    }
    l
}

/// Calls `train` until φ's version reaches `version`; panics after 60 s (a hang fails).
fn train_until_phi(l: &mut Learner, version: u64) {
    let start = Instant::now();
    while l.progress().phi_version.0 < version {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "φ version {} after 60 s, waiting for {version}",
            l.progress().phi_version.0
        );
        if l.train(usize::MAX).unwrap() == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

/// The store's priorities, as bits, over every candidate.
fn priorities(l: &Learner) -> Vec<u32> {
    let store = l.phi_store();
    store
        .candidates()
        .iter()
        .map(|c| store.priority(c.run, c.t).unwrap().to_bits())
        .collect()
}

#[test]
fn a_background_round_gives_the_in_line_phi_and_priorities_bit_for_bit() {
    let mut in_line = due_learner(false);
    train_until_phi(&mut in_line, 1);
    let mut background = due_learner(true);
    let before = policy_values(&background, "encoder");
    train_until_phi(&mut background, 1);
    let after = policy_values(&background, "encoder");
    assert_ne!(before, after, "the round changed φ");
    assert_eq!(after, policy_values(&in_line, "encoder"));
    assert_eq!(priorities(&background), priorities(&in_line));
    assert_eq!(metric(&background, "phi/rounds"), 1.0);
    assert_eq!(metric(&background, "phi/steps"), 300.0);
    for loss in ["phi/round_start_loss", "phi/round_end_loss"] {
        assert_eq!(metric(&background, loss), metric(&in_line, loss), "{loss}");
    }
}

#[test]
fn sac_updates_run_beside_a_background_round_on_the_published_encoder_as_it_was() {
    let mut l = due_learner(true);
    let encoder = policy_values(&l, "encoder");
    let before = l.progress();
    let ran = l.train(usize::MAX).unwrap();
    // Collected only by a later call: the round is still active after the one that sent it.
    assert!(l.phi_round_active());
    assert_eq!(metric(&l, "phi/round_active"), 1.0);
    assert!(
        ran > 0,
        "SAC updates ran in the call that sent the round off"
    );
    assert!(l.progress().updates_low > before.updates_low);
    assert!(l.progress().env_step_budget > before.env_step_budget);
    assert_eq!(
        policy_values(&l, "encoder"),
        encoder,
        "the published encoder waits for the round's end"
    );
    assert_eq!(l.progress().phi_version, PhiVersion(0));
    ingest_episode(&mut l, 1, 10, 10, 2, 5);
    assert_eq!(
        l.phi_store().n_runs(),
        4,
        "the store is frozen for the round"
    );
    assert_eq!(l.phi_store().n_staged(), 1);
    train_until_phi(&mut l, 1);
    assert!(!l.phi_round_active());
    assert_ne!(policy_values(&l, "encoder"), encoder);
    assert_eq!(
        l.phi_store().n_runs(),
        5,
        "staged episodes enter after the round"
    );
    let (header, _) = l
        .publish_due()
        .unwrap()
        .expect("a new φ is published at once");
    assert_eq!(header.phi_version, PhiVersion(1));
}

#[test]
fn a_checkpoint_waits_for_a_background_round_and_a_restored_learner_goes_on_alike() {
    let config = config_with(true);
    let dir = std::env::temp_dir().join(format!("asi-phi-bg-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut l = due_learner(true);
    l.train(1).unwrap();
    assert!(l.phi_round_active());
    let err = l.save_checkpoint(&config, &dir).unwrap_err();
    assert!(matches!(err, CheckpointError::RoundActive), "{err}");
    l.finish_phi_round().unwrap();
    assert!(!l.phi_round_active());
    assert_eq!(l.progress().phi_version, PhiVersion(1));
    let Checkpoint { path, .. } = l.save_checkpoint(&config, &dir).unwrap();
    // Restored with rounds in the background, and in line (the key may change on resume).
    let (mut restored, _) = Learner::restore_checkpoint(&config, DIMS, &path).unwrap();
    let (mut in_line, _) = Learner::restore_checkpoint(&config_with(false), DIMS, &path).unwrap();
    assert_eq!(
        policy_values(&restored, "encoder"),
        policy_values(&l, "encoder")
    );
    // The second round (after 8 episodes) from all three: same φ, so the restored trainer's
    // copy, Adam state, generator and the store's priorities are the saved ones.
    for learner in [&mut l, &mut restored, &mut in_line] {
        for ep in 4..8 {
            ingest_episode(learner, 0, ep, 10, 2, 5);
        }
        train_until_phi(learner, 2);
    }
    let phi = policy_values(&l, "encoder");
    assert_eq!(policy_values(&restored, "encoder"), phi);
    assert_eq!(policy_values(&in_line, "encoder"), phi);
    assert!(metric(&restored, "phi/stable_loss") > 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}
