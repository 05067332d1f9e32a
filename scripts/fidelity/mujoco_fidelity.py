"""MuJoCo reference run of the Ant physics-fidelity protocol (rapier vs MuJoCo).

Loads assets/ant.xml (timestep 0.02, RK4) and uses frame_skip 10, so one control
step is 0.2 s. The Rust/rapier side implements exactly the same protocol.

RNG: SplitMix64 on u64 (wrapping): state += 0x9E3779B97F4A7C15; z = state;
z = (z ^ z>>30) * 0xBF58476D1CE4E5B9; z = (z ^ z>>27) * 0x94D049BB133111EB;
out = z ^ z>>31; uniform u = (out >> 11) / 2**53.

Tests (actions are written into ctrl in actuator order
hip_4, ankle_4, hip_1, ankle_1, hip_2, ankle_2, hip_3, ankle_3):
1. gait:   from qpos0, qvel 0. 50 control steps; at step t, tau = 0.2 t, leg l has
           phase p = 0 (l = 1, 3) or pi (l = 2, 4); hip_l = 16 sin(2 pi tau + p),
           ankle_l = 16 cos(2 pi tau + p). Report final torso dx, dy, |dxy|,
           yaw (deg, from the quaternion) and z.
2. random: episodes e = 0..999 with rng = SplitMix64(e). Reset: qpos = qpos0 +
           0.1 (2u - 1) on all 15 entries in qpos order, quaternion normalised,
           qvel = 0, mj_forward. 100 control steps of 8 draws 16 (2u - 1).
           Report mean/std/median/p10/p90 of the final xy distance from the
           post-reset xy, and flip_frac = fraction of episodes with torso z < 0.3
           at the end of any control step.
3. limit:  from qpos0, 50 control steps with (a) hip_1 = +16 or (b) ankle_1 = +16,
           all other actuators 0; report that joint's angle (deg) averaged over
           the ends of the last 10 control steps.
Timing: control steps/s over 2000 control steps of random actions (SplitMix64
seed 12345, generated before the clock starts), single thread, median of 5 runs.

Usage: .venv-fidelity/bin/python scripts/fidelity/mujoco_fidelity.py [--out FILE]
"""
import argparse
import json
import math
import os
import sys
import time

import mujoco
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
XML = os.path.join(ROOT, "assets", "ant.xml")
FRAME_SKIP = 10
MAX_TORQUE = 16.0
MASK = (1 << 64) - 1
ACTUATOR_ORDER = ["hip_4", "ankle_4", "hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3"]


class SplitMix64:
    def __init__(self, seed):
        self.state = seed & MASK

    def next_u64(self):
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
        return z ^ (z >> 31)

    def uniform(self):
        return (self.next_u64() >> 11) / 2.0**53


def yaw_deg(quat):
    w, x, y, z = quat
    return math.degrees(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def reset(m, d, qpos=None):
    mujoco.mj_resetData(m, d)  # qpos = qpos0, qvel = 0, ctrl = 0, time = 0
    if qpos is not None:
        d.qpos[:] = qpos
    mujoco.mj_forward(m, d)


def control_step(m, d, action):
    d.ctrl[:] = action
    mujoco.mj_step(m, d, nstep=FRAME_SKIP)
    if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
        raise FloatingPointError("non-finite MuJoCo state")


def test_gait(m, d):
    reset(m, d)
    x0, y0 = d.qpos[0], d.qpos[1]
    phase = {1: 0.0, 2: math.pi, 3: 0.0, 4: math.pi}
    for t in range(50):
        tau = 0.2 * t
        action = []
        for name in ACTUATOR_ORDER:
            kind, leg = name.split("_")
            arg = 2.0 * math.pi * tau + phase[int(leg)]
            action.append(MAX_TORQUE * (math.sin(arg) if kind == "hip" else math.cos(arg)))
        control_step(m, d, action)
    dx, dy = d.qpos[0] - x0, d.qpos[1] - y0
    return {"dx": dx, "dy": dy, "dist": math.hypot(dx, dy), "yaw_deg": yaw_deg(d.qpos[3:7]), "z": d.qpos[2]}


def test_random(m, d, episodes=1000, steps=100):
    dists, flips = [], 0
    for e in range(episodes):
        rng = SplitMix64(e)
        qpos = m.qpos0 + np.array([0.1 * (2.0 * rng.uniform() - 1.0) for _ in range(m.nq)])
        qpos[3:7] /= np.linalg.norm(qpos[3:7])
        reset(m, d, qpos)
        x0, y0 = d.qpos[0], d.qpos[1]
        flipped = False
        for _ in range(steps):
            control_step(m, d, [MAX_TORQUE * (2.0 * rng.uniform() - 1.0) for _ in range(m.nu)])
            flipped |= d.qpos[2] < 0.3
        flips += flipped
        dists.append(math.hypot(d.qpos[0] - x0, d.qpos[1] - y0))
    a = np.array(dists)
    return {"mean": a.mean(), "std": a.std(), "median": np.median(a),
            "p10": np.percentile(a, 10), "p90": np.percentile(a, 90), "flip_frac": flips / episodes}


def hold_torque(m, d, actuator, joint, steps=50, last=10):
    reset(m, d)
    action = np.zeros(m.nu)
    action[ACTUATOR_ORDER.index(actuator)] = MAX_TORQUE
    adr = m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint)]
    angles = []
    for _ in range(steps):
        control_step(m, d, action)
        angles.append(d.qpos[adr])
    return math.degrees(float(np.mean(angles[-last:])))


def steps_per_sec(m, d, steps=2000, repeats=5):
    rng = SplitMix64(12345)
    actions = np.array([[MAX_TORQUE * (2.0 * rng.uniform() - 1.0) for _ in range(m.nu)] for _ in range(steps)])
    rates = []
    for _ in range(repeats):
        reset(m, d)
        start = time.perf_counter()
        for a in actions:
            d.ctrl[:] = a
            mujoco.mj_step(m, d, nstep=FRAME_SKIP)
        rates.append(steps / (time.perf_counter() - start))
    return float(np.median(rates))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="also write the JSON to this file")
    ap.add_argument("--speed-only", action="store_true",
                    help="only time control steps; print `mujoco_env_steps_per_sec: N` (median of 5)")
    args = ap.parse_args()

    m = mujoco.MjModel.from_xml_path(XML)
    d = mujoco.MjData(m)
    assert [m.actuator(i).name.removeprefix("m_") for i in range(m.nu)] == ACTUATOR_ORDER
    assert m.opt.timestep == 0.02 and m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    if args.speed_only:
        print(f"mujoco_env_steps_per_sec: {steps_per_sec(m, d):.0f}")
        return

    result = {
        "engine": "mujoco",
        "mujoco_version": mujoco.__version__,
        "mass": float(m.body_mass.sum()),
        "gait": test_gait(m, d),
        "random": test_random(m, d),
        "limit": {"hip1_deg": hold_torque(m, d, "hip_1", "hip_1"),
                  "ankle1_deg": hold_torque(m, d, "ankle_1", "ankle_1")},
        "steps_per_sec": steps_per_sec(m, d),
    }
    result = json.loads(json.dumps(result, default=float))  # numpy scalars -> float
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    print(f"total mass {result['mass']:.4f} kg", file=sys.stderr)


if __name__ == "__main__":
    main()
