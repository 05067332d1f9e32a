//! Ant fidelity protocol, rapier side. Prints one JSON object to compare with
//! `scripts/fidelity/mujoco_fidelity.py`, which runs the same protocol in MuJoCo.
//!
//! Run: `cargo run --release -p envs --example fidelity [-- [--episodes N] [--trace-gait]
//! [key=value ...]]`. `--trace-gait` also prints the gait's per-step torso pose and hinge
//! angles to stderr.
//! `key=value` overrides one Ant parameter for tuning experiments, e.g. `solver.substeps=4`
//! (see `common/ant_overrides.rs` for the keys). Without arguments it runs the full protocol with the
//! default parameters.
//!
//! Protocol (shared with the MuJoCo script; actions in actuator order hip_4, ankle_4, hip_1,
//! ankle_1, hip_2, ankle_2, hip_3, ankle_3):
//! 1. gait: from qpos0 with zero velocity, 50 control steps; at step t, τ = 0.2 t, legs 1 and 3
//!    have phase 0 and legs 2 and 4 phase π; hip = 16 sin(2πτ + p), ankle = 16 cos(2πτ + p).
//!    Reports the final torso dx, dy, |dxy|, yaw (deg) and z.
//! 2. random: episodes e = 0..999, SplitMix64(e); qpos = qpos0 + 0.1 (2u − 1) on all 15
//!    entries, quaternion normalised, qvel = 0; 100 control steps of 16 (2u − 1) per actuator.
//!    Reports mean, std, median, p10, p90 of the final xy distance from the post-reset xy, and
//!    the fraction of episodes with torso z < 0.3 at the end of any control step.
//! 3. limit: from qpos0, 50 control steps with +16 on hip_1 (then on ankle_1) and 0 elsewhere;
//!    reports that hinge's angle (deg) averaged over the last 10 control steps.
//! 4. gait_ensemble (rapier-side addition): the gait is chaotic — in MuJoCo a 1e-6 change of
//!    the start changes its final yaw by tens of degrees — so test 1 alone compares one sample
//!    of a chaotic map. This repeats it from qpos0 + 0.01 (2u − 1) on all 15 entries
//!    (SplitMix64(s), s = 0..49, quaternion normalised) and reports the mean and std of |dxy|,
//!    the mean dy and the mean |yaw|.
//!
//! Timing: control steps per second over 2000 control steps of random actions (SplitMix64
//!    seed 12345, drawn before the clock starts), single thread, median of 5 runs.

use std::time::Instant;

use envs::ant::{Ant, AntParams, N_JOINTS, QPOS_DIM, QVEL_DIM};
use envs::{EnvError, Robot};

#[path = "common/ant_overrides.rs"]
mod ant_overrides;
use ant_overrides::{apply_override, bad_arg};

/// Gait test length and its phase clock: τ = GAIT_TAU_PER_STEP · t.
const GAIT_STEPS: usize = 50;
const GAIT_TAU_PER_STEP: f64 = 0.2;
/// Random test size.
const RANDOM_EPISODES: u64 = 1000;
const RANDOM_STEPS: usize = 100;
/// Torso height below which an episode counts as flipped (the fall penalty's lower bound).
const FLIP_Z_M: f32 = 0.3;
/// Limit test length and the tail averaged.
const LIMIT_STEPS: usize = 50;
const LIMIT_TAIL: usize = 10;
/// Gait ensemble: number of perturbed starts and the perturbation half-width.
const GAIT_ENSEMBLE_N: u64 = 50;
const GAIT_ENSEMBLE_PERTURBATION: f64 = 0.01;
/// Timing run.
const TIMING_STEPS: usize = 2000;
const TIMING_REPEATS: usize = 5;
const TIMING_SEED: u64 = 12345;
/// Actuator indices (reference order) of hip_1 and ankle_1, and their hinge indices in qpos.
const ACTUATOR_HIP_1: usize = 2;
const ACTUATOR_ANKLE_1: usize = 3;
const QPOS_HIP_1: usize = 7;
const QPOS_ANKLE_1: usize = 8;

