"""A prediction sized to the horizon: the rollout's scene cut down to the vehicles that can matter.

SRMPC rolls the policy out for H = N * substeps * dt seconds (N = 25 control steps, 5 s) on a copy of
the whole scene (:mod:`srmpc.sim.rollout`). What the rollout returns about the ego depends on the other
vehicles only through the policy's observation and the safety index (both read only the closest vehicle
per lane and direction with |x_j - x_ego| <= R, R = ``perception_range``: ``find_observed_vehicles``)
and through collisions with the ego (centres closer than the vehicle diagonal, 5.39 m < R). A vehicle
that stays more than R ahead of or behind the ego for the whole horizon changes none of them, except
through the vehicles it leads (IDM has no distance cutoff). :func:`local_scene` therefore keeps

1. **the window**: every vehicle j that could come within R + m of the ego (m = one vehicle length, a
   margin for impacts and headings) at some t in [0, H]. With dx = x_j - x_ego at t = 0:

   - ahead (dx >= 0): dx <= R + m + P_ego^+(H), where P_ego^+(H) is the most the ego can advance:
     its acceleration is at most ``acceleration_max`` and its speed is pulled back above
     V = ``MAX_SPEED`` (40 m/s), so v(t) <= min(v_0 + a_max t, max(v_0, V)) and
     P_ego^+(H) = int_0^H min(v_0 + a_max t, max(v_0, V)) dt (<= 200 m at H = 5 s);
   - behind (dx < 0): -dx <= R + m + max(0, (w_j - v_0) H + b H^2 / 2), w_j = max(v_j, v0_j) (an IDM
     vehicle at or above its target speed v0_j, clipped to the speed limit, has IDM acceleration
     <= 0, so its speed never exceeds w_j), b = -``acceleration_min`` the ego's strongest braking.
     The closing distance (w_j - v_0) t + b t^2 / 2 is convex in t, so its maximum over [0, H] is at
     an end;

2. **the leaders**: the lane leader and target-lane leader (``idm.all_leaders`` at t = 0, the order the
   rollout's first sub-step uses) of every kept IDM vehicle, repeated ``leader_depth`` times (a chain of
   leaders in lane order), so that each window vehicle follows the vehicle it actually follows.

**The bound.** If (a) the other vehicles drive forward (x-progress >= 0 over the horizon; this is the one
assumption not proved here: IDM brakes at up to 6 m/s^2, so a vehicle that brakes hard for the whole horizon,
behind a crash, can stop and, in highway-env's model, reverse), and (b) every window vehicle's trajectory over
[0, H] is the full scene's, then no dropped vehicle is ever within R of the ego, so the observation, the SI,
r', the termination and the ego's trajectory of the reduced rollout equal the full one's bit for bit. Proof of
the first part: for a dropped vehicle ahead, x_j(t) - x_ego(t) >= dx + 0 - P_ego^+(t) >= dx - P_ego^+(H) > R + m;
for one behind, x_ego(t) - x_j(t) >= -dx - max_t[(w_j - v_0) t + b t^2 / 2] > R + m. The observation picks
among |dx| <= R only, and the ego's collision test needs |dx| < 5.39 m, so a dropped vehicle is neither
observed nor hit, and the ego's action at every step is the full rollout's.

(b) is where the reduced rollout is *not* exact: a kept vehicle's motion depends on its leader, its leader's
on its own, and so on to the front of the lane. With ``leader_depth`` = d, the leaders of window vehicles are
kept d links deep, and the last vehicle of each kept chain drives on a free road instead of behind its dropped
leader (lane changes are off in the twin, so the lane order, and with it each vehicle's leader, holds over the
horizon unless vehicles collide); that error reaches a window vehicle only through d IDM links within 5 s,
each damped by the IDM gap term (s*/gap)^2. ``leader_depth = -1`` keeps whole chains (then (b) holds except
for collisions between a dropped and a kept vehicle, and under (a) the reduced rollout equals the full one bit for bit;
it keeps every vehicle ahead of the window in a lane that has one). Followers are never needed: with lane
changes off, an IDM vehicle reads only its leaders. The measured deviation on twin scenes is in
``tests/test_local_rollout.py``.

The reduced scene keeps the storage order (IDM vehicles in spawn order, the ego last) and renumbers the
road order (``ego_rank``) and the x-order cache (``order``), so :func:`srmpc.sim.rollout.rollout` and the
fused kernel run on it unchanged, with ``constants.vehicles`` set to the reduced count. The rollout's
``others`` then has the kept vehicles only, in kept order: ``kept[:-1]`` maps them back to the full
scene's indices. The full rollout stays the default everywhere; nothing calls this module yet.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from srmpc.sim.constants import MAX_SPEED, VEHICLE_LENGTH, SimConstants
from srmpc.sim.engine import road_ranks, sort_by_x, workspace
from srmpc.sim.idm import all_leaders
from srmpc.sim.state import SPEED, SceneState, StateArrays, X

WINDOW_MARGIN_M = VEHICLE_LENGTH
"""m: the window's extra reach beyond the perception range [m] (impacts, headings)."""
LEADER_DEPTH = 2
"""Default links of each kept vehicle's leader chain to keep (module doc; measured in the tests)."""


