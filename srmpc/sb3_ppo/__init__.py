"""The peer PPO: Stable-Baselines3's PPO trained on the twin with our agent's hyperparameters.

- ``vec_env``: the twin as an SB3 ``VecEnv`` (actions in [-1, 1], terminal observations, truncation flags,
  the paper's per-episode metrics);
- ``training``: the hyperparameter map and every remaining difference, the training log, checkpoints and
  resume, the exported ``policy.pt`` (the clipped mean as an MLP) that the evaluation runs.
"""
