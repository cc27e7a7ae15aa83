""":class:`TwinSb3VecEnv`: the twin's :class:`~srmpc.sim.vector_env.TwinVectorEnv` as a Stable-Baselines3 ``VecEnv``.

What SB3 expects and the twin gives differently:

- **Actions in [-1, 1]**: SB3 samples an unsquashed Gaussian and clips it to the action space, and
  advises a normalized space. The adapter's space is [-1, 1]^2; a = c + h u maps it onto the physical box
  (c = (high + low) / 2, h = (high - low) / 2 of the twin's float32 action space: steering +-0.1 rad, which is
  0.1 + 1.5e-9 in float32 and clipped to 0.1 by the twin, acceleration +-5 m/s^2). So SB3's
  ``log_std_init`` is in the same units as our actor's pre-squash std (tanh'(0) = 1).
- **Autoreset and the end of an episode**: the twin respawns an ended scene in the same call. SB3 wants
  ``dones`` = terminated or truncated, the ended episode's last observation in
  ``infos[i]["terminal_observation"]`` and ``infos[i]["TimeLimit.truncated"]`` = truncated and not
  terminated (SB3 then bootstraps the truncated step with gamma V(terminal observation)).
- **The paper's units**: each step's r' [-], SI cost, event cost and v_x [m/s] are in ``infos[i]``, and the
  adapter sums them per episode (:attr:`finished`: one dict per ended episode, with the keys of
  ``srmpc.agents.trainer.EpisodeTracker``), so SB3's curves are logged as ours are.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from srmpc.agents.trainer import EpisodeTracker
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.vector_env import TwinVectorEnv

EPISODE_KEYS = EpisodeTracker.KEYS
"""Per-episode sums, our trainer's: r' (J_r), the training reward r, event cost (J_c), SI cost, steps, v_x [m/s]."""


class TwinSb3VecEnv(VecEnv):
    """``num_envs`` twin scenes behind SB3's ``VecEnv`` API, actions normalized to [-1, 1]."""

    def __init__(self, params: ScenarioParameters, num_envs: int, seed: int = 0) -> None:
        self.twin = TwinVectorEnv(params, num_envs, seed=seed, threads=1)
        box = self.twin.single_action_space
        self.action_center = (box.high.astype(np.float64) + box.low.astype(np.float64)) / 2.0
        self.action_half_range = (box.high.astype(np.float64) - box.low.astype(np.float64)) / 2.0
        normalized = spaces.Box(-1.0, 1.0, shape=box.shape, dtype=np.float32)
        super().__init__(num_envs, self.twin.single_observation_space, normalized)
        self._actions: np.ndarray | None = None
        self.sums = {key: np.zeros(num_envs) for key in EPISODE_KEYS}
        self.finished: list[dict[str, float]] = []
        """Episodes that ended since the caller last emptied this list."""
        self.total_event_cost = 0.0
        self.total_reward = 0.0
        self.total_steps = 0

    def physical_actions(self, normalized: np.ndarray) -> np.ndarray:
        """(B, 2) in [-1, 1] -> (delta [rad], a [m/s^2]) in the box."""
        return self.action_center + self.action_half_range * np.asarray(normalized, dtype=np.float64)

    # --------------------------------------------------------------------------------- VecEnv API
    def reset(self) -> np.ndarray:
        seed = self._seeds[0]
        observation, _ = self.twin.reset(seed=seed)
        self._reset_seeds()
        self.sums = {key: np.zeros(self.num_envs) for key in EPISODE_KEYS}
        return observation

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = self.physical_actions(actions)

    def step_wait(self):
        observation, reward, terminated, truncated, info = self.twin.step(self._actions)
        self._track(reward, info)
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = info["final_obs"][i]
            infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            infos[i]["termination"] = info["termination"][i]
        self._close_episodes(dones)
        return observation, reward.astype(np.float32), dones, infos

    def close(self) -> None:
        self.twin.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.twin, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.twin, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        method = getattr(self.twin, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    # --------------------------------------------------------------------------------- episodes
    def _track(self, reward: np.ndarray, info: dict[str, np.ndarray]) -> None:
        self.sums["return"] += info["reward_prime"]
        self.sums["train_return"] += reward
        self.sums["cost_return"] += info["event_cost"]
        self.sums["si_cost_return"] += info["cost"]
        self.sums["steps"] += 1.0
        self.sums["vx_sum"] += info["vx"]
        self.total_event_cost += float(info["event_cost"].sum())
        self.total_reward += float(reward.sum())
        self.total_steps += self.num_envs

    def _close_episodes(self, dones: np.ndarray) -> None:
        for i in np.flatnonzero(dones):
            episode = {key: float(self.sums[key][i]) for key in EPISODE_KEYS}
            episode["vx"] = episode.pop("vx_sum") / max(episode["steps"], 1.0)
            self.finished.append(episode)
            for key in EPISODE_KEYS:
                self.sums[key][i] = 0.0

    def runtime_state(self) -> dict[str, Any]:
        """The simulator's scenes and streams plus the running episode sums (a checkpoint's env part)."""
        return {"simulator": self.twin.simulator.snapshot(), "sums": {k: v.copy() for k, v in self.sums.items()},
                "total_event_cost": self.total_event_cost, "total_reward": self.total_reward,
                "total_steps": self.total_steps}

    def load_runtime_state(self, state: dict[str, Any]) -> None:
        self.twin.simulator.restore(state["simulator"])
        self.sums = {k: v.copy() for k, v in state["sums"].items()}
        self.total_event_cost, self.total_steps = state["total_event_cost"], state["total_steps"]
        self.total_reward = state["total_reward"]
