//! Self-imitation on states that make its losses non-finite (issue #7, hostile input): such a
//! level step is skipped and counted (`si/skipped_nonfinite`), no Adam step touches the
//! policies, the round is done (not retried, so a restarted learner cannot loop on it), the
//! counter survives a checkpoint, and SI trains normally once the bad entries are gone.
//!
//! The bad states are finite (the protocol refuses NaN and infinities) but ±3e38, and so are the
//! points of the routes a hostile graph returns: the high loss overflows f32; the low loss is
//! finite (π_lo's tanh saturates: 0) but its gradient is not (without the gradient check, the
//! Adam step turned 112 of the 468 low-policy values into NaN).

mod common;

use std::fs;
use std::path::PathBuf;

use common::*;
use learner::learner::checkpoint::{checksum, Manifest, MANIFEST};
use learner::si::SiStats;
use learner::{Learner, RouteSource, RoutesReply};
use protocol::graph::{LatentPoint, RouteAnswer, RouteQuery};
use protocol::{Config, PhiVersion};

/// SI on, its buffer of 40 entries (4 episodes of 10 steps), batches of 8, rounds due from the
/// third episode on.
fn config() -> Config {
    si_config(true, 40)
}

/// Answers every query with the same route of 6 points of ±3e38 (finite, so usable).
struct HugeRoutes;

impl RouteSource for HugeRoutes {
    fn routes(&mut self, queries: &[RouteQuery], _phi_version: PhiVersion) -> RoutesReply {
        let route: Vec<LatentPoint> = (0..6)
            .map(|i| {
                let h = huge_state(i);
                [h[0], -h[1]]
            })
            .collect();
        RoutesReply::Answered(
            queries
                .iter()
                .map(|_| RouteAnswer::Direct(route.clone()))
                .collect(),
        )
    }
}

fn stats(l: &Learner) -> SiStats {
    *l.self_imitation().stats()
}

/// A learner whose SI buffer holds only the huge states of 3 episodes, one round due.
fn fed_huge_states() -> Learner {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    for ep in 0..3 {
        ingest_episode_in_one_chunk(&mut l, ep, true);
    }
    assert_eq!((l.self_imitation().buffer().len(), l.si_pending()), (30, 1));
    l
}

#[test]
fn a_round_with_non_finite_losses_or_gradients_skips_both_steps_leaves_the_policies_bit_identical()
{
    let mut l = fed_huge_states();
    let (high0, low0) = (
        policy_values(&l, "high_policy"),
        policy_values(&l, "low_policy"),
    );
    let steps = l
        .train_self_imitation(&mut HugeRoutes)
        .expect("a non-finite SI loss is not an error");
    assert_eq!(steps, 0, "no Adam step");
    assert_eq!(policy_values(&l, "high_policy"), high0, "π_hi untouched");
    assert_eq!(policy_values(&l, "low_policy"), low0, "π_lo untouched");
    let s = stats(&l);
    assert_eq!(
        (s.skipped_nonfinite, s.skipped(), s.high_steps, s.low_steps),
        (2, 2, 0, 0)
    );
    assert_eq!(l.si_pending(), 0, "the round is done, not retried");
    assert_eq!(metric(&l, "si/skipped_nonfinite"), 2.0);
    assert_eq!(metric(&l, "si/skipped"), 2.0);
    assert!(
        s.high.loss.is_finite() && s.low.loss.is_finite(),
        "the reported losses stay those of the latest step that ran"
    );
}

#[test]
fn with_ordinary_routes_only_the_non_finite_high_step_is_skipped() {
    let mut l = fed_huge_states();
    let (high0, low0) = (
        policy_values(&l, "high_policy"),
        policy_values(&l, "low_policy"),
    );
    // Routes along φ of the huge states: the usable ones lead far away (the high loss
    // overflows); π_lo, saturated, has a finite loss and gradient and takes its step.
    assert_eq!(
        l.train_self_imitation(&mut StraightRoutes::new(6)).unwrap(),
        1
    );
    let s = stats(&l);
    assert_eq!((s.skipped_nonfinite, s.high_steps, s.low_steps), (1, 0, 1));
    assert_eq!(policy_values(&l, "high_policy"), high0, "π_hi untouched");
    assert!(
        policy_values(&l, "low_policy")
            .iter()
            .zip(&low0)
            .all(|(&a, &b)| f32::from_bits(a).is_finite() && f32::from_bits(b).is_finite()),
        "π_lo stays finite"
    );
}

