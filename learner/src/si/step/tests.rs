//! The SI gradient norms are those of the gradients the Adam steps took: a round on freshly
//! built networks (both low-level algorithms) with straight-line routes, and each reported norm
//! against the gradient read back from the level's Adam first moments, m = β₁·m₀ + (1 − β₁)·g.

use nets::{spec_from_config, TaskDims};
use protocol::config::LowAlgo;
use protocol::graph::RouteAnswer;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::*;
use crate::adam::AdamState;
use crate::setup::build_networks;

const DIMS: TaskDims = TaskDims {
    obs_dim: 3,
    goal_dim: 2,
    action_dim: 2,
    action_scale: 1.0,
};

/// Routes of six evenly spaced nodes from each query's start to its end.
struct StraightRoutes;

impl RouteSource for StraightRoutes {
    fn routes(&mut self, queries: &[RouteQuery], _phi_version: PhiVersion) -> RoutesReply {
        let line = |q: &RouteQuery| {
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

/// Tiny networks, SI on from the first episode, batches of 8.
fn config(low: LowAlgo) -> Config {
    let mut c = Config::default();
    c.encoder.hidden = vec![8];
    c.learner.high.hidden = vec![16, 16];
    c.learner.low.hidden = vec![16, 16];
    c.learner.low.algo = low;
    c.learner.low.deterministic.actor_hidden = vec![16, 16];
    c.learner.low.deterministic.critic_hidden = vec![16, 16];
    c.asi.self_imitation = true;
    c.asi.si_start_episode = 0;
    c.asi.si_batch_size = 8;
    c.asi.si_buffer_capacity = 100;
    c
}

/// The Adam state of a level's policy optimiser (`policy` for SAC, `actor` for deterministic).
fn policy_state(opts: Vec<(&'static str, &crate::adam::Adam)>) -> AdamState {
    opts.into_iter()
        .find(|(name, _)| matches!(*name, "policy" | "actor"))
        .map(|(_, opt)| opt.export_state())
        .unwrap()
}

/// ‖g‖₂ of the step between `before` and `after`: g = (m − β₁·m₀) / (1 − β₁) per element.
fn absorbed_norm(before: &AdamState, after: &AdamState, beta1: f64) -> f64 {
    assert_eq!(after.step, before.step + 1, "one Adam step");
    let m0 = before.m.iter().flatten();
    let m = after.m.iter().flatten();
    m.zip(m0)
        .map(|(&m, &m0)| (f64::from(m) - beta1 * f64::from(m0)) / (1.0 - beta1))
        .map(|g| g * g)
        .sum::<f64>()
        .sqrt()
}

#[test]
fn each_reported_si_grad_norm_is_the_norm_of_the_gradient_its_adam_step_took() {
    for low in [LowAlgo::Sac, LowAlgo::Deterministic] {
        let config = config(low);
        config.validate().unwrap();
        let spec = spec_from_config(&config, DIMS).unwrap();
        let mut nets = build_networks(&config, &spec, 5).unwrap();
        let mut si = SelfImitation::new(SiParams::from_config(&config), 3, 2);
        let episode = si.buffer_mut().begin_episode(&[0.0, 0.0, 0.5]).unwrap();
        for t in 0..10 {
            let obs = [t as f32, 0.3 * t as f32, 0.5];
            assert!(si.buffer_mut().push(episode, &obs, &[5.0, 6.0]));
        }
        si.on_episode_end(1);
        let high0 = policy_state(nets.high.optimizers().0);
        let low0 = policy_state(nets.low.optimizers().0);
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        let steps = si
            .run_round(&mut nets, &mut rng, &mut StraightRoutes, PhiVersion(0))
            .unwrap();
        assert_eq!(steps, 2, "{low:?}: a high and a low step");
        let beta1 = crate::adam::AdamParams::default().beta1;
        let high = absorbed_norm(&high0, &policy_state(nets.high.optimizers().0), beta1);
        let low_norm = absorbed_norm(&low0, &policy_state(nets.low.optimizers().0), beta1);
        let s = si.stats();
        for (what, got, want) in [
            ("high", s.high_grad_norm, high),
            ("low", s.low_grad_norm, low_norm),
        ] {
            assert!(want > 0.0, "{low:?} {what}: a non-zero gradient");
            assert!(
                (got - want).abs() <= 1e-5 * want,
                "{low:?} {what}: reported {got}, Adam took {want}"
            );
        }
    }
}
