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
use protocol::{Config, PhiVersion, TrajectoryFlags};

/// SI buffer of 40 entries (4 episodes of 10 steps), batches of 8, rounds due from the third
/// episode on.
fn config() -> Config {
    let mut c = common::config();
    c.asi.self_imitation = true;
    c.asi.si_start_episode = 2;
    c.asi.si_batch_size = 8;
    c.asi.si_buffer_capacity = 40;
    c.validate().unwrap();
    c
}

/// Answers every query with a straight route of 6 points from its start to its end.
struct StraightRoutes;

impl RouteSource for StraightRoutes {
    fn routes(&mut self, queries: &[RouteQuery], _phi_version: PhiVersion) -> RoutesReply {
        let line = |q: &RouteQuery| -> Vec<LatentPoint> {
            (0..6)
                .map(|i| {
                    let f = i as f32 / 5.0;
                    [
                        q.start[0] + f * (q.end[0] - q.start[0]),
                        q.start[1] + f * (q.end[1] - q.start[1]),
                    ]
                })
                .collect()
        };
        RoutesReply::Answered(
            queries
                .iter()
                .map(|q| RouteAnswer::Direct(line(q)))
                .collect(),
        )
    }
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

/// The overflowing state at time `t`: all components ±3e38, the sign alternating with `t`.
fn huge_state(t: usize) -> [f32; 3] {
    let sign = if t.is_multiple_of(2) { 1.0 } else { -1.0 };
    [sign * 3.0e38; 3]
}

/// Ingests episode `ep` (10 steps, one chunk), its states huge or the common ones.
fn ingest_episode_of(l: &mut Learner, ep: u64, huge: bool) {
    let mut records = steps(0..10, ep, 2, 9);
    if huge {
        for (t, r) in records.iter_mut().enumerate() {
            r.obs = huge_state(t).to_vec();
            r.next_obs = huge_state(t + 1).to_vec();
        }
    }
    let flags =
        TrajectoryFlags::EPISODE_START | TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
    ingest(l, 0, ep, 0, &records, flags).unwrap();
}

/// The values of the policy variables whose names start with `prefix`, name-sorted.
fn policy_values(l: &Learner, prefix: &str) -> Vec<u32> {
    let data = l.policy_varmap().data().lock().unwrap();
    let mut names: Vec<_> = data
        .keys()
        .filter(|k| k.starts_with(prefix))
        .cloned()
        .collect();
    names.sort();
    // Bit patterns, so that the comparison is exact (and NaN would not equal itself).
    names
        .iter()
        .flat_map(|n| {
            data[n]
                .as_tensor()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
                .into_iter()
                .map(f32::to_bits)
        })
        .collect()
}

fn stats(l: &Learner) -> SiStats {
    *l.self_imitation().stats()
}

fn metric(l: &Learner, name: &str) -> f64 {
    l.metrics()
        .into_iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("{name} missing"))
        .1
}

/// A learner whose SI buffer holds only the huge states of 3 episodes, one round due.
fn fed_huge_states() -> Learner {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    for ep in 0..3 {
        ingest_episode_of(&mut l, ep, true);
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
    assert_eq!(l.train_self_imitation(&mut StraightRoutes).unwrap(), 1);
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
        ingest_episode_of(&mut l, ep, false);
    }
    assert_eq!(l.self_imitation().buffer().n_evicted(), 30);
    assert_eq!(l.si_pending(), 4);
    let (high0, low0) = (
        policy_values(&l, "high_policy"),
        policy_values(&l, "low_policy"),
    );
    let mut steps = 0;
    while l.si_pending() > 0 {
        steps += l.train_self_imitation(&mut StraightRoutes).unwrap();
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