@njit(cache=True, error_model="numpy", inline="always")
def ego_reach_ahead_m(speed: float, acceleration_max: float, horizon_s: float) -> float:
    """P_ego^+(H) = int_0^H min(v_0 + a_max t, max(v_0, V)) dt [m] (module doc)."""
    cap = max(speed, MAX_SPEED)
    if acceleration_max <= 0.0:
        return max(speed, 0.0) * horizon_s
    t_cap = (cap - speed) / acceleration_max
    if t_cap >= horizon_s:
        return speed * horizon_s + 0.5 * acceleration_max * horizon_s**2
    return speed * t_cap + 0.5 * acceleration_max * t_cap**2 + cap * (horizon_s - t_cap)


@njit(cache=True, error_model="numpy", inline="always")
def closing_from_behind_m(speed_bound: float, ego_speed: float, ego_brake: float, horizon_s: float) -> float:
    """max over t in [0, H] of (w_j - v_0) t + b t^2 / 2 [m] (convex in t: the larger end)."""
    return max(0.0, (speed_bound - ego_speed) * horizon_s + 0.5 * ego_brake * horizon_s**2)


@njit(cache=True, error_model="numpy")
def local_vehicles(s, c, b: int, horizon_s: float, leader_depth: int, keep: np.ndarray) -> None:
    """keep[k] := whether storage index k of scene b is in the local scene (module doc); the ego always."""
    n = c.vehicles
    ego = n - 1
    vehicles = s.vehicles[b]
    x_ego, v_ego = vehicles[ego, X], vehicles[ego, SPEED]
    ahead_m = c.perception_range + WINDOW_MARGIN_M + ego_reach_ahead_m(v_ego, c.acceleration_max, horizon_s)
    frontier = np.empty(n, dtype=np.int64)
    count = 0
    for k in range(n - 1):
        dx = vehicles[k, X] - x_ego
        if dx >= 0.0:
            keep[k] = dx <= ahead_m
        else:
            target = min(max(s.target_speed[b, k], 0.0), c.speed_limit)
            bound = max(vehicles[k, SPEED], target)
            reach = c.perception_range + WINDOW_MARGIN_M + closing_from_behind_m(
                bound, v_ego, -c.acceleration_min, horizon_s)
            keep[k] = -dx <= reach
        if keep[k]:
            frontier[count] = k
            count += 1
    keep[ego] = True
    if leader_depth == 0 or count == 0:
        return
    w = workspace(n, c.lane_count)
    order = s.order[b].copy()
    road_ranks(s.ego_rank[b], n, w.rank)
    sort_by_x(vehicles, order, w.rank, w.position)
    all_leaders(vehicles, order, w.position, s.lane[b], s.target_lane[b], c.lane_count, c.lane_width,
                c.road_length, w.lane_leader, w.target_leader, w.last_on_lane)
    depth = 0
    following = np.empty(n, dtype=np.int64)
    while count > 0 and (leader_depth < 0 or depth < leader_depth):
        added = 0
        for i in range(count):
            k = frontier[i]
            for j in (w.lane_leader[k], w.target_leader[k]):
                if j >= 0 and not keep[j]:
                    keep[j] = True
                    following[added] = j
                    added += 1
        frontier[:added] = following[:added]
        count = added
        depth += 1