/// SplitMix64, the generator both sides of the protocol share.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) from the top 53 bits.
    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [−scale, scale).
    fn symmetric(&mut self, scale: f64) -> f64 {
        scale * (2.0 * self.uniform() - 1.0)
    }
}

fn main() -> Result<(), EnvError> {
    let args = parse_args()?;
    let params = args.params;
    let mass = Ant::new(params.clone(), &[])?.total_mass();
    let gait = gait(&params, args.trace_gait)?;
    let gait_ensemble = gait_ensemble(&params)?;
    let random = random(&params, args.episodes)?;
    let hip1 = hold(&params, ACTUATOR_HIP_1, QPOS_HIP_1)?;
    let ankle1 = hold(&params, ACTUATOR_ANKLE_1, QPOS_ANKLE_1)?;
    let rate = steps_per_sec(&params)?;
    println!(
        "{{\"engine\":\"rapier\",\"mass\":{mass},\"gait\":{gait},\"gait_ensemble\":{gait_ensemble},\"random\":{random},\
         \"limit\":{{\"hip1_deg\":{hip1},\"ankle1_deg\":{ankle1}}},\"steps_per_sec\":{rate}}}"
    );
    Ok(())
}

/// Command line: parameters with overrides, random-test size, gait tracing.
struct Args {
    params: AntParams,
    episodes: u64,
    trace_gait: bool,
}

/// Reads `--episodes N`, `--trace-gait` and `key=value` overrides.
fn parse_args() -> Result<Args, EnvError> {
    let mut parsed = Args {
        params: AntParams::default(),
        episodes: RANDOM_EPISODES,
        trace_gait: false,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        if arg == "--episodes" {
            let value = args.next().unwrap_or_default();
            parsed.episodes = value.parse().map_err(|_| bad_arg("--episodes", &value))?;
        } else if arg == "--trace-gait" {
            parsed.trace_gait = true;
        } else if let Some((key, value)) = arg.split_once('=') {
            apply_override(&mut parsed.params, key, value)?;
        } else {
            return Err(bad_arg(&arg, ""));
        }
    }
    if parsed.episodes == 0 {
        return Err(bad_arg("--episodes", "0"));
    }
    parsed.params.validate()?;
    Ok(parsed)
}

/// An ant at qpos0 with zero velocity.
fn ant_at_rest(params: &AntParams) -> Result<Ant, EnvError> {
    Ant::new(params.clone(), &[])
}

/// Test 1: the fixed sinusoidal gait from qpos0.
fn gait(params: &AntParams, trace: bool) -> Result<String, EnvError> {
    let mut ant = ant_at_rest(params)?;
    let (dx, dy, qpos) = run_gait(&mut ant, params, trace);
    Ok(format!(
        "{{\"dx\":{dx},\"dy\":{dy},\"dist\":{},\"yaw_deg\":{},\"z\":{}}}",
        dx.hypot(dy),
        yaw_deg(&qpos),
        qpos[2]
    ))
}

/// Test 4: the gait from slightly perturbed starts.
fn gait_ensemble(params: &AntParams) -> Result<String, EnvError> {
    let mut ant = ant_at_rest(params)?;
    let mut distances = Vec::new();
    let (mut dy_sum, mut abs_yaw_sum) = (0.0, 0.0);
    for seed in 0..GAIT_ENSEMBLE_N {
        let qpos = noisy_qpos0(params, &mut SplitMix64(seed), GAIT_ENSEMBLE_PERTURBATION);
        ant.rebuild();
        ant.set_state(&qpos, &[0.0; QVEL_DIM]);
        let (dx, dy, final_qpos) = run_gait(&mut ant, params, false);
        distances.push(dx.hypot(dy));
        dy_sum += dy;
        abs_yaw_sum += yaw_deg(&final_qpos).abs();
    }
    let n = GAIT_ENSEMBLE_N as f64;
    let stats = Stats::of(&mut distances);
    Ok(format!(
        "{{\"dist_mean\":{},\"dist_std\":{},\"dy_mean\":{},\"abs_yaw_mean\":{}}}",
        stats.mean,
        stats.std,
        dy_sum / n,
        abs_yaw_sum / n
    ))
}

