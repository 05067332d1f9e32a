"""PyTorch side of `asi bench learner`: the same SAC updates and φ steps as the Rust bench
(src/bench_learner.rs), on the CPU with one thread, timed the same way.

Setup: scripts/bench_learner_torch_setup.sh (creates .venv-bench-torch with a pinned torch).
Run:   .venv-bench-torch/bin/python scripts/bench_learner_torch.py [--batch 128] ...
Prints one JSON object on the last line of stdout:
  {"torch": version, "threads": 1, "low_updates_per_sec": ..., "high_updates_per_sec": ...,
   "phi_steps_per_sec": ..., "low_block_rates": [...], ...}

What is timed, exactly as on the Rust side:
- One SAC update of a level (CleanRL's sac_continuous_action.py order): the soft target under
  no-grad with a' ~ π(·|s') from the target critic; one Adam step on the twin critic loss; one
  Adam step on the actor loss against the just-updated critic (critic parameters are not frozen,
  as in CleanRL and the Rust learner); Polyak averaging of the target (τ = 0.005). α fixed at 0.2.
  Networks: tanh-Gaussian policy (2 x 256 ReLU trunk, mean and log-std heads, log-std clamped to
  [-20, 2], log-det correction ln(scale (1 - tanh²) + 1e-6)), two separate Q MLPs (2 x 256).
  Inputs: policy [head, tail], critic [head, action, tail]; low: head 31 (obs 29 + φ 2), tail 2
  (subgoal), action 8, scale 16; high: head 31 (obs 29 + goal 2), no tail, action 2, scale 10.
- One φ step (HESS): the encoder 29 → 100 → 100 → 2 on anchors, positives, negatives and
  regularisation states (batch each), triplet loss
  mean(mean_d (φa − φp)² + relu(1 − mean_d (φa − φn)²)) plus 0.001 · mean (φ(r) − φ_old(r))²,
  one Adam step (lr 1e-4).
Batches are drawn once (8 of them, cycled) with the noise, so sampling is not timed. The rate of
a block is updates / wall seconds; the figure is the median over the blocks after a warm-up.

With --serve the script times on request instead, so the Rust bench can alternate candle and
PyTorch blocks and take the ratio of neighbouring blocks (robust to load that changes during
the run): it builds the three workloads, runs --warmup calls of each, prints one JSON line
{"torch": version, "threads": n}, then for each stdin line "<low|high|phi> <calls>" prints
{"what": ..., "per_sec": ...} after timing that many calls; "quit" or end of input exits.
"""

import argparse
import copy
import json
import math
import statistics
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

HALF_LN_2PI = 0.5 * math.log(2.0 * math.pi)
N_BATCHES = 8


class GaussianPolicy(nn.Module):
    def __init__(self, in_dim, hidden, action_dim, scale):
        super().__init__()
        self.l0 = nn.Linear(in_dim, hidden)
        self.l1 = nn.Linear(hidden, hidden)
        self.mean = nn.Linear(hidden, action_dim)
        self.log_std = nn.Linear(hidden, action_dim)
        self.scale = scale

    def sample(self, x, eps):
        h = F.relu(self.l1(F.relu(self.l0(x))))
        mean = self.mean(h)
        log_std = self.log_std(h).clamp(-20.0, 2.0)
        u = mean + log_std.exp() * eps
        tanh_u = torch.tanh(u)
        action = self.scale * tanh_u
        gauss = -0.5 * eps.square() - HALF_LN_2PI - log_std
        log_det = torch.log(self.scale * (1.0 - tanh_u.square()) + 1e-6)
        return action, (gauss - log_det).sum(-1, keepdim=True)


def mlp(in_dim, hidden, out_dim):
    return nn.Sequential(
        nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
        nn.Linear(hidden, out_dim))


class TwinCritic(nn.Module):
    def __init__(self, in_dim, hidden):
        super().__init__()
        self.q1 = mlp(in_dim, hidden, 1)
        self.q2 = mlp(in_dim, hidden, 1)

    def forward(self, x):
        return self.q1(x), self.q2(x)


class SacLevel:
    def __init__(self, head, tail, action_dim, scale, hidden, lr=3e-4):
        self.tail = tail
        self.policy = GaussianPolicy(head + tail, hidden, action_dim, scale)
        self.critic = TwinCritic(head + action_dim + tail, hidden)
        self.target = copy.deepcopy(self.critic)
        for p in self.target.parameters():
            p.requires_grad_(False)
        self.policy_opt = torch.optim.Adam(self.policy.parameters(), lr=lr)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=lr)
        self.gamma, self.tau, self.alpha = 0.99, 0.005, 0.2

    def cat_policy(self, head, tail):
        return head if tail is None else torch.cat([head, tail], 1)

    def cat_critic(self, head, action, tail):
        return torch.cat([head, action] if tail is None else [head, action, tail], 1)

    def update(self, b):
        with torch.no_grad():
            next_a, next_logp = self.policy.sample(self.cat_policy(b["next_head"], b["tail"]),
                                                   b["next_eps"])
            q1t, q2t = self.target(self.cat_critic(b["next_head"], next_a, b["tail"]))
            y = b["reward"] + self.gamma * (1.0 - b["terminal"]) * (
                torch.min(q1t, q2t) - self.alpha * next_logp)
        q1, q2 = self.critic(self.cat_critic(b["head"], b["action"], b["tail"]))
        critic_loss = F.mse_loss(q1, y) + F.mse_loss(q2, y)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()

        a, logp = self.policy.sample(self.cat_policy(b["head"], b["tail"]), b["eps"])
        q1, q2 = self.critic(self.cat_critic(b["head"], a, b["tail"]))
        actor_loss = (self.alpha * logp - torch.min(q1, q2)).mean()
        self.policy_opt.zero_grad()
        actor_loss.backward()
        self.policy_opt.step()

        with torch.no_grad():
            for p_t, p in zip(self.target.parameters(), self.critic.parameters()):
                p_t.lerp_(p, self.tau)
        return critic_loss.item(), actor_loss.item()


