//! The deterministic low level's update ([`learner::deterministic::update`]): the targets move
//! by exactly the Polyak rule on every third update and only then, gradient clipping bounds the
//! norm as PyTorch's `clip_grad_norm_`, rows at their subgoal are dropped, and the first Adam
//! steps follow the gradients of the pre-update networks (actor before critic).

use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor, Var};
use candle_nn::VarMap;
use learner::deterministic::update::clip_grad_norm;
use learner::deterministic::{DeterministicLevel, DeterministicNets, DeterministicParams};
use learner::sac::SacBatch;
use nets::weights::vars_under;
use nets::{seeded_var_builder, DeterministicActor, DistanceCritic, LinearInit};

/// head `[obs (1), φ (2)]`, subgoal 2, action 1 (bound 2).
const HEAD: usize = 3;
const ACTION_SCALE: f64 = 2.0;
/// Learning rate of the first-step test.
const LR: f64 = 0.3;

const PARAMS: DeterministicParams = DeterministicParams {
    gamma: 0.99,
    lr: 1e-3,
    lr_decay_episodes: 3000,
    lr_decay_factor: 0.5,
    critic_weight_decay: 1e-5,
    polyak: 0.99,
    target_update_period: 3,
    grad_clip: 1.0,
    reach_threshold: 0.1,
};

fn level(params: DeterministicParams) -> DeterministicLevel {
    level_with(params, &[16, 16])
}

fn level_with(params: DeterministicParams, hidden: &[usize]) -> DeterministicLevel {
    let cpu = Device::Cpu;
    let (online, target) = (VarMap::new(), VarMap::new());
    let build = |vm: &VarMap, seed| {
        let vb = seeded_var_builder(vm, seed, &cpu);
        let actor = DeterministicActor::new(
            &vb.pp("actor"),
            HEAD + 2,
            hidden,
            1,
            ACTION_SCALE,
            LinearInit::TorchDefault,
        )
        .unwrap();
        let critic = DistanceCritic::new(
            &vb.pp("critic"),
            HEAD + 1 + 2,
            hidden,
            LinearInit::TorchDefault,
        )
        .unwrap();
        (actor, critic)
    };
    let (actor, critic) = build(&online, 1);
    let (actor_target, critic_target) = build(&target, 2);
    let nets = DeterministicNets {
        actor,
        actor_vars: vars_under(&online, "actor"),
        actor_target,
        actor_target_vars: vars_under(&target, "actor"),
        critic,
        critic_vars: vars_under(&online, "critic"),
        critic_target,
        critic_target_vars: vars_under(&target, "critic"),
    };
    DeterministicLevel::new(nets, params).unwrap()
}

fn mat(values: &[f32], cols: usize) -> Tensor {
    Tensor::from_slice(values, (values.len() / cols, cols), &Device::Cpu).unwrap()
}

/// Four rows; row `i` has φ = [0.5 i, 0], subgoal [1, 0], so row 2 (φ = [1, 0]) is at its
/// subgoal; rewards −0.1·‖φ' − sg‖, row 1 reached (terminal).
fn batch() -> SacBatch {
    let phi = [0.0f32, 0.5, 1.0, 1.5];
    let mut head = Vec::new();
    let mut next_head = Vec::new();
    for (i, p) in phi.iter().enumerate() {
        head.extend([i as f32 * 0.3 - 0.4, *p, 0.0]);
        next_head.extend([i as f32 * 0.3 - 0.3, p + 0.45, 0.1]);
    }
    SacBatch {
        head: mat(&head, HEAD),
        next_head: mat(&next_head, HEAD),
        tail: Some(mat(&[1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0], 2)),
        action: mat(&[1.5, -0.5, 0.2, -1.9], 1),
        reward: mat(&[-0.055, -0.01, -0.045, -0.095], 1),
        terminal: mat(&[0.0, 1.0, 0.0, 0.0], 1),
    }
}

