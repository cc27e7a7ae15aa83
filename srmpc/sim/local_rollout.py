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
fused kernel run on it unchanged (they take the vehicle count from the scene's arrays). The rollout's
``others`` then has the kept vehicles only, in kept order: ``kept[:-1]`` maps them back to the full
scene's indices.

**Who uses it.** SRMPC with ``controller.srmpc.rollout=local`` (``srmpc.controllers.srmpc.RolloutScope``): on
its compiled step the cut is made inside the same numba call as the rollout (:func:`local_arrays` on the
rollout's own work buffers, ``srmpc.mpc.compiled_step.srmpc_step``), on the Python path (the variants) by
:func:`local_rollout`. **What the dropped vehicles get.** Only the ego's trajectory and inputs of the rollout
enter SRMPC's QP, except with ``prediction=policy_rollout``, where the observed vehicles' rollout trajectories
are its prediction. Every observed vehicle is kept: it is within R of the ego at t = 0, inside the window
(whose reach is at least R + m on both sides). :func:`local_rollout` still returns a trajectory for every
vehicle: the dropped ones are predicted at constant speed along their heading (x + v cos(psi) t, y + v sin(psi) t),
as the QP's constant-velocity prediction does. The full rollout stays the default (``rollout=full``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit

from srmpc.sim.constants import MAX_SPEED, VEHICLE_LENGTH, SimConstants
from srmpc.sim.engine import road_ranks, sort_by_x, workspace
from srmpc.sim.idm import all_leaders
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import Rollout, rollout
from srmpc.sim.state import HEADING, SPEED, SceneState, StateArrays, X, Y

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


def horizon_seconds(horizon: int, constants: SimConstants) -> float:
    """H = horizon * substeps * dt [s]: the rollout's duration for ``horizon`` control steps."""
    return horizon * constants.substeps * constants.dt


@njit(cache=True, error_model="numpy")
def local_vehicles(s, c, b: int, horizon_s: float, leader_depth: int, keep: np.ndarray, w) -> None:
    """keep[k] := whether storage index k of scene b is in the local scene (module doc); the ego always.
    ``w``: a :data:`~srmpc.sim.engine.Workspace` for at least the scene's vehicles (its contents are overwritten)."""
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
def local_arrays(s, c, b: int, horizon_s: float, leader_depth: int, w):
    """(scene b's reduced copy as (1, n, ...) :data:`~srmpc.sim.state.StateArrays`, the kept storage indices);
    ``w`` as in :func:`local_vehicles`."""
    full = c.vehicles
    keep = np.zeros(full, dtype=np.bool_)
    local_vehicles(s, c, b, horizon_s, leader_depth, keep, w)
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
    arrays, kept = local_arrays(state.arrays(), constants, scene, horizon_seconds(horizon, constants), leader_depth,
                                workspace(constants.vehicles, constants.lane_count))
    return SceneState(*arrays), constants._replace(vehicles=kept.size), kept


def constant_speed_others(others: np.ndarray, horizon: int, step_s: float) -> np.ndarray:
    """(H + 1, V, 4) states of ``others`` (V, 4) at constant speed along their heading, ``step_s`` [s] per step."""
    t = np.arange(horizon + 1)[:, None] * step_s
    predicted = np.repeat(others[None], horizon + 1, axis=0)
    predicted[:, :, X] += others[:, SPEED] * np.cos(others[:, HEADING]) * t
    predicted[:, :, Y] += others[:, SPEED] * np.sin(others[:, HEADING]) * t
    return predicted


def local_rollout(state: SceneState, constants: SimConstants, policy: Callable[[np.ndarray], np.ndarray] | MlpPolicy,
                  horizon: int, record_others: bool = False, leader_depth: int = LEADER_DEPTH) -> Rollout:
    """:func:`srmpc.sim.rollout.rollout` of scene 0 on :func:`local_scene`'s cut (B = 1).

    With ``record_others``, ``others`` has every other vehicle of the full scene in its storage order: the kept
    ones as simulated, the dropped ones at constant speed (:func:`constant_speed_others`; module doc)."""
    reduced, reduced_constants, kept = local_scene(state, constants, horizon, leader_depth)
    result = rollout(reduced, reduced_constants, policy, horizon, record_others=record_others, parallel=False)
    if record_others:
        others = constant_speed_others(state.vehicles[0, :-1], horizon, constants.substeps * constants.dt)
        others[:, kept[:-1]] = result.others[0]
        result.others = others[None]
    return result
