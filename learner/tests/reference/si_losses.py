"""Reference numbers for learner/tests/si_losses.rs (numpy, float64).

Self-imitation losses (paper Eq. 11-12, digest section 8):
  L_hi = alpha * mean_{B,D} (a - (R[idx] - phi))^2,  a = scale * tanh(mu + exp(log_std) * eps)
  L_lo = beta * mean_{B,U,A} (pi_lo(x_idx) - NG(pi_lo(x_u)))^2,  pi_lo(x) = scale * tanh(mu(x))
The policies are the tanh-Gaussian of nets::GaussianPolicy with one hidden ReLU layer:
  h = relu(x W0^T + b0), mu = h Wm^T + bm, log_std = clamp(h Ws^T + bs, -20, 2).
Gradients w.r.t. the mean-head bias bm are analytic; for the low loss only the aligned
branch contributes (the reference branch is detached).
Run: python3 learner/tests/reference/si_losses.py
"""
import numpy as np

np.set_printoptions(precision=17)

# ---- tensor-level losses -------------------------------------------------------------------
alpha, beta = 0.01, 0.001
action = np.array([[0.5, -1.0], [2.0, 0.25], [-0.75, 1.5]])
route_target = np.array([[3.0, 4.0], [-2.0, 1.0], [0.5, -0.5]])
phi = np.array([[1.0, 2.0], [0.0, 0.5], [1.5, -1.0]])
diff = action - (route_target - phi)
high = alpha * np.mean(diff ** 2)
grad_action = 2 * alpha * diff / diff.size
print("high_loss", repr(high))
print("high_grad_action", repr(grad_action.ravel()))

aligned = np.array([[1.0, -2.0, 0.5], [0.0, 3.0, -1.0]])
reference = np.array([
    [[0.5, -1.0, 0.0], [1.5, -2.5, 1.0], [0.0, 0.0, 0.0]],
    [[1.0, 2.0, -1.0], [-1.0, 4.0, 0.0], [0.5, 3.5, -2.0]],
])
low_diff = aligned[:, None, :] - reference
low = beta * np.mean(low_diff ** 2)
grad_aligned = 2 * beta * low_diff.sum(axis=1) / low_diff.size
print("low_loss", repr(low))
print("low_grad_aligned", repr(grad_aligned.ravel()))

# ---- with a policy -------------------------------------------------------------------------
# in 3 -> hidden 4 -> 2 heads of dim 2, scale 2.
W0 = np.array([[0.2, -0.1, 0.4], [-0.3, 0.5, 0.1], [0.6, 0.2, -0.2], [0.1, 0.1, 0.3]])
b0 = np.array([0.05, -0.02, 0.1, 0.0])
Wm = np.array([[0.3, -0.2, 0.1, 0.4], [-0.1, 0.5, 0.2, -0.3]])
bm = np.array([0.01, -0.03])
Ws = np.array([[0.1, 0.1, -0.2, 0.05], [0.2, -0.1, 0.1, 0.0]])
bs = np.array([-0.5, -1.0])
scale = 2.0


def heads(x):
    h = np.maximum(x @ W0.T + b0, 0.0)
    return h @ Wm.T + bm, np.clip(h @ Ws.T + bs, -20, 2)


# High: x = [s_t (1 value), goal (2 values)], eps fixed.
x_hi = np.array([[0.5, 1.0, -1.0], [1.0, -0.5, 2.0], [-1.5, 0.3, 0.8]])
eps = np.array([[0.3, -1.2], [0.0, 0.5], [-0.7, 0.9]])
mu, log_std = heads(x_hi)
u = mu + np.exp(log_std) * eps
a = scale * np.tanh(u)
d_hi = a - (route_target - phi)
high_pol = alpha * np.mean(d_hi ** 2)
grad_bm_hi = (2 * alpha * d_hi / d_hi.size * scale * (1 - np.tanh(u) ** 2)).sum(axis=0)
print("policy_high_action", repr(a.ravel()))
print("policy_high_loss", repr(high_pol))
print("policy_high_grad_mean_bias", repr(grad_bm_hi))

# Low: aligned input x_idx = [base, R[idx]], references [base, R[u_i]]; base = 1 value here so
# the input is 3 wide: [s_t, subgoal (2)].
base = np.array([[0.4], [-0.8]])
r_idx = np.array([[1.0, 2.0], [-1.0, 0.5]])
r_refs = np.array([[[0.2, 0.4], [0.2, 0.4], [0.5, 1.0]], [[-0.3, 0.1], [-0.3, 0.1], [-0.6, 0.3]]])
x_idx = np.concatenate([base, r_idx], axis=1)
mu_idx, _ = heads(x_idx)
al = scale * np.tanh(mu_idx)
ref = np.stack([scale * np.tanh(heads(np.concatenate([base, r_refs[:, j]], axis=1))[0])
                for j in range(3)], axis=1)
dl = al[:, None, :] - ref
low_pol = beta * np.mean(dl ** 2)
grad_bm_lo = ((2 * beta * dl.sum(axis=1) / dl.size) * scale * (1 - np.tanh(mu_idx) ** 2)).sum(axis=0)
print("policy_low_aligned", repr(al.ravel()))
print("policy_low_loss", repr(low_pol))
print("policy_low_grad_mean_bias", repr(grad_bm_lo))
