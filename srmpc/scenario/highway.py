"""``srmpc/Highway-v0``: the paper's highway scenario on top of highway-env.

A :class:`highway_env.envs.HighwayEnv` with
- our spawning (vehicles behind and ahead of the ego, see :class:`ScenarioParameters`),
- IDM vehicles with lane changes switched off and randomized DELTA,
- continuous actions (delta [rad], a [m/s^2]) mapped onto highway-env's ``ContinuousAction``,
- the paper's 30-float observation, reward r (info: r'), safety-index cost, event cost,
- termination on collision or road exit, truncation after ``episode_steps`` control steps.

``info`` after each step carries: ``reward_prime`` (r'), ``cost`` (SI cost c), ``phi`` (phi(s')),
``event_cost`` (1.0 on collision or road exit, the paper's J_c), ``vx`` [m/s], ``crashed``,
``offroad``, ``termination`` ("collision", "offroad" or "") and ``rewards`` (named reward terms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.action import action_factory
from highway_env.envs.common.observation import ObservationType
from highway_env.envs.highway_env import HighwayEnv
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from srmpc.scenario import road as road_geometry
from srmpc.scenario.actions import to_highway_env
from srmpc.scenario.observation import (
    OBSERVATION_SCALE,
    OBSERVATION_SIZE,
    SLOT_COUNT,
    find_observed_vehicles,
    raw_observation,
)
from srmpc.scenario.parameters import SafetyIndexKind, ScenarioParameters
from srmpc.scenario.reward import reward_prime, training_reward
from srmpc.scenario.safety_index import safety_index_cost, scene_safety_index


@dataclass
class SceneMeasurement:
    """Everything the scenario derives from one state of the scene."""

    ego: np.ndarray
    """[x, y, heading, speed] of the ego."""
    others: np.ndarray
    """(V, 4) [x, y, heading, speed] of the other vehicles, in spawn order."""
    slot_vehicle: np.ndarray
    """(6,) index into ``others`` of each observation slot, -1 if empty."""
    raw_observation: np.ndarray
    """(30,) unnormalized observation."""
    phi: float
    """Safety index phi(s)."""


def scene_arrays(ego: Vehicle, others: list[Vehicle]) -> tuple[np.ndarray, np.ndarray]:
    """[x, y, heading, speed] of the ego (4,) and of the other vehicles (V, 4), float64."""
    ego_state = np.array([ego.position[0], ego.position[1], ego.heading, ego.speed], dtype=np.float64)
    other_states = np.array(
        [[v.position[0], v.position[1], v.heading, v.speed] for v in others], dtype=np.float64
    ).reshape(-1, 4)
    return ego_state, other_states


class _PaperObservation(ObservationType):
    """highway-env observation type that returns the scenario's normalized 30-float vector."""

    def __init__(self, env: SrmpcHighwayEnv) -> None:
        super().__init__(env)
        self.srmpc_env = env

    def space(self) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, shape=(OBSERVATION_SIZE,), dtype=np.float32)

    def observe(self) -> np.ndarray:
        measurement = self.srmpc_env.measure()
        return (measurement.raw_observation / OBSERVATION_SCALE).astype(np.float32)


