//! The actor state machine on the real point-maze task: chunk shapes, episode bookkeeping,
//! φ labels, subgoal holding, determinism, physics failures and weights loading.

mod common;
use common::*;

use actor::{Actor, ActorError, Chunk, NoGraph};
use candle_core::Device;
use candle_nn::VarMap;
use envs::api::{Env, EnvError, EnvSpec, Reset, Step};
use envs::maze::Maze;
use protocol::config::LowAlgo;
use protocol::{
    ActorId, Config, DecisionKind, PhiVersion, PolicyVersion, StepRecord, TrajectoryFlags as F,
    WeightsHeader,
};

#[test]
fn chunks_have_the_configured_lengths_and_every_record_decodes() {
    let mut actor = Actor::new(&config(30, 100), ActorId(3), 1).unwrap();
    for episode in episodes(&mut actor, &mut NoGraph, 2) {
        let lengths: Vec<u32> = episode.iter().map(|c| c.header.n_steps).collect();
        assert_eq!(lengths, [30, 30, 30, 10]);
        for chunk in &episode {
            let h = &chunk.header;
            assert_eq!(h.step_layout().unwrap(), actor.layout());
            assert_eq!(h.actor_id, ActorId(3));
            assert_eq!(
                chunk.records.len(),
                h.n_steps as usize * actor.layout().record_len()
            );
            decode(chunk);
        }
    }
    let stats = actor.stats();
    assert_eq!((stats.env_steps, stats.episodes), (200, 2));
}

#[test]
fn chunk_indices_increment_and_flags_mark_each_episode_start_and_end_once() {
    let mut actor = Actor::new(&config(40, 100), ActorId(1), 2).unwrap();
    let episodes = episodes(&mut actor, &mut NoGraph, 3);
    let mut ids = Vec::new();
    for episode in &episodes {
        let id = episode[0].header.episode_id;
        ids.push(id);
        assert_eq!(id.0 >> 40, 1, "the actor id sits above bit 40");
        let mut next_step = 0;
        for (i, chunk) in episode.iter().enumerate() {
            let h = &chunk.header;
            assert_eq!(
                (h.episode_id, h.chunk_index, h.first_env_step),
                (id, i as u32, next_step)
            );
            next_step += u64::from(h.n_steps);
            assert_eq!(h.flags.contains(F::EPISODE_START), i == 0);
            assert_eq!(h.flags.contains(F::EPISODE_END), i + 1 == episode.len());
        }
        let last = episode.last().unwrap();
        assert!(
            last.header.flags.contains(F::TRUNCATED) && !last.header.flags.contains(F::TERMINATED)
        );
        let records = records_of(episode);
        assert!(records.last().unwrap().truncated);
        assert_eq!(
            records
                .iter()
                .filter(|r| r.truncated || r.terminated)
                .count(),
            1
        );
    }
    ids.dedup();
    assert_eq!(ids.len(), 3, "episode ids are distinct");
}

#[test]
fn phi_of_each_step_is_the_next_phi_of_the_step_before() {
    let mut actor = Actor::new(&config(25, 100), ActorId(0), 3).unwrap();
    for episode in episodes(&mut actor, &mut NoGraph, 2) {
        let records = records_of(&episode);
        for pair in records.windows(2) {
            assert_eq!(pair[1].phi, pair[0].next_phi);
            assert_eq!(pair[1].obs, pair[0].next_obs);
        }
    }
}

#[test]
fn the_subgoal_is_held_for_c_steps_and_changes_only_on_decision_steps() {
    let mut actor = Actor::new(&config(30, 100), ActorId(0), 4).unwrap();
    for (e, episode) in episodes(&mut actor, &mut NoGraph, 2).iter().enumerate() {
        let expected_kind = if e == 0 {
            DecisionKind::Random
        } else {
            DecisionKind::Policy
        };
        let records = records_of(episode);
        for (t, r) in records.iter().enumerate() {
            if t % 10 == 0 {
                assert_eq!(r.decision, expected_kind, "step {t}");
                assert!(r.high_action.iter().all(|d| d.abs() <= 10.0));
                for ((d, sg), phi) in r.high_action.iter().zip(&r.subgoal).zip(&r.phi) {
                    assert!(
                        (d - (sg - phi)).abs() <= 1e-4 * sg.abs().max(1.0),
                        "step {t}: {r:?}"
                    );
                }
            } else {
                assert_eq!(r.decision, DecisionKind::None, "step {t}");
                assert!(r.high_action.iter().all(|d| *d == 0.0));
                assert_eq!(r.subgoal, records[t - 1].subgoal, "step {t}");
            }
            assert!(
                r.action.iter().all(|a| a.abs() <= 1.0),
                "actions are clipped to the point's bound"
            );
        }
    }
}

