""":class:`TwinVectorEnv`: the twin as a gymnasium ``VectorEnv`` (same-step autoreset).

``step`` returns (B, 30) float32 observations, r, terminated, truncated and ``info`` with the
scenario's per-step arrays (``reward_prime``, ``cost``, ``event_cost``, ``vx``, ``termination``).
A scene that ends is respawned in the same call: its ``observation`` is then the new episode's
first, the ended episode's last one is in ``info["final_obs"]`` (masked by ``info["_final_obs"]``).
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from srmpc.scenario.observation import OBSERVATION_SIZE
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.constants import TERMINATION_REASONS
from srmpc.sim.simulator import TwinSimulator


class TwinVectorEnv(VectorEnv):
    """``num_envs`` scenes of ``srmpc/Highway-v0`` behind gymnasium's vector API."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, params: ScenarioParameters, num_envs: int, seed: int = 0, threads: int | None = 1) -> None:
        self.params = params
        self.num_envs = num_envs
        self.simulator = TwinSimulator(params, num_envs, seed=seed, threads=threads)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, shape=(OBSERVATION_SIZE,), dtype=np.float32)
        self.single_action_space = spaces.Box(
            low=np.array([-params.steering_max_rad, params.acceleration_min_mps2], dtype=np.float32),
            high=np.array([params.steering_max_rad, params.acceleration_max_mps2], dtype=np.float32),
            dtype=np.float32,
        )
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Respawn every scene (or those in ``options["reset_mask"]``); ``seed`` re-seeds the streams."""
        if seed is not None:
            self.simulator.seed(int(seed))
        mask = None if options is None else options.get("reset_mask")
        return self.simulator.reset(mask), {}

    def step(self, actions):
        result = self.simulator.step(np.asarray(actions, dtype=np.float64), auto_reset=True)
        ended = result.terminated | result.truncated
        info = {
            "reward_prime": result.reward_prime,
            "cost": result.cost,
            "event_cost": result.event_cost,
            "vx": result.vx,
            "termination": np.array([TERMINATION_REASONS[r] for r in result.reason], dtype=object),
        }
        if ended.any():
            info["final_obs"] = np.where(ended[:, None], result.final_observation, np.nan).astype(np.float32)
            info["_final_obs"] = ended
        return result.observation, result.reward, result.terminated, result.truncated, info