fn values(vars: &[Var]) -> Vec<Vec<f32>> {
    vars.iter()
        .map(|v| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
        .collect()
}

/// (target, online) values of both networks, flattened.
fn snapshot(l: &DeterministicLevel) -> (Vec<f32>, Vec<f32>) {
    let n = l.nets();
    let flat = |a: &[Var], b: &[Var]| -> Vec<f32> {
        values(a).into_iter().chain(values(b)).flatten().collect()
    };
    (
        flat(&n.actor_target_vars, &n.critic_target_vars),
        flat(&n.actor_vars, &n.critic_vars),
    )
}

#[test]
fn the_targets_start_as_copies_and_move_by_the_polyak_rule_on_every_third_update_only() {
    let mut l = level(PARAMS);
    let (target, online) = snapshot(&l);
    assert_eq!(target, online, "targets start as copies");
    let (mut before, mut online_before) = (target, online);
    for k in 0..7u64 {
        let stats = l.update(&batch(), k).unwrap();
        let (target, online) = snapshot(&l);
        assert_ne!(online, online_before, "update {k} trained");
        if k % 3 == 0 {
            assert!(stats.targets_moved, "update {k}");
            for (i, ((t, b), o)) in target.iter().zip(&before).zip(&online).enumerate() {
                let want = 0.99 * b + 0.01 * o;
                assert!((t - want).abs() <= 1e-6 * (1.0 + want.abs()), "k {k} [{i}]");
            }
        } else {
            assert!(!stats.targets_moved, "update {k}");
            assert_eq!(target, before, "update {k} leaves the targets alone");
        }
        (before, online_before) = (target, online);
    }
}

#[test]
fn clipping_scales_the_gradients_to_the_bound_as_pytorch_and_leaves_small_ones_alone() {
    let cpu = Device::Cpu;
    let a = Var::from_slice(&[1.0f32, 2.0], 2, &cpu).unwrap();
    let b = Var::from_slice(&[3.0f32], 1, &cpu).unwrap();
    let grads_of = |ga: &[f32], gb: &[f32]| {
        let loss = ((a.as_tensor() * Tensor::from_slice(ga, 2, &cpu).unwrap())
            .unwrap()
            .sum_all()
            .unwrap()
            + (b.as_tensor() * Tensor::from_slice(gb, 1, &cpu).unwrap())
                .unwrap()
                .sum_all()
                .unwrap())
        .unwrap();
        loss.backward().unwrap()
    };
    let get =
        |g: &GradStore, v: &Var| -> Vec<f32> { g.get(v.as_tensor()).unwrap().to_vec1().unwrap() };
    // ‖(3, 4, 12)‖ = 13 → scaled by 1 / (13 + 1e-6).
    let mut grads = grads_of(&[3.0, 4.0], &[12.0]);
    let vars = [a.clone(), b.clone()];
    let norm = clip_grad_norm(&mut grads, &vars, 1.0).unwrap();
    assert!((norm - 13.0).abs() < 1e-9);
    let coef = (1.0 / (13.0 + 1e-6)) as f32;
    assert_eq!(get(&grads, &a), vec![3.0 * coef, 4.0 * coef]);
    assert_eq!(get(&grads, &b), vec![12.0 * coef]);
    let clipped: f32 = [get(&grads, &a), get(&grads, &b)]
        .concat()
        .iter()
        .map(|g| g * g)
        .sum();
    assert!(clipped.sqrt() <= 1.0);
    // ‖(0.3, 0.4, 0)‖ = 0.5 < 1: unchanged.
    let mut grads = grads_of(&[0.3, 0.4], &[0.0]);
    let norm = clip_grad_norm(&mut grads, &vars, 1.0).unwrap();
    assert!((norm - 0.5).abs() < 1e-6);
    assert_eq!(get(&grads, &a), vec![0.3, 0.4]);
}

#[test]
fn rows_at_their_subgoal_are_dropped_and_a_batch_of_only_those_changes_nothing() {
    let mut l = level(PARAMS);
    let stats = l.update(&batch(), 1).unwrap();
    assert_eq!(
        (stats.n_kept, stats.n_sampled),
        (3, 4),
        "row 2 is at its subgoal"
    );
    let mut at_goal = batch();
    at_goal.tail = Some(mat(&[0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 1.5, 0.05], 2));
    let before = snapshot(&l);
    let stats = l.update(&at_goal, 1).unwrap();
    assert_eq!(stats.n_kept, 0);
    assert_eq!(
        snapshot(&l),
        before,
        "nothing trained, update 1 moves no target"
    );
}

#[test]
fn the_first_steps_follow_the_pre_update_gradients_actor_first_with_adam_sign_steps() {
    // Adam's first step moves every parameter by lr·g/(|g| + ε′) ≈ lr·sign(g) whatever the
    // clipping scale, so the step direction reveals which gradient was used: the actor's from
    // the critic as it was before this update, the critic's from the target networks. A large
    // rate makes the critic step big enough that an actor stepped after it would go elsewhere.
    let params = DeterministicParams { lr: LR, ..PARAMS };
    let mut l = level(params);
    let probe = level(params); // the same seeds: identical networks, never stepped.
    let b = batch();
    let input = |head: &Tensor, a: &Tensor| {
        Tensor::cat(
            &[
                head,
                &a.affine(1.0 / ACTION_SCALE, 0.0).unwrap(),
                b.tail.as_ref().unwrap(),
            ],
            1,
        )
        .unwrap()
    };
    let pn = probe.nets();
    let policy_in = Tensor::cat(&[&b.head, b.tail.as_ref().unwrap()], 1).unwrap();
    let q_pi = pn
        .critic
        .q(
            &input(&b.head, &pn.actor.forward(&policy_in).unwrap()),
            0.99,
        )
        .unwrap();
    // Row 2 is dropped by the update; drop it here by weighting (mean over 3 kept rows).
    let keep = mat(&[1.0, 1.0, 0.0, 1.0], 1);
    let actor_loss = (q_pi * &keep)
        .unwrap()
        .sum_all()
        .unwrap()
        .affine(-1.0 / 3.0, 0.0)
        .unwrap();
    let actor_grads = actor_loss.backward().unwrap();
    let next_in = Tensor::cat(&[&b.next_head, b.tail.as_ref().unwrap()], 1).unwrap();
    let next_q = pn
        .critic_target
        .q(
            &input(&b.next_head, &pn.actor_target.forward(&next_in).unwrap()),
            0.99,
        )
        .unwrap();
    let not_done = b.terminal.affine(-1.0, 1.0).unwrap();
    let y = (&b.reward + (not_done * next_q).unwrap().affine(0.99, 0.0).unwrap())
        .unwrap()
        .minimum(0.0)
        .unwrap()
        .detach();
    let q = pn.critic.q(&input(&b.head, &b.action), 0.99).unwrap();
    let critic_loss = ((q - y).unwrap().sqr().unwrap() * &keep)
        .unwrap()
        .sum_all()
        .unwrap()
        .affine(1.0 / 3.0, 0.0)
        .unwrap();
    let critic_grads = critic_loss.backward().unwrap();

    l.update(&b, 1).unwrap();
    let n = l.nets();
    let check = |what: &str, moved: &[Var], start: &[Var], grads: &GradStore, wd: f32| {
        let mut checked = 0;
        for (after, before) in moved.iter().zip(start) {
            let g: Vec<f32> = grads
                .get(before.as_tensor())
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1()
                .unwrap();
            let (a, b): (Vec<f32>, Vec<f32>) = (
                after.as_tensor().flatten_all().unwrap().to_vec1().unwrap(),
                before.as_tensor().flatten_all().unwrap().to_vec1().unwrap(),
            );
            for ((a, b), g) in a.iter().zip(&b).zip(&g) {
                let g = g + wd * b;
                if g.abs() > 1e-4 {
                    let step = (b - a) / LR as f32;
                    assert!(
                        (step - g.signum()).abs() < 0.02,
                        "{what}: step {step}, grad {g}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(
            checked > 20,
            "{what}: only {checked} parameters with a clear gradient"
        );
    };
    check("actor", &n.actor_vars, &pn.actor_vars, &actor_grads, 0.0);
    check(
        "critic",
        &n.critic_vars,
        &pn.critic_vars,
        &critic_grads,
        1e-5,
    );
}

#[test]
fn the_learning_rates_halve_every_decay_period() {
    let mut l = level(PARAMS);
    for (episodes, lr) in [(0, 1e-3), (2999, 1e-3), (3000, 5e-4), (9000, 1.25e-4)] {
        l.set_lr_for_episodes(episodes);
        assert!(
            (l.learning_rate() - lr).abs() < 1e-15,
            "{episodes}: {}",
            l.learning_rate()
        );
    }
}

// Reference: learner/tests/reference/deterministic_update.py (numpy, float64, hand-written
// backprop; run with any python that has numpy): two updates on tiny networks (hidden [3]) with
// formula weights, clipping at 0.01 (both networks, every update), Adam lr 1e-3, critic weight
// decay 1e-5, targets moved after update 0 only. Update 1 runs on a stretched batch (gradients
// of another size), so that clipping shows through Adam: without it the online parameters
// differ by up to 8e-5 (`--no-clip`), 40 × the tolerance.
/// Per update: actor loss, critic loss, actor and critic gradient norms, mean Q, mean y.
const WANT_STATS: [[f64; 6]; 2] = [
    // update 0
    [
        -0.47467673248759956,
        0.21881022453912116,
        0.08252309478693484,
        1.0629663859421423,
        0.41717781438537177,
        -0.026858118518266225,
    ],
    // update 1
    [
        -0.482171258579485,
        0.821262339803137,
        0.15689430123214887,
        2.2318530472437796,
        0.4246235617281579,
        -0.44409328983070884,
    ],
];
/// Online parameters after the two updates, in `vars_under` order.
const WANT_ONLINE: [&[f64]; 8] = [
    // actor.l0.bias
    &[
        0.0007441254744793037,
        0.3834223930522253,
        0.20545642170242978,
    ],
    // actor.l0.weight
    &[
        0.2584312060440563,
        0.3644630999877428,
        -0.06309827765729929,
        -0.3967322759789065,
        -0.1495506659320944,
        0.3178052971062204,
        0.31743557209582735,
        -0.1465916517007707,
        -0.3998219163962476,
        -0.06624167017932377,
        0.36163776499855554,
        0.2593710057709158,
        -0.22322090851471177,
        -0.3802819261934055,
        0.020169075122724492,
    ],
    // actor.l1.bias
    &[0.3961682495331649],
    // actor.l1.weight
    &[
        0.34602787757682457,
        -0.10035911982917582,
        -0.39922517036381566,
    ],
    // critic.l0.bias
    &[
        0.13201368929475765,
        -0.3270369518224189,
        -0.30712119953946604,
    ],
    // critic.l0.weight
    &[
        -0.13840343460736226,
        -0.40042174913298556,
        -0.07089254221856335,
        0.35748734201148497,
        0.26320610473753187,
        -0.21561772514013713,
        -0.37985212997851553,
        0.011592226479330314,
        0.38680820224610546,
        0.1928052806384654,
        -0.2844435402539123,
        -0.3448867008650299,
        0.10097035583392427,
        0.40190149277429554,
        0.11283859897868764,
        -0.34047244197251497,
        -0.29392684470057334,
        0.17818743913833782,
    ],
    // critic.l1.bias
    &[-0.34663278667514125],
    // critic.l1.weight
    &[-0.3909809661293752, -0.0315204003676252, 0.3771481443468857],
];
/// Target parameters after the two updates, in `vars_under` order.
const WANT_TARGET: [&[f64]; 8] = [
    // actor.l0.bias
    &[
        -0.37973401276660285,
        0.01050253752928137,
        0.3853581956117545,
    ],
    // actor.l0.weight
    &[
        -0.21549460411971372,
        0.2638038827999432,
        0.3566290633909192,
        -0.0730081693788345,
        -0.39568826296864645,
        -0.13867412626814363,
        0.3214825817565484,
        0.31068190216361796,
        -0.15528849136187348,
        -0.393755531368164,
        -0.055379795253188875,
        0.36412747064876905,
        0.2501871389903475,
        -0.2302779374150598,
        -0.37338529602357673,
    ],
    // actor.l1.bias
    &[0.05010528403070276],
    // actor.l1.weight
    &[0.2921245773564424, 0.337409003021641, -0.11161690108898963],
    // critic.l0.bias
    &[
        0.3967531174072254,
        0.12309981258714674,
        -0.33090033985645906,
    ],
    // critic.l0.weight
    &[
        0.3148077635530722,
        -0.1491203934215222,
        -0.394561610327981,
        -0.06199442098821513,
        0.36139995491271865,
        0.25534785451477365,
        -0.22479480256560466,
        -0.37561723690775894,
        0.02384544003106131,
        0.38836057092647647,
        0.18393186885580698,
        -0.28996276085693573,
        -0.3390466365004774,
        0.1085882259690924,
        0.3971358191167743,
        0.10388381071089382,
        -0.34155278767637665,
        -0.2866390464893333,
    ],
    // critic.l1.bias
    &[0.08478810288219546],
    // critic.l1.weight
    &[
        -0.18510402441616697,
        -0.38807703044742714,
        -0.022501471597606126,
    ],
];

/// [`batch`] with the obs columns of head and next head × 4 and rewards × 10.
fn stretched() -> SacBatch {
    let b = batch();
    let stretch = mat(&[4.0, 1.0, 1.0], 3);
    SacBatch {
        head: b.head.broadcast_mul(&stretch).unwrap(),
        next_head: b.next_head.broadcast_mul(&stretch).unwrap(),
        reward: b.reward.affine(10.0, 0.0).unwrap(),
        ..b
    }
}

/// Element `k` of parameter `index` (in `vars_under` order): `0.4 sin(1.3 k + 0.7 index + extra)`.
fn formula(var: &Var, index: usize, extra: f64) {
    let n = var.elem_count();
    let values: Vec<f32> = (0..n)
        .map(|k| (0.4 * (1.3 * k as f64 + 0.7 * index as f64 + extra).sin()) as f32)
        .collect();
    let t = Tensor::from_vec(values, var.shape(), &Device::Cpu).unwrap();
    var.set(&t).unwrap();
}

#[test]
fn two_updates_match_a_numpy_reference_of_the_reference_code_update() {
    let params = DeterministicParams {
        grad_clip: 0.01,
        ..PARAMS
    };
    let mut l = level_with(params, &[3]);
    let n = l.nets();
    let online: Vec<Var> = n.actor_vars.iter().chain(&n.critic_vars).cloned().collect();
    let target: Vec<Var> = n
        .actor_target_vars
        .iter()
        .chain(&n.critic_target_vars)
        .cloned()
        .collect();
    assert_eq!((online.len(), target.len()), (8, 8));
    for (i, (o, t)) in online.iter().zip(&target).enumerate() {
        formula(o, i, 0.0);
        formula(t, i, 5.0);
    }
    for (k, want) in WANT_STATS.iter().enumerate() {
        let s = l.update(&[batch(), stretched()][k], k as u64).unwrap();
        let got = [
            s.actor_loss,
            s.critic.loss,
            s.actor_grad_norm,
            s.critic_grad_norm,
            s.critic.q_mean,
            s.critic.target_mean,
        ];
        for (j, (g, w)) in got.iter().zip(want).enumerate() {
            assert!(
                (g - w).abs() < 1e-5 * (1.0 + w.abs()),
                "update {k} stat {j}: {g} vs {w}"
            );
        }
        assert_eq!(s.n_kept, 3);
    }
    for (what, vars, want) in [
        ("online", &online, WANT_ONLINE),
        ("target", &target, WANT_TARGET),
    ] {
        for (i, (var, want)) in vars.iter().zip(want).enumerate() {
            let got: Vec<f32> = var.as_tensor().flatten_all().unwrap().to_vec1().unwrap();
            assert_eq!(got.len(), want.len());
            for (e, (g, w)) in got.iter().zip(want.iter()).enumerate() {
                assert!(
                    (f64::from(*g) - w).abs() < 2e-6,
                    "{what} param {i}[{e}]: {g} vs {w}"
                );
            }
        }
    }
}
