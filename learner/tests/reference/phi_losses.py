"""Reference numbers for learner/tests/phi_losses.rs (numpy, float64).

φ as in HESS (digest §4): phi(s) = relu(s W0^T + b0) W1^T + b1, here obs 3 -> 4 -> 2.
  triplet, per sample: l_b = mean_d (a - p)^2 + max(0, margin - mean_d (a - n)^2); L_tri = mean_b l_b
  stable:  L_s = coeff * mean_{b,d} lam_b (phi(s) - phi_old(s))^2    (phi_old fixed)
  total:   L = L_tri + L_s   (lam = 1), gradients by hand (chain rule), then one Adam step
  Adam (PyTorch defaults, weight decay 0): m = (1-b1) g, v = (1-b2) g^2,
  theta -= lr * (m / (1-b1)) / (sqrt(v / (1-b2)) + eps)
Run: python3 learner/tests/reference/phi_losses.py
"""
import numpy as np

np.set_printoptions(precision=10, suppress=False, linewidth=120)

W0 = np.array([[0.5, -0.3, 0.2], [-0.4, 0.6, 0.1], [0.3, 0.2, -0.5], [0.1, -0.2, 0.4]])
b0 = np.array([0.1, -0.1, 0.05, 0.03])
W1 = np.array([[0.7, -0.5, 0.3, 0.2], [-0.2, 0.4, 0.6, -0.3]])
b1 = np.array([0.05, -0.05])
# phi_old: the same network with every parameter shifted
OLD = [W0 + 0.05, b0 - 0.02, W1 - 0.03, b1 + 0.01]

anchor = np.array([[0.0, 1.0, 0.6], [1.0, 0.0, -0.5], [2.0, 1.0, 0.0]])
positive = np.array([[0.2, 1.1, 0.5], [1.1, 0.2, -0.4], [2.2, 1.0, 0.1]])
negative = np.array([[2.0, 1.5, 0.5], [8.0, -6.0, -2.0], [2.1, 1.1, 0.0]])
reg = np.array([[0.5, 0.5, 0.5], [-1.0, 2.0, 0.0], [1.5, -0.5, 1.0]])
margin, coeff, lr = 1.0, 0.1, 0.01
lam = np.array([1.0, 0.5, 2.0])


def forward(x, W0, b0, W1, b1):
    z = x @ W0.T + b0
    h = np.maximum(z, 0.0)
    return h @ W1.T + b1, z, h


def backward(x, z, h, dy, W1):
    """Gradients of sum(dy * y) w.r.t. (W0, b0, W1, b1)."""
    dW1 = dy.T @ h
    db1 = dy.sum(0)
    dh = dy @ W1
    dz = dh * (z > 0)
    return [dz.T @ x, dz.sum(0), dW1, db1]


ya, za, ha = forward(anchor, W0, b0, W1, b1)
yp, zp, hp = forward(positive, W0, b0, W1, b1)
yn, zn, hn = forward(negative, W0, b0, W1, b1)
yr, zr, hr = forward(reg, W0, b0, W1, b1)
yo, _, _ = forward(reg, *OLD)
B, D = ya.shape

pos_sq = ((ya - yp) ** 2).mean(1)
neg_sq = ((ya - yn) ** 2).mean(1)
hinge = np.maximum(0.0, margin - neg_sq)
per = pos_sq + hinge
tri = per.mean()
print("per_sample", repr(per))
print("triplet", repr(tri), "positive_sq", repr(pos_sq.mean()), "negative_sq", repr(neg_sq.mean()),
      "hinge_active", (hinge > 0).mean())
stable = coeff * ((yr - yo) ** 2).mean()
stable_w = coeff * (lam[:, None] * (yr - yo) ** 2).mean()
print("stable", repr(stable), "stable_weighted", repr(stable_w))

# dL/dy for each forward pass (L = tri + stable, lam = 1)
active = (hinge > 0)[:, None]
d_ya = (2.0 * (ya - yp) / D - active * 2.0 * (ya - yn) / D) / B
d_yp = -2.0 * (ya - yp) / D / B
d_yn = active * 2.0 * (ya - yn) / D / B
d_yr = coeff * 2.0 * (yr - yo) / (B * D)
grads = [np.zeros_like(p) for p in (W0, b0, W1, b1)]
for x, z, h, dy in ((anchor, za, ha, d_ya), (positive, zp, hp, d_yp), (negative, zn, hn, d_yn), (reg, zr, hr, d_yr)):
    for g, gi in zip(grads, backward(x, z, h, dy, W1)):
        g += gi
names = ["l0.weight", "l0.bias", "l1.weight", "l1.bias"]
b1_, b2_, eps = 0.9, 0.999, 1e-8
for name, p, g in zip(names, (W0, b0, W1, b1), grads):
    m = (1 - b1_) * g
    v = (1 - b2_) * g ** 2
    new = p - lr * (m / (1 - b1_)) / (np.sqrt(v / (1 - b2_)) + eps)
    print("grad", name, repr(g.ravel()))
    print("after_adam", name, repr(new.ravel()))
