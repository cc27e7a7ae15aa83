"""Shared fixtures: scenario envs and hand-built scenes."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from highway_env.vehicle.behavior import IDMVehicle

import srmpc  # noqa: F401  (registers srmpc/Highway-v0)
from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.scenario.parameters import ScenarioParameters


def make_env(**overrides) -> SrmpcHighwayEnv:
    """An unwrapped scenario env with ``ScenarioParameters(**overrides)``."""
    return gymnasium.make(srmpc.SCENARIO_ID, params=ScenarioParameters(**overrides)).unwrapped


def build_scene(env: SrmpcHighwayEnv, ego: tuple, others: list[tuple]) -> None:
    """Replace the scene by an ego at (x, y, heading, speed) and IDM vehicles at ``others``."""
    road = env.road
    ego_vehicle = env.vehicle
    ego_vehicle.position = np.array(ego[:2], dtype=float)
    ego_vehicle.heading, ego_vehicle.speed = float(ego[2]), float(ego[3])
    ego_vehicle.crashed = False
    ego_vehicle.on_state_update()
    vehicles = [ego_vehicle]
    for x, y, heading, speed in others:
        vehicle = IDMVehicle(road, np.array([x, y], dtype=float), heading, speed, enable_lane_change=False)
        vehicles.append(vehicle)
    road.vehicles = vehicles
    env.measure()
    env._phi = env.measurement.phi


@pytest.fixture
def env() -> SrmpcHighwayEnv:
    scenario_env = make_env()
    scenario_env.reset(seed=0)
    return scenario_env