class SrmpcHighwayEnv(HighwayEnv):
    """The paper's scenario. Construct with ``ScenarioParameters`` (or via ``gymnasium.make``)."""

    def __init__(self, params: ScenarioParameters | None = None, render_mode: str | None = None) -> None:
        self.params = params if params is not None else ScenarioParameters()
        self.measurement: SceneMeasurement | None = None
        self.control_steps = 0
        self._phi = 0.0
        super().__init__(config=self._highway_env_config(self.params), render_mode=render_mode)

    @staticmethod
    def _highway_env_config(params: ScenarioParameters) -> dict:
        return {
            "action": {
                "type": "ContinuousAction",
                "acceleration_range": (params.acceleration_min_mps2, params.acceleration_max_mps2),
                "steering_range": (-params.steering_max_rad, params.steering_max_rad),
                "clip": True,
            },
            "lanes_count": road_geometry.LANE_COUNT,
            "vehicles_count": params.vehicles_count,
            "simulation_frequency": params.simulation_frequency_hz,
            "policy_frequency": params.policy_frequency_hz,
            "duration": params.episode_steps / params.policy_frequency_hz,  # [s]
            "offroad_terminal": True,
            "other_vehicles_type": "highway_env.vehicle.behavior.IDMVehicle",
            "screen_width": 800,
            "screen_height": 200,
        }

    # ----------------------------------------------------------------- spaces
    def define_spaces(self) -> None:
        self.action_type = action_factory(self, self.config["action"])
        self.observation_type = _PaperObservation(self)
        self.observation_space = self.observation_type.space()
        self.action_space = spaces.Box(
            low=np.array([-self.params.steering_max_rad, self.params.acceleration_min_mps2], dtype=np.float32),
            high=np.array([self.params.steering_max_rad, self.params.acceleration_max_mps2], dtype=np.float32),
            dtype=np.float32,
        )

    # ------------------------------------------------------------------ scene
    def _create_road(self) -> None:
        self.road = Road(
            network=RoadNetwork.straight_road_network(
                road_geometry.LANE_COUNT, length=road_geometry.ROAD_LENGTH, speed_limit=road_geometry.SPEED_LIMIT
            ),
            np_random=self.np_random,
            record_history=self.config["show_trajectories"],
        )

    def _spawn_other(self) -> IDMVehicle:
        speed = self.np_random.uniform(self.params.other_speed_min_mps, self.params.other_speed_max_mps)
        vehicle = IDMVehicle.create_random(self.road, speed=speed, spacing=self.params.spawn_spacing)
        vehicle.enable_lane_change = False
        vehicle.randomize_behavior()
        self.road.vehicles.append(vehicle)
        return vehicle

    def _create_vehicles(self) -> None:
        """Spawn ``vehicles_behind_ego`` IDM vehicles, the ego, then the rest, each ahead of the last."""
        for _ in range(self.params.vehicles_behind_ego):
            self._spawn_other()
        ego_speed = self.np_random.uniform(self.params.ego_speed_min_mps, self.params.ego_speed_max_mps)
        spawned = Vehicle.create_random(self.road, speed=ego_speed, spacing=self.params.spawn_spacing)
        ego = self.action_type.vehicle_class(self.road, spawned.position, spawned.heading, spawned.speed)
        self.controlled_vehicles = [ego]
        self.road.vehicles.append(ego)
        for _ in range(self.params.vehicles_count - self.params.vehicles_behind_ego):
            self._spawn_other()

    @property
    def other_vehicles(self) -> list[Vehicle]:
        """The IDM vehicles, in spawn order."""
        return [v for v in self.road.vehicles if v is not self.vehicle]

    def measure(self) -> SceneMeasurement:
        """Observation slots, raw observation and phi of the current state (cached until the next step)."""
        ego, others = scene_arrays(self.vehicle, self.other_vehicles)
        slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
        raw = np.empty(OBSERVATION_SIZE, dtype=np.float64)
        find_observed_vehicles(ego, others, self.params.perception_range_m, slot_vehicle)
        raw_observation(ego, others, slot_vehicle, self.params.perception_range_m, raw)
        si = self.params.safety_index
        phi = scene_safety_index(ego, others, slot_vehicle, si.kind is SafetyIndexKind.rss, si.sigma_m, si.d_min_m,
                                 si.edge_d_min_m, si.n, si.k_s, si.rss.as_tuple())
        self.measurement = SceneMeasurement(ego, others, slot_vehicle, raw, float(phi))
        return self.measurement

    # ---------------------------------------------------------------- running
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.control_steps = 0
        obs, info = super().reset(seed=seed, options=options)
        self._phi = self.measurement.phi
        info.update(self._step_info(cost=0.0))
        return obs, info

    def step(self, action: np.ndarray):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        if action.shape != (2,) or not np.all(np.isfinite(action)):
            raise ValueError(f"action must be 2 finite floats (steering [rad], acceleration [m/s^2]), got {action!r}")
        self.control_steps += 1
        params = self.params
        highway_action = to_highway_env(
            action, params.steering_max_rad, params.acceleration_min_mps2, params.acceleration_max_mps2
        )
        obs, reward, terminated, truncated, info = super().step(highway_action)
        si = params.safety_index
        cost = safety_index_cost(self._phi, self.measurement.phi, si.eta, si.cost_floor)
        self._phi = self.measurement.phi
        info.update(self._step_info(cost=float(cost)))
        return obs, float(reward), bool(terminated), bool(truncated), info

    def _rewards(self, action) -> dict[str, float]:
        ego = self.measurement.ego
        reward_params = self.params.reward
        vx = ego[3] * np.cos(ego[2])
        y_ref = road_geometry.LANE_CENTERS[road_geometry.RIGHT_LANE]
        r_prime = reward_prime(vx, ego[1], reward_params.vx_ref_mps, y_ref, reward_params.speed_weight)
        return {
            "speed_error_sq": float((reward_params.vx_ref_mps - vx) ** 2),
            "lane_error_sq": float((y_ref - ego[1]) ** 2),
            "reward_prime": float(r_prime),
            "reward": float(training_reward(r_prime, reward_params.scale)),
        }

    def _reward(self, action) -> float:
        return self._rewards(action)["reward"]

    def _is_terminated(self) -> bool:
        return bool(self.vehicle.crashed or not self.vehicle.on_road)

    def _is_truncated(self) -> bool:
        return self.control_steps >= self.params.episode_steps

    def _step_info(self, cost: float) -> dict:
        crashed = bool(self.vehicle.crashed)
        offroad = not self.vehicle.on_road
        rewards = self._rewards(None)
        return {
            "reward_prime": rewards["reward_prime"],
            "rewards": rewards,
            "cost": cost,
            "phi": self.measurement.phi,
            "event_cost": float(crashed or offroad),
            "vx": float(self.measurement.ego[3] * np.cos(self.measurement.ego[2])),
            "crashed": crashed,
            "offroad": offroad,
            "termination": "collision" if crashed else ("offroad" if offroad else ""),
        }
