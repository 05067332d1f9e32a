"""Reference numbers for learner/tests/deterministic_update.rs (numpy, float64): two updates of
the deterministic low level (digest §3.2, HESS `_update_network` + `_soft_update_target_network`)
with hand-written backprop, on tiny networks whose weights follow a fixed formula.

Networks (parameter names as in `nets`): actor `actor.l0` 5 -> 3 (ReLU), `actor.l1` 3 -> 1,
a = 2 tanh(.); critic `critic.l0` 6 -> 3 (ReLU), `critic.l1` 3 -> 1 gives d,
Q = -(1 - gamma^d) / (1 - gamma). Layer weight W [out, in], y = x W^T + b.
Initial value of element k (row-major) of parameter p: 0.4 sin(1.3 k + offset(p)),
offset = 0.7 * index of p in [actor.l0.bias, actor.l0.weight, actor.l1.bias, actor.l1.weight,
critic.l0.bias, critic.l0.weight, critic.l1.bias, critic.l1.weight]; the targets use offset + 5.

Update 0 uses the batch below; update 1 the same with the obs column and the next obs column
times 4 and rewards times 10. Update k, in the code's order:
  keep rows with ||phi - sg|| > 0.1 (phi = head[:, 1:3])
  y = min(r + gamma (1 - terminal) Q_t(s', pi_t(s'), sg), 0)      (target nets, no grad)
  actor: L = -mean Q(s, pi(s), sg); clip_grad_norm_(CLIP = 0.01); Adam(lr)
  critic: L = mean (Q(s, a, sg) - y)^2; clip; Adam(lr, weight_decay=WD)
  if k % 3 == 0: target <- 0.99 target + 0.01 online (actor and critic)
Run: python3 learner/tests/reference/deterministic_update.py
"""
import sys

import numpy as np

# `--no-clip` shows that clipping changes the numbers (Adam is scale invariant per step, so the
# second batch is built to give gradients of another size than the first).
CLIP = float("inf") if "--no-clip" in sys.argv else 0.01
GAMMA, LR, WD, POLYAK, SCALE = 0.99, 1e-3, 1e-5, 0.99, 2.0
B1, B2, EPS = 0.9, 0.999, 1e-8

phi = np.array([0.0, 0.5, 1.0, 1.5])
head = np.array([[i * 0.3 - 0.4, p, 0.0] for i, p in enumerate(phi)])
next_head = np.array([[i * 0.3 - 0.3, p + 0.45, 0.1] for i, p in enumerate(phi)])
sg = np.array([[1.0, 0.0]] * 4)
action = np.array([[1.5], [-0.5], [0.2], [-1.9]])
reward = np.array([[-0.055], [-0.01], [-0.045], [-0.095]])
terminal = np.array([[0.0], [1.0], [0.0], [0.0]])

NAMES = ["actor.l0.bias", "actor.l0.weight", "actor.l1.bias", "actor.l1.weight",
         "critic.l0.bias", "critic.l0.weight", "critic.l1.bias", "critic.l1.weight"]
SHAPES = {"actor.l0.bias": (3,), "actor.l0.weight": (3, 5), "actor.l1.bias": (1,),
          "actor.l1.weight": (1, 3), "critic.l0.bias": (3,), "critic.l0.weight": (3, 6),
          "critic.l1.bias": (1,), "critic.l1.weight": (1, 3)}


def init(extra):
    out = {}
    for i, n in enumerate(NAMES):
        k = np.arange(int(np.prod(SHAPES[n])))
        out[n] = (0.4 * np.sin(1.3 * k + 0.7 * i + extra)).reshape(SHAPES[n])
    return out


def mlp(p, net, x):
    pre = x @ p[net + ".l0.weight"].T + p[net + ".l0.bias"]
    h = np.maximum(pre, 0.0)
    return h @ p[net + ".l1.weight"].T + p[net + ".l1.bias"], (x, pre, h)