/// Runs the gait from the ant's current state; returns (dx, dy, final qpos).
fn run_gait(ant: &mut Ant, params: &AntParams, trace: bool) -> (f64, f64, [f32; QPOS_DIM]) {
    let [x0, y0] = ant.xy();
    let phases = [0.0, std::f64::consts::PI, 0.0, std::f64::consts::PI];
    for t in 0..GAIT_STEPS {
        let tau = GAIT_TAU_PER_STEP * t as f64;
        let mut joint_torques = [0.0f32; N_JOINTS];
        for (leg, phase) in phases.iter().enumerate() {
            let angle = std::f64::consts::TAU * tau + phase;
            joint_torques[2 * leg] = (f64::from(params.ctrl_range) * angle.sin()) as f32;
            joint_torques[2 * leg + 1] = (f64::from(params.ctrl_range) * angle.cos()) as f32;
        }
        ant.step(&to_actuator_order(&joint_torques));
        if trace {
            trace_line(t, &ant.qpos());
        }
    }
    let qpos = ant.qpos();
    (f64::from(qpos[0] - x0), f64::from(qpos[1] - y0), qpos)
}

/// qpos0 plus U(−half_width, half_width) on all 15 entries, quaternion left for `set_state`
/// to normalise.
fn noisy_qpos0(params: &AntParams, rng: &mut SplitMix64, half_width: f64) -> [f32; QPOS_DIM] {
    let mut qpos = params.qpos0();
    for value in qpos.iter_mut() {
        *value = (f64::from(*value) + rng.symmetric(half_width)) as f32;
    }
    qpos
}

/// One stderr line: step, torso xyz, yaw and hinge angles (deg).
fn trace_line(step: usize, qpos: &[f32; QPOS_DIM]) {
    let hinges: Vec<String> = qpos[7..]
        .iter()
        .map(|q| format!("{:6.1}", q.to_degrees()))
        .collect();
    eprintln!(
        "{step:3} {:7.3} {:7.3} {:7.3} yaw {:7.2} j {}",
        qpos[0],
        qpos[1],
        qpos[2],
        yaw_deg(qpos),
        hinges.join(" ")
    );
}

/// Reorders per-hinge values (observation order) into actuator order.
fn to_actuator_order(joint_values: &[f32; N_JOINTS]) -> [f32; N_JOINTS] {
    let mut action = [0.0; N_JOINTS];
    for (actuator, joint) in envs::ant::ACTUATOR_TO_JOINT.iter().enumerate() {
        action[actuator] = joint_values[*joint];
    }
    action
}

/// Heading about z (deg) from the qpos quaternion (w, x, y, z).
fn yaw_deg(qpos: &[f32; QPOS_DIM]) -> f64 {
    let [w, x, y, z] = [qpos[3], qpos[4], qpos[5], qpos[6]].map(f64::from);
    (2.0 * (w * z + x * y))
        .atan2(1.0 - 2.0 * (y * y + z * z))
        .to_degrees()
}

