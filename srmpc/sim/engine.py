"""One control step of a scene, and its batched drivers (serial, and over threads with prange).

A control step replicates ``SrmpcHighwayEnv.step``:

1. the ego's physical action goes through highway-env's action round trip
   (:func:`~srmpc.sim.vehicle.ego_control`) and is held for the whole step;
2. ``substeps`` times (``AbstractEnv._simulate``): every IDM vehicle acts (leader, IDM
   acceleration, lane-following steering; crashed vehicles keep their action), every vehicle
   integrates one step of dt (:func:`~srmpc.sim.vehicle.integrate`), then every pair is checked
   for collision in road order (:func:`~srmpc.sim.collision.handle_collisions`);
3. the scenario's measurement: the 30-float observation, phi(s'), r', r = exp(r'/scale),
   c = max(phi(s') - max(phi(s) - eta, 0), floor), the event cost, termination (the ego crashed,
   or its centre left its closest lane) and truncation (``episode_steps`` control steps).

The observation, safety index and reward are the scenario's own numba kernels
(``srmpc.scenario.observation``, ``safety_index``, ``reward``), called on the twin's arrays.
"""

from collections import namedtuple

import numba
import numpy as np
from numba import njit, prange

from srmpc.scenario.observation import (
    OBSERVATION_SCALE,
    OBSERVATION_SIZE,
    SLOT_COUNT,
    find_observed_vehicles,
    raw_observation,
)
from srmpc.scenario.reward import reward_prime, training_reward
from srmpc.scenario.safety_index import safety_index_cost, scene_safety_index
from srmpc.sim.collision import handle_collisions
from srmpc.sim.constants import MAX_STEERING_ANGLE, TERMINATION_COLLISION, TERMINATION_NONE, TERMINATION_OFFROAD
from srmpc.sim.idm import all_leaders, clip_idm_acceleration, idm_acceleration, steering_control
from srmpc.sim.spawning import spawn_scene
from srmpc.sim.state import ACCELERATION, HEADING, SPEED, STEERING, X, Y
from srmpc.sim.vehicle import apply_impacts, ego_control, integrate, on_lane

StepOutputs = namedtuple(
    "StepOutputs",
    [
        "observation",  # (B, 30) float32, normalized (after an auto-reset: the new episode's)
        "final_observation",  # (B, 30) float32, the step's own observation (before any auto-reset)
        "reward",  # (B,) float64 r
        "reward_prime",  # (B,) float64 r'
        "cost",  # (B,) float64 SI cost c
        "event_cost",  # (B,) float64, 1 on collision or road exit
        "vx",  # (B,) float64 ego longitudinal speed [m/s]
        "terminated",  # (B,) bool
        "truncated",  # (B,) bool
        "reason",  # (B,) int64 TERMINATION_*
    ],
)
"""Output arrays of a batched step (allocated once by the caller, overwritten in place)."""


@njit(cache=True, error_model="numpy", inline="always")
def road_ranks(ego_rank: int, n: int, rank: np.ndarray) -> None:
    """rank[k] = road-order position of storage index k (the ego is stored last)."""
    for k in range(n - 1):
        rank[k] = k + 1 if k >= ego_rank else k
    rank[n - 1] = ego_rank


@njit(cache=True, error_model="numpy", inline="always")
def sort_by_x(vehicles: np.ndarray, order: np.ndarray, rank: np.ndarray, position: np.ndarray) -> None:
    """Insertion-sort ``order`` by (x, road rank), O(N) when nearly sorted; position = its inverse."""
    n = order.shape[0]
    for p in range(1, n):
        k = order[p]
        x_k = vehicles[k, X]
        rank_k = rank[k]
        q = p
        while q > 0:
            j = order[q - 1]
            x_j = vehicles[j, X]
            if x_j > x_k or (x_j == x_k and rank[j] > rank_k):
                order[q] = j
                q -= 1
            else:
                break
        order[q] = k
    for p in range(n):
        position[order[p]] = p