@njit(cache=True, error_model="numpy")
def local_arrays(s, c, b: int, horizon_s: float, leader_depth: int):
    """(scene b's reduced copy as (1, n, ...) :data:`~srmpc.sim.state.StateArrays`, the kept storage indices)."""
    full = c.vehicles
    keep = np.zeros(full, dtype=np.bool_)
    local_vehicles(s, c, b, horizon_s, leader_depth, keep)
    kept = np.nonzero(keep)[0]
    n = kept.size
    index = np.full(full, -1, dtype=np.int64)
    for i in range(n):
        index[kept[i]] = i
    vehicles, control, impact = np.empty((1, n, 4)), np.empty((1, n, 2)), np.empty((1, n, 2))
    crashed, has_impact = np.empty((1, n), dtype=np.bool_), np.empty((1, n), dtype=np.bool_)
    lane, target_lane = np.empty((1, n), dtype=np.int64), np.empty((1, n), dtype=np.int64)
    target_speed, delta = np.empty((1, n)), np.empty((1, n))
    for i in range(n):
        k = kept[i]
        vehicles[0, i] = s.vehicles[b, k]
        control[0, i] = s.control[b, k]
        impact[0, i] = s.impact[b, k]
        crashed[0, i] = s.crashed[b, k]
        has_impact[0, i] = s.has_impact[b, k]
        lane[0, i] = s.lane[b, k]
        target_lane[0, i] = s.target_lane[b, k]
        target_speed[0, i] = s.target_speed[b, k]
        delta[0, i] = s.delta[b, k]
    ego_rank = np.zeros(1, dtype=np.int64)
    for i in range(n - 1):
        if kept[i] < s.ego_rank[b]:
            ego_rank[0] += 1
    order = np.empty((1, n), dtype=np.int64)  # the full order restricted to the kept: as sorted as it was
    p = 0
    for q in range(full):
        i = index[s.order[b, q]]
        if i >= 0:
            order[0, p] = i
            p += 1
    arrays = StateArrays(vehicles, control, crashed, impact, has_impact, lane, target_lane, target_speed, delta,
                         ego_rank, s.steps[b:b + 1].copy(), s.phi[b:b + 1].copy(), s.rng[b:b + 1].copy(), order)
    return arrays, kept


def local_scene(
    state: SceneState, constants: SimConstants, horizon: int, leader_depth: int = LEADER_DEPTH, scene: int = 0
) -> tuple[SceneState, SimConstants, np.ndarray]:
    """Scene ``scene`` of ``state`` cut to the vehicles that matter within ``horizon`` control steps.

    Returns (the reduced scene, B = 1; the constants with ``vehicles`` = its vehicle count; ``kept``, the
    full scene's storage indices of its vehicles, increasing, the ego last). ``state`` is not modified.
    ``leader_depth``: how many links of each kept vehicle's lane-ordered leader chain to keep (-1: all).
    """
    if horizon < 1:
        raise ValueError(f"horizon={horizon}: must be >= 1")
    horizon_s = horizon * constants.substeps * constants.dt
    arrays, kept = local_arrays(state.arrays(), constants, scene, horizon_s, leader_depth)
    return SceneState(*arrays), constants._replace(vehicles=kept.size), kept