#[test]
fn the_same_seed_gives_identical_chunks_and_another_seed_does_not() {
    let run = |actor_id, seed| {
        let mut actor = Actor::new(&config(30, 100), ActorId(actor_id), seed).unwrap();
        (0..9)
            .map(|_| actor.next_chunk(&mut NoGraph).unwrap())
            .collect::<Vec<_>>()
    };
    assert_eq!(run(2, 11), run(2, 11));
    assert_ne!(run(2, 11)[0].records, run(2, 12)[0].records);
    assert_ne!(run(2, 11)[0].records, run(3, 11)[0].records);
}

#[test]
fn the_deterministic_low_variant_acts_within_bounds() {
    let mut config = config(50, 100);
    config.learner.low.algo = LowAlgo::Deterministic;
    config.learner.low.deterministic.actor_hidden = vec![32, 32];
    config.learner.low.deterministic.critic_hidden = vec![32, 32];
    let mut actor = Actor::new(&config, ActorId(0), 5).unwrap();
    let records = records_of(&episodes(&mut actor, &mut NoGraph, 1)[0]);
    assert_eq!(records.len(), 100);
    assert!(records
        .iter()
        .all(|r| r.action.iter().all(|a| a.abs() <= 1.0)));
}

#[test]
fn the_configured_episode_length_is_the_envs_own_even_beyond_the_task_default() {
    let mut actor = Actor::new(&config(100, 600), ActorId(0), 0).unwrap();
    let episode = &episodes(&mut actor, &mut NoGraph, 1)[0];
    let records = records_of(episode);
    assert_eq!(
        records.len(),
        600,
        "pointmaze-u's own 500 steps are overridden"
    );
    assert!(records[599].truncated && records[..599].iter().all(|r| !r.truncated));
}

#[test]
fn an_env_built_with_another_length_than_the_config_is_refused_with_both_numbers() {
    let env = envs::registry::make("pointmaze-u").unwrap();
    let err = match Actor::with_env(&config(50, 100), ActorId(0), 0, env) {
        Err(err) => err.to_string(),
        Ok(_) => panic!("an env of 500 steps under env.episode_length = 100 must be refused"),
    };
    assert!(err.contains("100") && err.contains("500"), "{err}");
}

/// Point maze U whose step `fail_at` (0-based) reports a physics failure, in the first episode
/// only or in every episode.
struct FailingEnv {
    inner: Box<dyn Env>,
    fail_at: u32,
    every_episode: bool,
    n_resets: u32,
    t: u32,
    n_failures: u64,
}

impl Env for FailingEnv {
    fn spec(&self) -> &EnvSpec {
        self.inner.spec()
    }
    fn reset(&mut self, seed: u64) -> Reset {
        self.t = 0;
        self.n_resets += 1;
        self.inner.reset(seed)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut step = self.inner.step(action)?;
        if self.t == self.fail_at && (self.every_episode || self.n_resets == 1) {
            step.terminated = true;
            step.info.physics_failure = true;
            self.n_failures += 1;
        }
        self.t += 1;
        Ok(step)
    }
    fn goal(&self) -> [f32; 2] {
        self.inner.goal()
    }
    fn set_goal(&mut self, goal: [f32; 2]) -> Result<(), EnvError> {
        self.inner.set_goal(goal)
    }
    fn achieved_goal(&self, obs: &[f32]) -> [f32; 2] {
        self.inner.achieved_goal(obs)
    }
    fn maze(&self) -> Option<&Maze> {
        self.inner.maze()
    }
    fn n_physics_failures(&self) -> u64 {
        self.n_failures
    }
}