@njit(cache=True, error_model="numpy")
def measure(s, c, b: int, observation: np.ndarray, slot_vehicle: np.ndarray, raw: np.ndarray) -> float:
    """Write scene b's normalized float32 observation into ``observation`` (30,); return phi.

    The scene's vehicle count is its arrays' (``s.vehicles.shape[1]``, = ``c.vehicles`` on a full scene), so a
    scene cut to fewer vehicles (``srmpc.sim.local_rollout``) runs with the same constants."""
    n = s.vehicles.shape[1]
    ego = s.vehicles[b, n - 1]
    others = s.vehicles[b, : n - 1]
    find_observed_vehicles(ego, others, c.perception_range, slot_vehicle)
    raw_observation(ego, others, slot_vehicle, c.perception_range, raw)
    for i in range(OBSERVATION_SIZE):
        observation[i] = np.float32(raw[i] / OBSERVATION_SCALE[i])
    rss = (c.rss_response_time_ego, c.rss_response_time_others, c.rss_longitudinal_acceleration_max,
           c.rss_longitudinal_brake_min, c.rss_longitudinal_brake_max, c.rss_lateral_acceleration_max,
           c.rss_lateral_brake_min, c.rss_lateral_margin)  # RssParameters.as_tuple()'s order
    return scene_safety_index(ego, others, slot_vehicle, c.si_rss, c.si_sigma, c.si_d_min, c.si_edge_d_min, c.si_n,
                              c.si_k, rss)


Workspace = namedtuple(
    "Workspace",
    [
        "rank",  # (N,) int64: road rank of each storage index
        "position",  # (N,) int64: inverse of ``order``
        "pair_keys",  # (N (N - 1) / 2 + 1,) int64: collision candidates' road-order keys
        "pair_first",  # (N (N - 1) / 2 + 1,) int64: their storage indices, first in road order
        "pair_second",  # (N (N - 1) / 2 + 1,) int64: and second
        "poly_a",  # (5, 2) polygon work buffer
        "poly_b",  # (5, 2)
        "lane_leader",  # (N,) int64
        "target_leader",  # (N,) int64
        "last_on_lane",  # (lanes,) int64
    ],
)
"""Work buffers of :func:`simulate_in`, allocated once per kernel call (per block of scenes in
:func:`step_parallel`); their contents carry nothing from one scene or step to the next."""


