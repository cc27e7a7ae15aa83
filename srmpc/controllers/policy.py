"""A trained actor as a controller: its deterministic action, in numpy.

Our actor's linear layers are copied into :class:`srmpc.sim.mlp.MlpPolicy`, which maps the mean
z into the action box as TorchRL's TanhNormal mode does: low + (tanh(z) + 1) / 2 (high - low).
A ``policy.pt`` of Stable-Baselines3's PPO (``action_head: clipped_gaussian_mean``, srmpc.sb3_ppo)
holds its mean network with the box map folded in; its action is that mean, which the environment
clips to the box, as SB3's deterministic ``predict`` does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from srmpc.sim.mlp import MlpPolicy


class PolicyController:
    """Acts with ``policy`` on the normalized observation; no planner outcomes to count."""

    def __init__(self, policy: MlpPolicy) -> None:
        self.policy = policy

    @classmethod
    def from_policy_file(cls, path: Path, action_low: np.ndarray, action_high: np.ndarray) -> PolicyController:
        """Load a ``policy.pt`` written by training (``srmpc.agents.checkpoint.save_policy``)."""
        from srmpc.agents.checkpoint import CheckpointError, actor_mean_layers, read_policy_file

        saved = read_policy_file(path)
        if saved.get("action_head") == "clipped_gaussian_mean":
            try:
                weights = [w.double().numpy() for w in saved["weights"]]
                biases = [b.double().numpy() for b in saved["biases"]]
                return cls(MlpPolicy(weights, biases, action_low, action_high, squash=False))
            except (KeyError, AttributeError, ValueError) as error:
                raise CheckpointError(f"{path}: not a policy file written by stage=train_sb3 ({error})") from error
        weights, biases = actor_mean_layers(saved, path)  # the file is read once
        return cls(MlpPolicy(weights, biases, action_low, action_high, squash=True))

    def reset(self) -> None:
        """Stateless."""

    def episode_outcomes(self) -> dict[str, int]:
        return {}

    def act(self, observation: np.ndarray, scene=None) -> np.ndarray:
        return self.policy(np.asarray(observation, dtype=np.float64)[None, :])[0]