fn failing_actor(fail_at: u32, every_episode: bool) -> Actor {
    let options = envs::EnvOptions {
        max_steps: Some(100),
    };
    let inner = envs::make_with("pointmaze-u", options).unwrap();
    let env = FailingEnv {
        inner,
        fail_at,
        every_episode,
        n_resets: 0,
        t: 0,
        n_failures: 0,
    };
    Actor::with_env(&config(30, 100), ActorId(0), 6, Box::new(env)).unwrap()
}

#[test]
fn a_physics_failure_on_a_chunk_boundary_still_ends_the_episode_in_a_non_empty_chunk() {
    let mut actor = failing_actor(60, false);
    let episode = &episodes(&mut actor, &mut NoGraph, 1)[0];
    let lengths: Vec<u32> = episode.iter().map(|c| c.header.n_steps).collect();
    assert_eq!(lengths, [30, 30], "the failing step 60 is not recorded");
    let end = episode[1].header.flags;
    assert!(
        end.contains(F::EPISODE_END | F::TERMINATED | F::PHYSICS_FAILURE),
        "{end:?}"
    );
    assert!(!episode[0].header.flags.contains(F::PHYSICS_FAILURE));
    assert!(records_of(episode).iter().all(|r| !r.terminated));
    let stats = actor.stats();
    assert_eq!(
        (stats.n_physics_failures, stats.episodes, stats.env_steps),
        (1, 1, 61)
    );
}

#[test]
fn a_physics_failure_on_the_first_step_yields_no_chunk_and_the_next_episode_follows() {
    let mut actor = failing_actor(0, false);
    let chunk = actor.next_chunk(&mut NoGraph).unwrap();
    assert_eq!(
        chunk.header.episode_id.0, 1,
        "episode 0 left nothing to send"
    );
    assert_eq!(chunk.header.chunk_index, 0);
    assert!(chunk.header.flags.contains(F::EPISODE_START));
    assert_eq!(
        (actor.stats().n_physics_failures, actor.stats().episodes),
        (1, 1)
    );
}

#[test]
fn an_env_that_fails_every_first_step_is_reported_instead_of_looping() {
    let mut actor = failing_actor(0, true);
    let err = actor.next_chunk(&mut NoGraph).unwrap_err();
    assert!(matches!(err, ActorError::NoProgress { .. }), "{err}");
}

/// Actor-side weights of a `PolicySet` with `actor`'s spec and another init seed.
fn foreign_weights(actor: &Actor, seed: u64) -> (Vec<u8>, u64) {
    let varmap = VarMap::new();
    let vb = nets::seeded_var_builder(&varmap, seed, &Device::Cpu);
    nets::PolicySet::new(actor.nets_spec(), &vb).unwrap();
    (
        nets::to_safetensors_bytes(&varmap).unwrap(),
        nets::layout_hash(&varmap),
    )
}

fn header(policy: u64, phi: u64, layout_hash: u64, bytes: &[u8]) -> WeightsHeader {
    WeightsHeader::new(
        PolicyVersion(policy),
        PhiVersion(phi),
        layout_hash,
        bytes.len(),
    )
}

#[test]
fn weights_of_another_policy_set_load_and_change_the_actions() {
    let config = config(30, 100);
    let mut plain = Actor::new(&config, ActorId(0), 7).unwrap();
    let mut loaded = Actor::new(&config, ActorId(0), 7).unwrap();
    let (bytes, hash) = foreign_weights(&loaded, 99);
    assert_eq!(hash, loaded.layout_hash());
    loaded
        .load_weights(&header(4, 2, hash, &bytes), &bytes)
        .unwrap();
    assert_eq!(loaded.weights_bytes().unwrap(), bytes);
    let stats = loaded.stats();
    assert_eq!(
        (stats.policy_version, stats.phi_version),
        (PolicyVersion(4), PhiVersion(2))
    );
    let (a, b) = (
        plain.next_chunk(&mut NoGraph).unwrap(),
        loaded.next_chunk(&mut NoGraph).unwrap(),
    );
    let (a, b) = (decode(&a), decode(&b));
    assert_eq!(a[0].obs, b[0].obs, "same env seed, same start");
    assert_ne!(a[0].action, b[0].action);
    assert_ne!(a[0].phi, b[0].phi);
}

