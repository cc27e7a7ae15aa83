"""Shared fixtures: scenario envs and hand-built scenes; processes started by a test, killed after it."""

from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

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


ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def start_process() -> Iterator[Callable[[list[str]], subprocess.Popen]]:
    """``start(command)``: the command in the repository root, in its own session, with piped text output and
    without the pipeline's parent MLflow run; whatever still runs when the test ends is killed (SIGKILL)."""
    started: list[subprocess.Popen] = []

    def start(command: list[str]) -> subprocess.Popen:
        env = {k: v for k, v in os.environ.items() if k != "SRMPC_PARENT_RUN_ID"}
        process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env=env, start_new_session=True)
        started.append(process)
        return process

    yield start
    for process in started:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
