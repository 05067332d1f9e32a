"""Reference numbers for learner/tests/deterministic_losses.rs (numpy, float64).

The reference code's deterministic low level (digest §3.2, HESS `_update_network`):
  Q(d)      = -(1 - gamma^d) / (1 - gamma)                 (gamma-distance parameterisation)
  not_done  = ||ag_{t+1} - sg|| > threshold
  y         = min(r + gamma * not_done * Q_targ(s', pi_targ(s'), sg), 0)   (clip above only)
  L_critic  = mean (Q(d) - y)^2,  dL/dd = 2 (Q - y) / B * dQ/dd,  dQ/dd = gamma^d ln(gamma) / (1 - gamma)
  L_actor   = -mean Q(s, pi(s), sg)
Run: python3 learner/tests/reference/deterministic_losses.py
"""
import numpy as np

gamma, threshold = 0.99, 0.1
reward = np.array([-0.5, -0.05, -1.2, -0.02])
ag_next = np.array([[1.0, 0.0], [0.05, 0.05], [3.0, 4.0], [0.0, 0.09]])
subgoal = np.zeros((4, 2))
not_done = (np.linalg.norm(ag_next - subgoal, axis=1) > threshold).astype(float)
next_d = np.array([10.0, 2.0, 50.0, 0.0])
next_q = -(1 - gamma ** next_d) / (1 - gamma)
y = np.minimum(reward + gamma * not_done * next_q, 0.0)
print("not_done", not_done, "next_q", repr(next_q), "target", repr(y))

d = np.array([8.0, 1.0, 45.0, -0.5])
q = -(1 - gamma ** d) / (1 - gamma)
critic = np.mean((q - y) ** 2)
dq_dd = gamma ** d * np.log(gamma) / (1 - gamma)
grad_d = 2 * (q - y) / len(d) * dq_dd
print("q", repr(q), "critic_loss", repr(critic), "grad_d", repr(grad_d))

q_pi = np.array([-3.0, -0.5, -40.0, 0.2])
print("actor_loss", repr(-q_pi.mean()))