#[test]
fn a_load_mid_episode_relabels_phi_and_versions_the_following_chunks() {
    let mut actor = Actor::new(&config(30, 100), ActorId(0), 8).unwrap();
    let first = actor.next_chunk(&mut NoGraph).unwrap();
    let (bytes, hash) = foreign_weights(&actor, 5);
    actor
        .load_weights(&header(1, 1, hash, &bytes), &bytes)
        .unwrap();
    let second = actor.next_chunk(&mut NoGraph).unwrap();
    let third = actor.next_chunk(&mut NoGraph).unwrap();
    // The second chunk's first step was acted before the load: its policy version is still 0,
    // but every φ value in it is from the new encoder.
    assert_eq!(
        (second.header.policy_version, second.header.phi_version),
        (PolicyVersion(0), PhiVersion(1))
    );
    assert_eq!(
        (third.header.policy_version, third.header.phi_version),
        (PolicyVersion(1), PhiVersion(1))
    );
    let records: Vec<StepRecord> = [&second, &third].into_iter().flat_map(decode).collect();
    for pair in records.windows(2) {
        assert_eq!(pair[1].phi, pair[0].next_phi);
    }
    let before = decode(&first);
    assert_eq!(records[0].obs, before.last().unwrap().next_obs);
    assert_ne!(
        records[0].phi,
        before.last().unwrap().next_phi,
        "relabelled under the new φ"
    );
    for (t, r) in records.iter().enumerate() {
        let t = t + 30;
        if t % 10 != 0 {
            continue;
        }
        for ((d, sg), phi) in r.high_action.iter().zip(&r.subgoal).zip(&r.phi) {
            assert!(
                (d - (sg - phi)).abs() <= 1e-4 * sg.abs().max(1.0),
                "step {t}: {r:?}"
            );
        }
    }
}

#[test]
fn weights_with_a_wrong_hash_version_length_or_content_are_refused_and_change_nothing() {
    let config = config(30, 100);
    let mut reference = Actor::new(&config, ActorId(0), 9).unwrap();
    let mut actor = Actor::new(&config, ActorId(0), 9).unwrap();
    assert_eq!(
        reference.next_chunk(&mut NoGraph).unwrap(),
        actor.next_chunk(&mut NoGraph).unwrap()
    );
    let (bytes, hash) = foreign_weights(&actor, 3);
    let mut old_protocol = header(1, 1, hash, &bytes);
    old_protocol.protocol_version += 1;
    let garbage = vec![7u8; 64];
    let mut small = Config::default();
    small.env.task = "pointmaze-u".into();
    let other_layout = Actor::new(&small, ActorId(0), 0).unwrap();
    let (other_bytes, other_hash) = foreign_weights(&other_layout, 3);
    let cases: [(WeightsHeader, &[u8], &str); 5] = [
        (header(1, 1, hash ^ 1, &bytes), &bytes, "layout hash"),
        (old_protocol, &bytes, "protocol version"),
        (header(1, 1, hash, &bytes[..10]), &bytes, "length"),
        (header(1, 1, hash, &garbage), &garbage, "safetensors"),
        (
            header(1, 1, other_hash, &other_bytes),
            &other_bytes,
            "layout hash",
        ),
    ];
    for (n, (header, payload, what)) in cases.into_iter().enumerate() {
        let err = actor.load_weights(&header, payload).unwrap_err();
        assert!(matches!(err, ActorError::WeightsRejected { .. }));
        assert!(
            err.to_string().contains(what),
            "expected `{what}` in: {err}"
        );
        assert_eq!(actor.stats().n_weights_rejected, n as u64 + 1);
    }
    assert_eq!(actor.stats().policy_version, PolicyVersion(0));
    for _ in 0..4 {
        assert_eq!(
            reference.next_chunk(&mut NoGraph).unwrap(),
            actor.next_chunk(&mut NoGraph).unwrap()
        );
    }
}