def make_batch(g, batch, head, tail, action_dim, scale):
    return {
        "head": torch.randn(batch, head, generator=g),
        "next_head": torch.randn(batch, head, generator=g),
        "tail": None if tail == 0 else torch.randn(batch, tail, generator=g),
        "action": (torch.rand(batch, action_dim, generator=g) * 2 - 1) * scale,
        "reward": -torch.rand(batch, 1, generator=g),
        "terminal": (torch.rand(batch, 1, generator=g) < 0.05).float(),
        "next_eps": torch.randn(batch, action_dim, generator=g),
        "eps": torch.randn(batch, action_dim, generator=g),
    }


def time_blocks(step, warmup, blocks, per_block):
    for _ in range(warmup):
        step()
    rates = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(per_block):
            step()
        rates.append(per_block / (time.perf_counter() - start))
    return rates


def level_step(args, head, tail, action_dim, scale):
    g = torch.Generator().manual_seed(0)
    level = SacLevel(head, tail, action_dim, scale, args.hidden)
    batches = [make_batch(g, args.batch, head, tail, action_dim, scale)
               for _ in range(N_BATCHES)]
    i = [0]

    def step():
        level.update(batches[i[0] % N_BATCHES])
        i[0] += 1

    return step


def bench_level(args, head, tail, action_dim, scale):
    step = level_step(args, head, tail, action_dim, scale)
    return time_blocks(step, args.warmup, args.blocks, args.updates_per_block)


def phi_step(args):
    g = torch.Generator().manual_seed(1)
    obs_dim, b = 29, args.phi_batch
    phi = nn.Sequential(nn.Linear(obs_dim, 100), nn.ReLU(), nn.Linear(100, 100), nn.ReLU(),
                        nn.Linear(100, 2))
    phi_old = copy.deepcopy(phi)
    for p in phi_old.parameters():
        p.requires_grad_(False)
    opt = torch.optim.Adam(phi.parameters(), lr=1e-4)
    states = [torch.randn(4 * b, obs_dim, generator=g) for _ in range(N_BATCHES)]
    i = [0]

    def step():
        x = states[i[0] % N_BATCHES]
        i[0] += 1
        z = phi(x)
        za, zp, zn, zr = z[:b], z[b:2 * b], z[2 * b:3 * b], z[3 * b:]
        with torch.no_grad():
            zr_old = phi_old(x[3 * b:])
        pos = (za - zp).square().mean(1)
        neg = F.relu(1.0 - (za - zn).square().mean(1))
        loss = (pos + neg).mean() + 0.001 * (zr - zr_old).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    return step


def bench_phi(args):
    per_block = max(1, args.phi_steps // args.blocks)
    return time_blocks(phi_step(args), args.warmup, args.blocks, per_block)


def serve(args):
    steps = {
        "low": level_step(args, head=31, tail=2, action_dim=8, scale=16.0),
        "high": level_step(args, head=31, tail=0, action_dim=2, scale=10.0),
        "phi": phi_step(args),
    }
    for step in steps.values():
        for _ in range(args.warmup):
            step()
    print(json.dumps({"torch": torch.__version__, "threads": torch.get_num_threads()}),
          flush=True)
    for line in sys.stdin:
        words = line.split()
        if not words or words[0] == "quit":
            break
        if len(words) != 2 or words[0] not in steps or not words[1].isdigit() \
                or int(words[1]) < 1:
            print(json.dumps({"error": f"bad request {line.strip()!r}"}), flush=True)
            continue
        step, calls = steps[words[0]], int(words[1])
        start = time.perf_counter()
        for _ in range(calls):
            step()
        print(json.dumps({"what": words[0],
                          "per_sec": calls / (time.perf_counter() - start)}), flush=True)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--batch", type=int, default=128)
    p.add_argument("--hidden", type=int, default=256)
    p.add_argument("--blocks", type=int, default=5)
    p.add_argument("--updates-per-block", type=int, default=50)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--phi-steps", type=int, default=2000)
    p.add_argument("--phi-batch", type=int, default=100)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--serve", action="store_true",
                   help="time blocks on request from stdin (see the module doc)")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    if args.serve:
        serve(args)
        return
    low = bench_level(args, head=31, tail=2, action_dim=8, scale=16.0)
    high = bench_level(args, head=31, tail=0, action_dim=2, scale=10.0)
    phi = bench_phi(args)
    print(json.dumps({
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "low_updates_per_sec": statistics.median(low),
        "high_updates_per_sec": statistics.median(high),
        "phi_steps_per_sec": statistics.median(phi),
        "low_block_rates": low,
        "high_block_rates": high,
        "phi_block_rates": phi,
    }))


if __name__ == "__main__":
    main()