@njit(cache=True, error_model="numpy")
def workspace(n: int, lane_count: int) -> Workspace:
    """Fresh :data:`Workspace` for scenes of ``n`` vehicles on ``lane_count`` lanes."""
    return Workspace(
        np.empty(n, dtype=np.int64),
        np.empty(n, dtype=np.int64),
        np.empty(n * (n - 1) // 2 + 1, dtype=np.int64),
        np.empty(n * (n - 1) // 2 + 1, dtype=np.int64),
        np.empty(n * (n - 1) // 2 + 1, dtype=np.int64),
        np.empty((5, 2)),
        np.empty((5, 2)),
        np.empty(n, dtype=np.int64),
        np.empty(n, dtype=np.int64),
        np.empty(lane_count, dtype=np.int64),
    )


@njit(cache=True, error_model="numpy")
def simulate(s, c, b: int, steering: float, acceleration: float) -> None:
    """Advance scene b by one control step (``substeps`` integration steps) with the ego's action."""
    simulate_in(s, c, b, steering, acceleration, workspace(s.vehicles.shape[1], c.lane_count))


@njit(cache=True, error_model="numpy")
def simulate_in(s, c, b: int, steering: float, acceleration: float, w) -> None:
    """:func:`simulate` with the work buffers ``w`` (a :data:`Workspace`).

    ``order`` is sorted by x before the leader search of the first sub-step and after every
    integration; positions do not move between that sort and the next sub-step's leader search
    (collisions only mark impacts), so later sub-steps reuse it. The vehicle count is the scene's own
    (``s.vehicles.shape[1]``, as in :func:`measure`); ``w`` may be sized for more vehicles.
    """
    n = s.vehicles.shape[1]
    ego = n - 1
    vehicles = s.vehicles[b]
    control = s.control[b]
    crashed = s.crashed[b]
    impact = s.impact[b]
    has_impact = s.has_impact[b]
    lane = s.lane[b]
    target_lane = s.target_lane[b]
    order = s.order[b]
    rank, position, lane_leader, target_leader = w.rank, w.position, w.lane_leader, w.target_leader
    road_ranks(s.ego_rank[b], n, rank)
    held_steering, held_acceleration = ego_control(
        steering, acceleration, c.steering_max, c.acceleration_min, c.acceleration_max
    )
    control[ego, STEERING] = held_steering
    control[ego, ACCELERATION] = held_acceleration
    sort_by_x(vehicles, order, rank, position)
    for _ in range(c.substeps):
        all_leaders(
            vehicles, order, position, lane, target_lane, c.lane_count, c.lane_width, c.road_length,
            lane_leader, target_leader, w.last_on_lane,
        )
        for k in range(n - 1):  # IDMVehicle.act
            if crashed[k]:
                continue
            x, y = vehicles[k, X], vehicles[k, Y]
            heading, speed = vehicles[k, HEADING], vehicles[k, SPEED]
            steer = steering_control(x, y, heading, speed, target_lane[k], c.lane_width)
            steer = min(max(steer, -MAX_STEERING_ANGLE), MAX_STEERING_ANGLE)
            target_speed, delta = s.target_speed[b, k], s.delta[b, k]
            accel = idm_acceleration(vehicles, k, lane_leader[k], target_speed, delta, c.speed_limit)
            if lane[k] != target_lane[k]:  # "when changing lane, check both current and target lanes"
                accel = min(accel, idm_acceleration(vehicles, k, target_leader[k], target_speed, delta, c.speed_limit))
            control[k, STEERING] = steer
            control[k, ACCELERATION] = clip_idm_acceleration(accel)
        for k in range(n):
            integrate(vehicles, control, crashed, lane, k, c.dt, c.lane_count, c.lane_width, c.road_length)
        apply_impacts(vehicles, crashed, impact, has_impact, lane, c.lane_count, c.lane_width, c.road_length)
        sort_by_x(vehicles, order, rank, position)
        handle_collisions(vehicles, crashed, impact, has_impact, order, rank, c.dt, w.pair_keys, w.poly_a, w.poly_b,
                          w.pair_first, w.pair_second)
    s.steps[b] += 1


@njit(cache=True, error_model="numpy")
def step_scene(s, c, out, actions: np.ndarray, b: int, auto_reset: bool) -> None:
    """Control step of scene b with ``actions[b]`` = (delta [rad], a [m/s^2]); fill ``out[.][b]``."""
    step_scene_in(s, c, out, actions, b, auto_reset, workspace(s.vehicles.shape[1], c.lane_count),
                  np.empty(SLOT_COUNT, dtype=np.int64), np.empty(OBSERVATION_SIZE))


@njit(cache=True, error_model="numpy")
def step_scene_in(s, c, out, actions: np.ndarray, b: int, auto_reset: bool, w, slot_vehicle: np.ndarray,
                  raw: np.ndarray) -> None:
    """:func:`step_scene` with the work buffers ``w`` (a :data:`Workspace`), ``slot_vehicle`` (6,) int64 and
    ``raw`` (30,) float64, whose contents carry nothing from one call to the next."""
    n = c.vehicles
    ego = n - 1
    simulate_in(s, c, b, actions[b, 0], actions[b, 1], w)
    phi = measure(s, c, b, out.observation[b], slot_vehicle, raw)
    x, y = s.vehicles[b, ego, X], s.vehicles[b, ego, Y]
    heading, speed = s.vehicles[b, ego, HEADING], s.vehicles[b, ego, SPEED]
    vx = speed * np.cos(heading)
    r_prime = reward_prime(vx, y, c.vx_ref, c.y_ref, c.speed_weight)
    out.reward[b] = training_reward(r_prime, c.reward_scale)
    out.reward_prime[b] = r_prime
    out.cost[b] = safety_index_cost(s.phi[b], phi, c.si_eta, c.si_cost_floor)
    out.vx[b] = vx
    s.phi[b] = phi
    crashed = s.crashed[b, ego]
    offroad = not on_lane(x, y, s.lane[b, ego], c.lane_width, c.road_length, 0.0)
    out.terminated[b] = crashed or offroad
    out.truncated[b] = s.steps[b] >= c.episode_steps
    out.event_cost[b] = 1.0 if (crashed or offroad) else 0.0
    out.reason[b] = TERMINATION_COLLISION if crashed else (TERMINATION_OFFROAD if offroad else TERMINATION_NONE)
    if auto_reset:
        out.final_observation[b, :] = out.observation[b, :]
        if out.terminated[b] or out.truncated[b]:
            spawn_scene(s, c, b)
            s.phi[b] = measure(s, c, b, out.observation[b], slot_vehicle, raw)


@njit(cache=True, error_model="numpy")
def step_serial(s, c, out, actions: np.ndarray, auto_reset: bool) -> None:
    """All scenes, one after the other (one thread), with one set of work buffers."""
    w = workspace(s.vehicles.shape[1], c.lane_count)
    slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
    raw = np.empty(OBSERVATION_SIZE)
    for b in range(s.vehicles.shape[0]):
        step_scene_in(s, c, out, actions, b, auto_reset, w, slot_vehicle, raw)


@njit(cache=True, parallel=True, error_model="numpy")
def step_parallel(s, c, out, actions: np.ndarray, auto_reset: bool) -> None:
    """All scenes, spread over numba's threads (``numba.set_num_threads``): one contiguous block of scenes
    per thread, each block with its own work buffers. Scenes are independent, so how they are split
    changes no result."""
    scenes = s.vehicles.shape[0]
    blocks = min(numba.get_num_threads(), scenes)
    for block in prange(blocks):
        w = workspace(s.vehicles.shape[1], c.lane_count)
        slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
        raw = np.empty(OBSERVATION_SIZE)
        for b in range(block * scenes // blocks, (block + 1) * scenes // blocks):
            step_scene_in(s, c, out, actions, b, auto_reset, w, slot_vehicle, raw)


@njit(cache=True, error_model="numpy")
def reset_scenes(s, c, mask: np.ndarray, observation: np.ndarray) -> None:
    """Spawn a fresh scene wherever ``mask`` is True; write its observation and phi."""
    slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
    raw = np.empty(OBSERVATION_SIZE)
    for b in range(s.vehicles.shape[0]):
        if mask[b]:
            spawn_scene(s, c, b)
            s.phi[b] = measure(s, c, b, observation[b], slot_vehicle, raw)


@njit(cache=True, error_model="numpy")
def observe(s, c, observation: np.ndarray, phi: np.ndarray) -> None:
    """Observation (B, 30) and phi (B,) of the current states, without stepping."""
    slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
    raw = np.empty(OBSERVATION_SIZE)
    for b in range(s.vehicles.shape[0]):
        phi[b] = measure(s, c, b, observation[b], slot_vehicle, raw)


def allocate_outputs(scenes: int) -> StepOutputs:
    """Fresh output arrays for ``scenes`` scenes."""
    return StepOutputs(
        observation=np.zeros((scenes, OBSERVATION_SIZE), dtype=np.float32),
        final_observation=np.zeros((scenes, OBSERVATION_SIZE), dtype=np.float32),
        reward=np.zeros(scenes),
        reward_prime=np.zeros(scenes),
        cost=np.zeros(scenes),
        event_cost=np.zeros(scenes),
        vx=np.zeros(scenes),
        terminated=np.zeros(scenes, dtype=np.bool_),
        truncated=np.zeros(scenes, dtype=np.bool_),
        reason=np.zeros(scenes, dtype=np.int64),
    )