#[test]
fn weights_holding_nan_are_refused_and_change_nothing() {
    let config = config(30, 100);
    let mut reference = Actor::new(&config, ActorId(0), 10).unwrap();
    let mut actor = Actor::new(&config, ActorId(0), 10).unwrap();
    let varmap = VarMap::new();
    let vb = nets::seeded_var_builder(&varmap, 1, &Device::Cpu);
    nets::PolicySet::new(actor.nets_spec(), &vb).unwrap();
    {
        let data = varmap.data().lock().unwrap();
        let var = &data["low_policy.mean.bias"];
        let nan = candle_core::Tensor::full(f32::NAN, var.shape(), &Device::Cpu).unwrap();
        var.set(&nan).unwrap();
    }
    let bytes = nets::to_safetensors_bytes(&varmap).unwrap();
    let err = actor
        .load_weights(&header(1, 1, actor.layout_hash(), &bytes), &bytes)
        .unwrap_err();
    assert!(err.to_string().contains("low_policy.mean.bias"), "{err}");
    for _ in 0..3 {
        assert_eq!(
            reference.next_chunk(&mut NoGraph).unwrap(),
            actor.next_chunk(&mut NoGraph).unwrap()
        );
    }
}

#[test]
fn an_actor_restored_between_episodes_continues_with_the_same_chunks_and_counters() {
    let mut saved = failing_actor(60, true);
    episodes(&mut saved, &mut NoGraph, 2);
    assert!(!saved.has_open_episode());
    let state = saved.save_state();
    assert!(!state.had_open_episode);
    assert_eq!(state.n_episodes_started, 2);
    let mut restored = failing_actor(60, true);
    restored.restore_state(state.clone()).unwrap();
    assert_eq!(restored.stats(), saved.stats());
    assert_eq!(restored.stats().n_physics_failures, 2);
    let mut counter_only = failing_actor(60, true);
    counter_only.start_at_episode(2, 0).unwrap();
    let expected = episodes(&mut saved, &mut NoGraph, 2);
    assert_eq!(episodes(&mut restored, &mut NoGraph, 2), expected);
    assert_eq!(restored.stats(), saved.stats());
    assert_eq!(restored.stats().n_physics_failures, 4);
    assert_ne!(
        episodes(&mut counter_only, &mut NoGraph, 2),
        expected,
        "the episode counter alone does not restore the generator"
    );
    assert!(
        restored.restore_state(state).is_err(),
        "a state goes into a fresh actor only"
    );
}

#[test]
fn an_actor_saved_mid_episode_restores_as_if_that_episode_was_abandoned() {
    let mut saved = failing_actor(60, true);
    saved.next_chunk(&mut NoGraph).unwrap();
    assert!(saved.has_open_episode());
    let state = saved.save_state();
    assert!(state.had_open_episode);
    let mut restored = Actor::new(&config(30, 100), ActorId(0), 6).unwrap();
    restored.restore_state(state).unwrap();
    let next = restored.next_chunk(&mut NoGraph).unwrap();
    assert!(next.header.flags.contains(F::EPISODE_START));
    assert_eq!(
        next.header.episode_id,
        actor::seeds::episode_id(ActorId(0), 1).unwrap()
    );
    let wrong_id = Actor::new(&config(30, 100), ActorId(1), 6)
        .unwrap()
        .restore_state(saved.save_state());
    assert!(wrong_id.is_err());
}

/// The decision kinds of the decision steps of `episode`.
fn decision_kinds(episode: &[Chunk]) -> Vec<DecisionKind> {
    records_of(episode)
        .iter()
        .map(|r| r.decision)
        .filter(|d| *d != DecisionKind::None)
        .collect()
}