/// Test 2: random torques from noisy starts.
fn random(params: &AntParams, episodes: u64) -> Result<String, EnvError> {
    let mut ant = ant_at_rest(params)?;
    let mut distances = Vec::with_capacity(episodes as usize);
    let mut n_flipped = 0u64;
    for episode in 0..episodes {
        let (distance, flipped) = random_episode(&mut ant, params, episode);
        distances.push(distance);
        n_flipped += u64::from(flipped);
    }
    let stats = Stats::of(&mut distances);
    Ok(format!(
        "{{\"mean\":{},\"std\":{},\"median\":{},\"p10\":{},\"p90\":{},\"flip_frac\":{}}}",
        stats.mean,
        stats.std,
        stats.median,
        stats.p10,
        stats.p90,
        n_flipped as f64 / episodes as f64
    ))
}

/// One random episode: returns (final xy distance from the start, whether it flipped).
fn random_episode(ant: &mut Ant, params: &AntParams, episode: u64) -> (f64, bool) {
    let mut rng = SplitMix64(episode);
    let qpos = noisy_qpos0(params, &mut rng, f64::from(params.reset_qpos_noise));
    ant.rebuild();
    ant.set_state(&qpos, &[0.0; QVEL_DIM]);
    let [x0, y0] = ant.xy();
    let mut flipped = false;
    for _ in 0..RANDOM_STEPS {
        let action: [f32; N_JOINTS] =
            std::array::from_fn(|_| rng.symmetric(f64::from(params.ctrl_range)) as f32);
        ant.step(&action);
        flipped |= ant.torso_z().is_some_and(|z| z < FLIP_Z_M);
    }
    let [x, y] = ant.xy();
    (f64::from(x - x0).hypot(f64::from(y - y0)), flipped)
}

/// Summary statistics with numpy's conventions (population std, linear percentiles).
struct Stats {
    mean: f64,
    std: f64,
    median: f64,
    p10: f64,
    p90: f64,
}

impl Stats {
    fn of(values: &mut [f64]) -> Stats {
        values.sort_by(f64::total_cmp);
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        Stats {
            mean,
            std: variance.sqrt(),
            median: percentile(values, 50.0),
            p10: percentile(values, 10.0),
            p90: percentile(values, 90.0),
        }
    }
}

/// Linear-interpolation percentile of sorted values (numpy's default method).
fn percentile(sorted: &[f64], q: f64) -> f64 {
    let rank = q / 100.0 * (sorted.len() - 1) as f64;
    let low = rank.floor() as usize;
    let high = rank.ceil() as usize;
    sorted[low] + (rank - low as f64) * (sorted[high] - sorted[low])
}

/// Test 3: +ctrl_range on one actuator; mean angle (deg) of its hinge over the last steps.
fn hold(params: &AntParams, actuator: usize, qpos_index: usize) -> Result<f64, EnvError> {
    let mut ant = ant_at_rest(params)?;
    let mut action = [0.0; N_JOINTS];
    action[actuator] = params.ctrl_range;
    let mut tail_sum = 0.0;
    for step in 0..LIMIT_STEPS {
        ant.step(&action);
        if step >= LIMIT_STEPS - LIMIT_TAIL {
            tail_sum += f64::from(ant.qpos()[qpos_index]);
        }
    }
    Ok((tail_sum / LIMIT_TAIL as f64).to_degrees())
}

/// Control steps per second of random actions, median of several runs.
fn steps_per_sec(params: &AntParams) -> Result<f64, EnvError> {
    let mut rng = SplitMix64(TIMING_SEED);
    let ctrl_range = f64::from(params.ctrl_range);
    let actions: Vec<[f32; N_JOINTS]> = (0..TIMING_STEPS)
        .map(|_| std::array::from_fn(|_| rng.symmetric(ctrl_range) as f32))
        .collect();
    let mut rates = Vec::with_capacity(TIMING_REPEATS);
    for _ in 0..TIMING_REPEATS {
        let mut ant = ant_at_rest(params)?;
        let start = Instant::now();
        for action in &actions {
            ant.step(action);
        }
        rates.push(TIMING_STEPS as f64 / start.elapsed().as_secs_f64());
    }
    rates.sort_by(f64::total_cmp);
    Ok(rates[TIMING_REPEATS / 2])
}
