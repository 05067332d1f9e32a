"""Reference numbers for learner/tests/adam.rs: torch.optim.Adam (PyTorch defaults apart from
lr; float32) on a tiny least-squares problem, L = mean((x @ w + b - y)^2).

Prints w, b after each of 4 steps and the final optimizer state (exp_avg, exp_avg_sq, step).
Run: .venv-bench-torch/bin/python learner/tests/reference/adam.py
(the venv comes from scripts/bench_learner_torch_setup.sh)
"""
import torch

torch.set_printoptions(precision=9)
x = torch.tensor([[0.5, -1.0], [1.5, 0.25], [-0.75, 2.0]], dtype=torch.float32)
y = torch.tensor([[1.0, 0.0, -1.0], [0.5, 2.0, 0.0], [-1.0, 1.0, 3.0]], dtype=torch.float32)
w = torch.tensor([[0.1, -0.2, 0.3], [0.4, 0.0, -0.5]], dtype=torch.float32, requires_grad=True)
b = torch.tensor([0.05, -0.05, 0.2], dtype=torch.float32, requires_grad=True)
opt = torch.optim.Adam([w, b], lr=0.1)
for step in range(4):
    opt.zero_grad()
    loss = ((x @ w + b - y) ** 2).mean()
    loss.backward()
    opt.step()
    print("step", step + 1, "w", w.detach().flatten().tolist(), "b", b.detach().tolist())
for name, p in (("w", w), ("b", b)):
    s = opt.state[p]
    print(name, "step", float(s["step"]), "m", s["exp_avg"].flatten().tolist(),
          "v", s["exp_avg_sq"].flatten().tolist())