#[test]
fn the_random_warm_up_is_shared_by_the_actors_and_a_later_start_skips_it() {
    let mut config = config(30, 60);
    config.learner.high.random_episodes = 3;
    config.run.n_actors = 2;
    assert_eq!(actor::warm_up_share(&config, 0), 2);
    assert_eq!(
        actor::warm_up_share(&config, 1),
        1,
        "2 episodes left over 2 actors"
    );
    assert_eq!(actor::warm_up_share(&config, 3), 0);
    assert_eq!(actor::warm_up_share(&config, 50), 0);
    let mut actor = Actor::new(&config, ActorId(1), 4).unwrap();
    let kinds: Vec<Vec<DecisionKind>> = episodes(&mut actor, &mut NoGraph, 3)
        .iter()
        .map(|e| decision_kinds(e))
        .collect();
    assert!(kinds[..2]
        .iter()
        .flatten()
        .all(|d| *d == DecisionKind::Random));
    assert!(
        kinds[2].iter().all(|d| *d == DecisionKind::Policy),
        "{kinds:?}"
    );
    assert_eq!(
        actor.stats().n_random_decisions,
        12,
        "2 episodes of 6 decisions"
    );
    assert_eq!(actor.stats().n_decisions, 18);

    // One actor takes the whole warm-up.
    config.run.n_actors = 1;
    let mut alone = Actor::new(&config, ActorId(0), 4).unwrap();
    episodes(&mut alone, &mut NoGraph, 3);
    assert_eq!(alone.stats().n_random_decisions, 18);

    // A restarted or resumed actor (a later incarnation) takes only what the run has left of
    // it: none after the warm-up, its share of the rest during it.
    let mut restarted = Actor::new(&config, ActorId(0), 4).unwrap();
    restarted.start_at_episode(1 << 28, 0).unwrap();
    let first = episodes(&mut restarted, &mut NoGraph, 1);
    assert!(decision_kinds(&first[0])
        .iter()
        .all(|d| *d == DecisionKind::Policy));
    assert_eq!(restarted.stats().n_random_decisions, 0);
    let mut during = Actor::new(&config, ActorId(0), 4).unwrap();
    during.start_at_episode(2 << 28, 1).unwrap();
    let kinds: Vec<Vec<DecisionKind>> = episodes(&mut during, &mut NoGraph, 2)
        .iter()
        .map(|e| decision_kinds(e))
        .collect();
    assert!(
        kinds[0].iter().all(|d| *d == DecisionKind::Random),
        "{kinds:?}"
    );
    assert!(
        kinds[1].iter().all(|d| *d == DecisionKind::Policy),
        "{kinds:?}"
    );
}

#[test]
fn a_start_at_episode_0_is_a_fresh_actor_and_a_later_start_draws_other_noise() {
    let config = config(30, 60);
    let fresh = episodes(
        &mut Actor::new(&config, ActorId(0), 4).unwrap(),
        &mut NoGraph,
        2,
    );
    let mut at_zero = Actor::new(&config, ActorId(0), 4).unwrap();
    at_zero
        .start_at_episode(0, actor::warm_up_share(&config, 0))
        .unwrap();
    assert!(
        episodes(&mut at_zero, &mut NoGraph, 2) == fresh,
        "a start at 0 changes nothing"
    );
    // Restored from the state of an actor that started at 2^28 (same env seeds and episode
    // ids as a later start) but with the generator of a fresh actor: a start at 2^28 must not
    // act like it, or a restarted actor replays the first start's noise.
    let mut later = Actor::new(&config, ActorId(0), 4).unwrap();
    later.start_at_episode(1 << 28, 0).unwrap();
    let mut counter_only = Actor::new(&config, ActorId(0), 4).unwrap();
    let mut state = Actor::new(&config, ActorId(0), 4).unwrap().save_state();
    state.n_episodes_started = 1 << 28;
    counter_only.restore_state(state).unwrap();
    let (a, b) = (
        episodes(&mut later, &mut NoGraph, 1),
        episodes(&mut counter_only, &mut NoGraph, 1),
    );
    assert_eq!(a[0][0].header.episode_id, b[0][0].header.episode_id);
    assert!(
        a != b,
        "the generator of a later start is a stream of its own"
    );
}

#[test]
fn the_last_episodes_end_position_is_its_last_next_observation() {
    let mut actor = Actor::new(&config(30, 100), ActorId(0), 4).unwrap();
    assert_eq!(
        actor.stats().last_episode_xy,
        None,
        "no episode finished yet"
    );
    let second = episodes(&mut actor, &mut NoGraph, 2).pop().unwrap();
    let records = records_of(&second);
    let (first, last) = (&records[0], records.last().unwrap());
    assert!(last.truncated);
    assert_eq!(
        actor.stats().last_episode_xy,
        Some([last.next_obs[0], last.next_obs[1]])
    );
    assert_ne!(
        actor.stats().last_episode_xy,
        Some([first.obs[0], first.obs[1]]),
        "where it ended, not where it started"
    );
}
