"""Reference numbers for learner/tests/sac_losses.rs (numpy, float64).

SAC as CleanRL's sac_continuous_action.py:
  y        = r + gamma * (1 - d) * (min(Q1', Q2') - alpha * logp')
  L_Q      = mean((Q1 - y)^2) + mean((Q2 - y)^2)
  L_pi     = mean(alpha * logp - min(Q1, Q2))
  L_alpha  = mean(-exp(log_alpha) * (logp + target_entropy))
Run: python3 sac_losses.py
"""
import numpy as np

reward = np.array([-1.0, -0.5, 0.0, -2.0])
terminal = np.array([0.0, 1.0, 0.0, 0.0])
next_min_q = np.array([-10.0, -3.0, -1.5, -20.0])
next_log_prob = np.array([-1.2, 0.3, 2.0, -0.7])
gamma, alpha = 0.99, 0.2

y = reward + gamma * (1.0 - terminal) * (next_min_q - alpha * next_log_prob)
print("target", repr(y))

q = np.array([[-9.0, -9.5], [-1.0, -0.8], [-1.2, -2.0], [-21.0, -19.0]])
critic = np.mean((q[:, 0] - y) ** 2) + np.mean((q[:, 1] - y) ** 2)
print("critic_loss", repr(critic), "q_means", q.mean(0), "target_mean", y.mean())

log_prob = np.array([-1.0, 0.5, 1.5, -2.0])
min_q = np.array([-5.0, -4.0, -3.0, -2.0])
actor = np.mean(alpha * log_prob - min_q)
print("actor_loss", repr(actor), "entropy", -log_prob.mean())

log_alpha, target_entropy = np.log(0.3), -2.0
temp = np.mean(-np.exp(log_alpha) * (log_prob + target_entropy))
# d L_alpha / d log_alpha = L_alpha (the loss is linear in exp(log_alpha))
print("temperature_loss", repr(temp), "grad_log_alpha", repr(temp))
