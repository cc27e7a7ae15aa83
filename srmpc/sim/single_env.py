"""One twin scene behind the gymnasium ``Env`` face of ``SrmpcHighwayEnv``.

Evaluation runs controllers through ``reset(seed) / step(action)`` and reads the scene
measurement (``env.unwrapped.measurement``); this class provides exactly that on the batched
simulator with B = 1, so every controller runs unchanged on either simulator. ``reset(seed=s)``
re-seeds the scene's stream with ``s``: the episode is a draw from the scenario's spawn
distributions (not highway-env's draw for the same seed).
"""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium import spaces

from srmpc.scenario.highway import SceneMeasurement
from srmpc.scenario.observation import (
    OBSERVATION_SIZE,
    SLOT_COUNT,
    find_observed_vehicles,
    raw_observation,
)
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.simulator import TwinSimulator


class TwinScenarioEnv(gymnasium.Env):
    """A single scene of :class:`TwinSimulator` with the scenario env's API and info keys."""

    metadata = {"render_modes": []}

    def __init__(self, params: ScenarioParameters | None = None) -> None:
        self.params = params if params is not None else ScenarioParameters()
        self.simulator = TwinSimulator(self.params, scenes=1, seed=0, threads=1)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(OBSERVATION_SIZE,), dtype=np.float32)
        self.action_space = spaces.Box(
            low=np.array([-self.params.steering_max_rad, self.params.acceleration_min_mps2], dtype=np.float32),
            high=np.array([self.params.steering_max_rad, self.params.acceleration_max_mps2], dtype=np.float32),
            dtype=np.float32,
        )
        self._slots = np.empty(SLOT_COUNT, dtype=np.int64)
        self._raw = np.empty(OBSERVATION_SIZE, dtype=np.float64)

    @property
    def measurement(self) -> SceneMeasurement:
        """The scene as ``SrmpcHighwayEnv.measurement`` describes it."""
        vehicles = self.simulator.state.vehicles[0]
        ego, others = vehicles[-1].copy(), vehicles[:-1].copy()
        find_observed_vehicles(ego, others, self.params.perception_range_m, self._slots)
        raw_observation(ego, others, self._slots, self.params.perception_range_m, self._raw)
        return SceneMeasurement(ego, others, self._slots.copy(), self._raw.copy(), float(self.simulator.state.phi[0]))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.simulator.seed(seed)
        observation = self.simulator.reset()[0]
        return observation, {"phi": float(self.simulator.state.phi[0])}

    def step(self, action):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite floats (steering [rad], acceleration [m/s^2]), got {action!r}")
        result = self.simulator.step(action[None, :])
        info = {
            "reward_prime": float(result.reward_prime[0]),
            "cost": float(result.cost[0]),
            "phi": float(self.simulator.state.phi[0]),
            "event_cost": float(result.event_cost[0]),
            "vx": float(result.vx[0]),
            "termination": result.termination(0),
        }
        return (result.observation[0], float(result.reward[0]), bool(result.terminated[0]),
                bool(result.truncated[0]), info)


class HighwayEnvStartTwinEnv(TwinScenarioEnv):
    """:class:`TwinScenarioEnv` whose episodes start from highway-env's own reset for the same seed.

    ``reset(seed=s)`` resets a ``srmpc/Highway-v0`` env (highway-env) with seed ``s`` and copies its
    scene exactly into the twin (:func:`srmpc.sim.highway_copy.state_from_highway_envs`); every step
    after that is the twin's, which equals highway-env's step for step. So an evaluation here draws its
    start states from highway-env's distribution at the twin's speed: the cross-check of the twin's
    own resets (DVC stage ``crosscheck_resets``).
    """

    def __init__(self, params: ScenarioParameters | None = None) -> None:
        super().__init__(params)
        from srmpc.scenario.highway import SrmpcHighwayEnv

        self._highway_env = SrmpcHighwayEnv(params=self.params)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        gymnasium.Env.reset(self, seed=seed)
        from srmpc.sim.highway_copy import state_from_highway_envs

        self._highway_env.reset(seed=seed)
        state = state_from_highway_envs([self._highway_env])
        if state.vehicle_count != self.simulator.state.vehicle_count:
            raise ValueError(f"highway-env spawned {state.vehicle_count} vehicles, the twin holds "
                             f"{self.simulator.state.vehicle_count}")
        state.rng[...] = self.simulator.state.rng  # the twin's stream (unused within an episode)
        self.simulator.restore(state)
        return self.simulator.observation[0], {"phi": float(self.simulator.state.phi[0])}

    def close(self) -> None:
        self._highway_env.close()
        super().close()
