"""Initial scenes with the distributions of ``SrmpcHighwayEnv._create_vehicles``.

In road order, ``vehicles_behind_ego`` IDM vehicles, the ego, then the remaining IDM vehicles are
placed, each by highway-env's ``Vehicle.create_random``: a uniform lane, and

    x = max_x + spacing (12 + v) exp(-5/40 * lanes) U(0.9, 1.1)   [m]

ahead of the furthest vehicle so far (the first vehicle at 3 offsets plus that), heading 0, on
the lane centre. IDM vehicles draw v ~ U(other_speed_min, other_speed_max), keep it as their target
speed, and a velocity exponent delta ~ U(3.5, 4.5); the ego draws v ~ U(ego_speed_min, ego_speed_max)
and starts with the action (0, 0). The random numbers come from the scene's own stream
(:mod:`srmpc.sim.random`), not highway-env's generator: same distributions, different draws.
"""

import numpy as np
from numba import njit

from srmpc.sim.constants import IDM_DELTA_RANGE, SPAWN_BASE_GAP, SPAWN_GAP_PER_SPEED, SPAWN_JITTER
from srmpc.sim.random import integer, uniform
from srmpc.sim.state import HEADING, SPEED, X, Y


@njit(cache=True, error_model="numpy")
def spawn_scene(s, c, b: int) -> None:
    """Overwrite scene b of state ``s`` (StateArrays) with a fresh random scene (phi not set)."""
    n = c.vehicles
    ego = n - 1
    lane_factor = np.exp(-5 / 40 * c.lane_count)
    max_x = 0.0
    for r in range(n):
        is_ego = r == c.vehicles_behind_ego
        k = ego if is_ego else (r if r < c.vehicles_behind_ego else r - 1)
        if is_ego:
            speed = uniform(s.rng, b, c.ego_speed_min, c.ego_speed_max)
        else:
            speed = uniform(s.rng, b, c.other_speed_min, c.other_speed_max)
        lane = integer(s.rng, b, c.lane_count)
        offset = c.spawn_spacing * (SPAWN_BASE_GAP + SPAWN_GAP_PER_SPEED * speed) * lane_factor
        x0 = max_x if r > 0 else 3 * offset
        x0 += offset * uniform(s.rng, b, SPAWN_JITTER[0], SPAWN_JITTER[1])
        max_x = x0 if r == 0 else max(max_x, x0)
        s.vehicles[b, k, X] = x0
        s.vehicles[b, k, Y] = lane * c.lane_width
        s.vehicles[b, k, HEADING] = 0.0
        s.vehicles[b, k, SPEED] = speed
        s.control[b, k, 0] = 0.0
        s.control[b, k, 1] = 0.0
        s.crashed[b, k] = False
        s.impact[b, k, 0] = 0.0
        s.impact[b, k, 1] = 0.0
        s.has_impact[b, k] = False
        s.lane[b, k] = lane
        s.target_lane[b, k] = lane
        s.target_speed[b, k] = speed
        s.delta[b, k] = 4.0 if is_ego else uniform(s.rng, b, IDM_DELTA_RANGE[0], IDM_DELTA_RANGE[1])
        s.order[b, r] = k  # spawned in increasing x: road order is x order
    s.ego_rank[b] = c.vehicles_behind_ego
    s.steps[b] = 0
