"""Copy the exact state of ``SrmpcHighwayEnv`` scenes into a :class:`~srmpc.sim.state.SceneState`.

Per vehicle: position, heading, speed, held action, crashed flag, pending impact, closest lane,
and for IDM vehicles target lane, target speed and DELTA; per scene: the ego's road rank, the
control-step counter and phi. The scenes must be ``srmpc/Highway-v0`` scenes: one straight road,
IDM vehicles with lane changes off, a plain kinematic ego, no road objects.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.sim.state import SceneState


def _lane_id(lane_index: tuple) -> int:
    if lane_index is None or tuple(lane_index[:2]) != ("0", "1"):
        raise ValueError(f"vehicle on lane {lane_index!r}, expected one of the straight road ('0', '1', i)")
    return int(lane_index[2])


def state_from_highway_envs(envs: Sequence[SrmpcHighwayEnv]) -> SceneState:
    """The twin state of ``envs`` (one scene each, in order). Raises ValueError on foreign scenes."""
    if len(envs) == 0:
        raise ValueError("need at least one env")
    counts = {len(env.unwrapped.road.vehicles) for env in envs}
    if len(counts) != 1:
        raise ValueError(f"all scenes need the same number of vehicles, got {sorted(counts)}")
    n = counts.pop()
    state = SceneState.empty(len(envs), n)
    for b, wrapped in enumerate(envs):
        env = wrapped.unwrapped
        road = env.road
        if road.objects:
            raise ValueError("road objects are not supported by the twin")
        ego = env.vehicle
        if type(ego) is not Vehicle:
            raise ValueError(f"the ego must be a plain kinematic Vehicle, got {type(ego).__name__}")
        ranks = [r for r, v in enumerate(road.vehicles) if v is ego]
        if len(ranks) != 1:
            raise ValueError("the ego must be on the road exactly once")
        others = [v for v in road.vehicles if v is not ego]
        for k, vehicle in enumerate([*others, ego]):
            is_ego = vehicle is ego
            if not is_ego:
                if not isinstance(vehicle, IDMVehicle) or type(vehicle).act is not IDMVehicle.act:
                    raise ValueError(f"other vehicles must be IDMVehicle, got {type(vehicle).__name__}")
                if vehicle.enable_lane_change:
                    raise ValueError("IDM vehicles must have enable_lane_change=False")
            state.vehicles[b, k] = [vehicle.position[0], vehicle.position[1], vehicle.heading, vehicle.speed]
            state.control[b, k] = [vehicle.action.get("steering", 0.0), vehicle.action.get("acceleration", 0.0)]
            state.crashed[b, k] = bool(vehicle.crashed)
            impact = getattr(vehicle, "impact", None)
            state.has_impact[b, k] = impact is not None
            state.impact[b, k] = impact if impact is not None else 0.0
            state.lane[b, k] = _lane_id(vehicle.lane_index)
            if isinstance(vehicle, ControlledVehicle):
                state.target_lane[b, k] = _lane_id(vehicle.target_lane_index)
                state.target_speed[b, k] = vehicle.target_speed
            else:
                state.target_lane[b, k] = state.lane[b, k]
                state.target_speed[b, k] = vehicle.speed
            state.delta[b, k] = getattr(vehicle, "DELTA", 4.0)
        state.ego_rank[b] = ranks[0]
        state.steps[b] = env.control_steps
        state.phi[b] = env._phi
        rank = np.array([k + 1 if k >= ranks[0] else k for k in range(n - 1)] + [ranks[0]])
        state.order[b] = np.lexsort((rank, state.vehicles[b, :, 0]))
    return state
