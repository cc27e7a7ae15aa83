"""A trained actor as a controller: its deterministic action (the TanhNormal's mode), in numpy.

The actor's linear layers are copied into :class:`srmpc.sim.mlp.MlpPolicy`, which maps the mean
z into the action box as TorchRL's TanhNormal mode does: low + (tanh(z) + 1) / 2 (high - low).
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
        from srmpc.agents.checkpoint import load_actor

        actor = load_actor(path)
        return cls(MlpPolicy.from_torch(actor, squash=True, action_low=action_low, action_high=action_high))

    def reset(self) -> None:
        """Stateless."""

    def episode_outcomes(self) -> dict[str, int]:
        return {}

    def act(self, observation: np.ndarray, scene=None) -> np.ndarray:
        return self.policy(np.asarray(observation, dtype=np.float64)[None, :])[0]
