//! The SAC update itself: Polyak averaging of the target critic, the online/target start, the
//! reported actor gradient norm, and a small learning sanity check (a one-step contextual
//! bandit).

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams, SacShape};
use nets::weights::vars_under;
use nets::LinearInit;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64Mcg;

const PARAMS: SacParams = SacParams {
    gamma: 0.99,
    tau: 0.05,
    lr: 3e-3,
    alpha: 0.01,
    auto_alpha: false,
    target_entropy: -1.0,
    critic_action_scale: 1.0,
    target_clip: None,
};

/// A 1-D state → 1-D action level with hidden [32, 32]; returns the maps too.
fn level(params: SacParams) -> (SacLevel, VarMap, VarMap) {
    let shape = SacShape {
        policy_in: 1,
        critic_in: 2,
        hidden: &[32, 32],
        action_dim: 1,
        action_scale: 1.0,
        init: LinearInit::XavierUniform,
    };
    let (nets, vm, tvm) = SacNets::seeded(&shape, 1).unwrap();
    (SacLevel::new("test", nets, params).unwrap(), vm, tvm)
}

fn tensor(values: &[f32]) -> Tensor {
    Tensor::from_slice(values, (values.len(), 1), &Device::Cpu).unwrap()
}

/// Bandit batch: s, a ~ U(−1, 1), r = −4 (a − s/2)², terminal (one-step episodes).
fn bandit_batch(rng: &mut Pcg64Mcg, b: usize) -> (SacBatch, Tensor, Tensor) {
    let s: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let a: Vec<f32> = (0..b).map(|_| rng.random_range(-1.0..1.0)).collect();
    let r: Vec<f32> = s
        .iter()
        .zip(&a)
        .map(|(s, a)| -4.0 * (a - 0.5 * s).powi(2))
        .collect();
    let mut noise = || {
        tensor(
            &(0..b)
                .map(|_| StandardNormal.sample(rng))
                .collect::<Vec<f32>>(),
        )
    };
    let (e1, e2) = (noise(), noise());
    let batch = SacBatch {
        head: tensor(&s),
        next_head: tensor(&s),
        tail: None,
        action: tensor(&a),
        reward: tensor(&r),
        terminal: tensor(&vec![1.0; b]),
    };
    (batch, e1, e2)
}

fn values(vm: &VarMap, prefix: &str) -> Vec<Vec<f32>> {
    vars_under(vm, prefix)
        .iter()
        .map(|v| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
        .collect()
}

#[test]
fn the_target_starts_as_a_copy_and_follows_by_polyak_averaging() {
    let (mut level, vm, tvm) = level(PARAMS);
    assert_eq!(values(&vm, "critic"), values(&tvm, "critic"));
    let before = values(&tvm, "critic");
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let (batch, e1, e2) = bandit_batch(&mut rng, 16);
    let stats = level.update(&batch, &e1, &e2).unwrap();
    assert!(stats.critic.loss.is_finite() && stats.actor.loss.is_finite());
    let online = values(&vm, "critic");
    for ((t_after, t_before), o) in values(&tvm, "critic").iter().zip(&before).zip(&online) {
        for ((ta, tb), o) in t_after.iter().zip(t_before).zip(o) {
            let want = 0.95 * tb + 0.05 * o;
            assert!((ta - want).abs() < 1e-6, "{ta} vs {want}");
        }
    }
    assert_ne!(online, before, "the critic moved");
}

#[test]
fn sac_learns_the_best_action_of_a_contextual_bandit() {
    let (mut level, _vm, _tvm) = level(PARAMS);
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    for _ in 0..500 {
        let (batch, e1, e2) = bandit_batch(&mut rng, 64);
        level.update(&batch, &e1, &e2).unwrap();
    }
    let s = [-0.8f32, -0.3, 0.0, 0.4, 0.9];
    let action: Vec<f32> = level
        .policy()
        .deterministic(&tensor(&s))
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    for (s, a) in s.iter().zip(&action) {
        assert!(
            (a - 0.5 * s).abs() < 0.15,
            "state {s}: action {a}, best {}",
            0.5 * s
        );
    }
}

#[test]
fn auto_alpha_moves_the_temperature() {
    let (mut level, _vm, _tvm) = level(SacParams {
        auto_alpha: true,
        alpha: 0.2,
        ..PARAMS
    });
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let start = level.alpha().unwrap();
    assert!((start - 0.2).abs() < 1e-6);
    for _ in 0..20 {
        let (batch, e1, e2) = bandit_batch(&mut rng, 16);
        let stats = level.update(&batch, &e1, &e2).unwrap();
        assert!(stats.alpha_loss.is_finite());
    }
    assert_ne!(level.alpha().unwrap(), start);
}

/// Σ g² over `prefix`'s variables of `vm` in `grads` (f64).
fn sum_sq(grads: &candle_core::backprop::GradStore, vm: &VarMap, prefix: &str) -> f64 {
    vars_under(vm, prefix)
        .iter()
        .filter_map(|v| grads.get(v.as_tensor()))
        .flat_map(|g| g.flatten_all().unwrap().to_vec1::<f32>().unwrap())
        .map(|g| f64::from(g) * f64::from(g))
        .sum()
}

#[test]
fn the_actor_grad_norm_is_the_norm_of_the_actor_loss_gradient_over_the_policy_only() {
    let (mut level, vm, _tvm) = level(PARAMS);
    let mut rng = Pcg64Mcg::seed_from_u64(6);
    // A first update, so that the critic the actor step meets is not the initial one.
    let (batch, e1, e2) = bandit_batch(&mut rng, 16);
    level.update(&batch, &e1, &e2).unwrap();
    let policy_before = values(&vm, "policy");
    let (batch, next_eps, eps) = bandit_batch(&mut rng, 16);
    let stats = level.update(&batch, &next_eps, &eps).unwrap();

    // L_π by hand, with the policy as the actor step found it (put back here) and the online
    // critic as it is now (the actor, temperature and Polyak steps leave it alone).
    for (var, before) in vars_under(&vm, "policy").iter().zip(&policy_before) {
        let t = Tensor::from_slice(before, var.shape(), &Device::Cpu).unwrap();
        var.set(&t).unwrap();
    }
    let (action, log_prob) = level.policy().sample(&batch.head, &eps).unwrap();
    let q_in = Tensor::cat(&[&batch.head, &action], 1).unwrap();
    let min_q = level.critic().min_q(&q_in).unwrap();
    let loss = (log_prob.affine(PARAMS.alpha, 0.0).unwrap() - min_q)
        .unwrap()
        .mean_all()
        .unwrap();
    let loss_value = f64::from(loss.to_scalar::<f32>().unwrap());
    assert!((loss_value - stats.actor.loss).abs() <= 1e-6 * (1.0 + loss_value.abs()));
    let grads = loss.backward().unwrap();
    let policy_sq = sum_sq(&grads, &vm, "policy");
    let want = policy_sq.sqrt();
    let got = stats.actor_grad_norm;
    assert!(want > 0.0);
    assert!(
        (got - want).abs() <= 1e-5 * want,
        "reported {got}, by hand {want}"
    );
    // The critic's variables have a gradient too, which the norm leaves out.
    let with_critic = (policy_sq + sum_sq(&grads, &vm, "critic")).sqrt();
    assert!(with_critic > want * (1.0 + 1e-3), "{with_critic} vs {want}");
}