#[test]
fn self_imitation_trains_normally_once_the_bad_entries_are_evicted() {
    let mut l = fed_huge_states();
    l.train_self_imitation(&mut HugeRoutes).unwrap();
    assert_eq!(stats(&l).skipped_nonfinite, 2);
    // Four ordinary episodes fill the 40 entries; the huge ones are evicted a quarter at a time.
    for ep in 3..7 {
        ingest_episode_in_one_chunk(&mut l, ep, false);
    }
    assert_eq!(l.self_imitation().buffer().n_evicted(), 30);
    assert_eq!(l.si_pending(), 4);
    let (high0, low0) = (
        policy_values(&l, "high_policy"),
        policy_values(&l, "low_policy"),
    );
    let mut steps = 0;
    while l.si_pending() > 0 {
        steps += l.train_self_imitation(&mut StraightRoutes::new(6)).unwrap();
    }
    assert_eq!(steps, 8, "four rounds, a high and a low step each");
    let s = stats(&l);
    assert_eq!((s.high_steps, s.low_steps, s.skipped_nonfinite), (4, 4, 2));
    assert!(s.high.loss > 0.0 && s.high.loss.is_finite());
    assert!(s.low.loss > 0.0 && s.low.loss.is_finite());
    assert_ne!(policy_values(&l, "high_policy"), high0, "π_hi trained");
    assert_ne!(policy_values(&l, "low_policy"), low0, "π_lo trained");
}

/// Saves `l` into a fresh folder named after `name`; returns the folder and the checkpoint.
fn save(l: &Learner, name: &str) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("asi-si-nonfinite-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    let saved = l.save_checkpoint(&config(), &dir).unwrap();
    (dir, saved.path)
}

#[test]
fn the_non_finite_skip_count_survives_a_checkpoint() {
    let mut l = fed_huge_states();
    l.train_self_imitation(&mut HugeRoutes).unwrap();
    let (dir, ckpt) = save(&l, "roundtrip");
    let (restored, _) = Learner::restore_checkpoint(&config(), DIMS, &ckpt).unwrap();
    fs::remove_dir_all(&dir).unwrap();
    assert_eq!(stats(&restored).skipped_nonfinite, 2);
    assert_eq!(stats(&restored).skipped(), stats(&l).skipped());
}

#[test]
fn a_checkpoint_written_before_the_counter_existed_loads_with_it_at_zero() {
    let mut l = fed_huge_states();
    l.train_self_imitation(&mut HugeRoutes).unwrap();
    let (dir, ckpt) = save(&l, "older");
    // An older build wrote no `skipped_nonfinite` key: rename it (same length, so the
    // safetensors header keeps its size) and re-seal the manifest.
    let file = ckpt.join("si.safetensors");
    let bytes = fs::read(&file).unwrap();
    // The key is the only place the name occurs (the other counters are an unnamed list).
    let (key, other) = (b"skipped_nonfinite", b"unknown_key_xxxxx");
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("the key is written");
    let mut older = bytes.clone();
    older[at..at + key.len()].copy_from_slice(other);
    fs::write(&file, &older).unwrap();
    let mut manifest: Manifest =
        serde_json::from_slice(&fs::read(ckpt.join(MANIFEST)).unwrap()).unwrap();
    let entry = manifest
        .files
        .iter_mut()
        .find(|f| f.name == "si.safetensors")
        .unwrap();
    entry.checksum = format!("{:016x}", checksum(&older));
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&manifest).unwrap()).unwrap();
    let (restored, _) = Learner::restore_checkpoint(&config(), DIMS, &ckpt).unwrap();
    fs::remove_dir_all(&dir).unwrap();
    let (s, before) = (stats(&restored), stats(&l));
    assert_eq!(s.skipped_nonfinite, 0);
    assert_eq!((s.rounds_due, s.skipped()), (before.rounds_due, 0));
    assert_eq!(restored.self_imitation().buffer().len(), 30);
}