def mlp_back(p, net, cache, dy):
    x, pre, h = cache
    g = {net + ".l1.weight": dy.T @ h, net + ".l1.bias": dy.sum(0)}
    dpre = (dy @ p[net + ".l1.weight"]) * (pre > 0)
    g[net + ".l0.weight"] = dpre.T @ x
    g[net + ".l0.bias"] = dpre.sum(0)
    return g, dpre @ p[net + ".l0.weight"]


def q_of(d):
    return -(1 - GAMMA ** d) / (1 - GAMMA)


def dq_dd(d):
    return GAMMA ** d * np.log(GAMMA) / (1 - GAMMA)


def actor(p, x):
    u, cache = mlp(p, "actor", x)
    return SCALE * np.tanh(u), (u, cache)


def clip(g, names):
    norm = np.sqrt(sum((g[n] ** 2).sum() for n in names))
    coef = CLIP / (norm + 1e-6)
    if coef < 1:
        for n in names:
            g[n] = g[n] * coef
    return norm


def adam(p, g, state, names, wd, t):
    for n in names:
        grad = g[n] + wd * p[n]
        m, v = state.get(n, (0.0, 0.0))
        m = B1 * m + (1 - B1) * grad
        v = B2 * v + (1 - B2) * grad ** 2
        state[n] = (m, v)
        p[n] = p[n] - LR * (m / (1 - B1 ** t)) / (np.sqrt(v / (1 - B2 ** t)) + EPS)


online, target = init(0.0), init(5.0)
opt_a, opt_c = {}, {}
keep = np.linalg.norm(head[:, 1:3] - sg, axis=1) > 0.1
h0, nh0, s, a, r0, term = (z[keep] for z in (head, next_head, sg, action, reward, terminal))
n = len(h0)
A = [x for x in NAMES if x.startswith("actor")]
C = [x for x in NAMES if x.startswith("critic")]
stretch = np.array([4.0, 1.0, 1.0])
for k in range(2):
    h, nh, r = (h0, nh0, r0) if k == 0 else (h0 * stretch, nh0 * stretch, r0 * 10)
    na, _ = actor(target, np.hstack([nh, s]))
    nd, _ = mlp(target, "critic", np.hstack([nh, na / SCALE, s]))
    y = np.minimum(r + GAMMA * (1 - term) * q_of(nd), 0.0)
    # actor, against the critic before its step
    pa, (u, acache) = actor(online, np.hstack([h, s]))
    d_pi, ccache = mlp(online, "critic", np.hstack([h, pa / SCALE, s]))
    actor_loss = -q_of(d_pi).mean()
    dd = -dq_dd(d_pi) / n
    _, dx = mlp_back(online, "critic", ccache, dd)
    da = dx[:, 3:4] / SCALE
    du = da * SCALE * (1 - np.tanh(u) ** 2)
    ga, _ = mlp_back(online, "actor", acache, du)
    actor_norm = clip(ga, A)
    # critic
    d, ccache = mlp(online, "critic", np.hstack([h, a / SCALE, s]))
    q = q_of(d)
    critic_loss = ((q - y) ** 2).mean()
    gc, _ = mlp_back(online, "critic", ccache, 2 * (q - y) / n * dq_dd(d))
    critic_norm = clip(gc, C)
    adam(online, ga, opt_a, A, 0.0, k + 1)
    adam(online, gc, opt_c, C, WD, k + 1)
    if k % 3 == 0:
        for x in NAMES:
            target[x] = POLYAK * target[x] + (1 - POLYAK) * online[x]
    print(f"update {k}: actor_loss {actor_loss!r} critic_loss {critic_loss!r} "
          f"actor_norm {actor_norm!r} critic_norm {critic_norm!r} q_mean {q.mean()!r} "
          f"target_mean {y.mean()!r}")
for label, p in (("online", online), ("target", target)):
    for x in NAMES:
        print(label, x, repr(p[x].flatten().tolist()))
