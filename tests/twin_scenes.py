"""Hand-built scenes of the scenario on the twin simulator, for tests that need exact vehicles.

``hand_built_twin(ego, others, **overrides)`` places an ego and IDM vehicles (no lane changes,
IDM target speed = initial speed, highway-env's default DELTA = 4) on the scenario's road with
``tests.conftest.build_scene`` and copies that highway-env scene into a
:class:`~srmpc.sim.simulator.TwinSimulator` with one scene (B = 1, serial kernel). Then:

* ``twin.step(action[None])`` advances one control step (0.2 s, 3 sub-steps) with the ego
  input (steering [rad], acceleration [m/s^2]); ``result.terminated[0]`` and
  ``result.termination(0)`` ("collision", "offroad" or "") report the outcome;
* ``ego_state(twin)`` / ``other_states(twin)`` read [x, y, heading, speed] of the ego and of the
  other vehicles (in the order given to ``hand_built_twin``);
* ``observe(twin)`` returns (ego, observed others) exactly as the scenario controllers feed the
  LTV-MPC (``srmpc/controllers/ltv_mpc.py``): the leader and follower on each lane within the
  perception range, at most 6.

Road (``srmpc/scenario/road.py``): lane centres y = 0 (left), 4, 8 m (right lane, the tracking
target); y grows to the driver's right; the road edges are y = -2 and 10 m.

The scenario needs at least one other vehicle: for a scene without traffic (``others=[]``) a
placeholder is put :data:`PLACEHOLDER_AHEAD_M` ahead of the ego on the left lane, driving at the
speed limit, so it stays beyond the perception range of an ego that drives at most that fast.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from srmpc.scenario import road
from srmpc.scenario.observation import SLOT_COUNT, find_observed_vehicles
from srmpc.sim.simulator import TwinSimulator
from tests.conftest import build_scene, make_env

PLACEHOLDER_AHEAD_M = 1000.0
"""How far ahead of the ego the placeholder vehicle of a traffic-free scene starts [m]."""


def hand_built_twin(ego: Sequence[float], others: Sequence[Sequence[float]] = (),
                    **scenario_overrides) -> TwinSimulator:
    """A one-scene twin holding exactly ``ego`` and ``others``, each (x, y, heading, speed).

    ``scenario_overrides`` go to ``ScenarioParameters`` (e.g. ``episode_steps``). With no
    ``others``, one placeholder vehicle far ahead is added (see the module doc).
    """
    others = [tuple(map(float, vehicle)) for vehicle in others]
    if not others:
        others = [(float(ego[0]) + PLACEHOLDER_AHEAD_M, float(road.LANE_CENTERS[0]), 0.0, road.SPEED_LIMIT)]
    env = make_env(**scenario_overrides)
    env.reset(seed=0)
    build_scene(env, ego=tuple(map(float, ego)), others=others)
    return TwinSimulator.from_highway_env([env], threads=1)


def ego_state(twin: TwinSimulator) -> np.ndarray:
    """(4,) [x, y, heading, speed] of the ego of scene 0 (a copy)."""
    return twin.state.vehicles[0, -1].copy()


def other_states(twin: TwinSimulator) -> np.ndarray:
    """(V, 4) [x, y, heading, speed] of the other vehicles of scene 0 (a copy)."""
    return twin.state.vehicles[0, :-1].copy()


def observe(twin: TwinSimulator) -> tuple[np.ndarray, np.ndarray]:
    """(ego (4,), observed others (<= 6, 4)) of scene 0: the LTV-MPC's input, as in the scenario."""
    ego, others = ego_state(twin), other_states(twin)
    slots = np.empty(SLOT_COUNT, dtype=np.int64)
    find_observed_vehicles(ego, others, twin.params.perception_range_m, slots)
    return ego, others[slots[slots >= 0]]
