"""Forward rollouts of a policy from given scenes: SRMPC's prediction of the nominal trajectory.

From a :class:`~srmpc.sim.state.SceneState` (left untouched: the rollout runs on a copy), the
policy acts on each scene's normalized observation for ``horizon`` control steps, without resets;
a scene that terminates keeps being simulated (its flags say when it terminated). Returned
per scene b and step t: the ego's state before step t (t = 0..H), the action applied at t
(clipped to the action box), the SI cost, r' and the termination flag of step t, optionally all
other vehicles' states.

A :class:`~srmpc.sim.mlp.MlpPolicy` with two hidden layers runs fused inside one numba kernel
(observation, network and simulation never leave compiled code); any other callable
(B, 30) float32 -> (B, 2) runs in a Python loop over the horizon, one batched step per call.
"""

from __future__ import annotations

from collections import namedtuple
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from srmpc.scenario.observation import OBSERVATION_SIZE, SLOT_COUNT
from srmpc.scenario.reward import reward_prime
from srmpc.scenario.safety_index import safety_index_cost
from srmpc.sim import engine
from srmpc.sim.constants import SimConstants
from srmpc.sim.engine import measure, simulate_in, workspace
from srmpc.sim.mlp import MlpPolicy, mlp_action
from srmpc.sim.state import HEADING, SPEED, SceneState, StateArrays, X, Y
from srmpc.sim.vehicle import on_lane


@dataclass
class Rollout:
    """A batch of predicted trajectories."""

    ego: np.ndarray
    """(B, H + 1, 4) ego [x [m], y [m], heading [rad], speed [m/s]] at steps 0..H."""
    actions: np.ndarray
    """(B, H, 2) applied (delta [rad], a [m/s^2]), clipped to the action box."""
    cost: np.ndarray
    """(B, H) SI cost of each step."""
    reward_prime: np.ndarray
    """(B, H) r' after each step."""
    terminated: np.ndarray
    """(B, H) bool: the ego had crashed or left the road after step t."""
    others: np.ndarray | None = None
    """(B, H + 1, N - 1, 4) the other vehicles' states, if recorded."""


RolloutBuffers = namedtuple("RolloutBuffers", ["slot_vehicle", "raw", "observation", "h0", "h1", "z", "work"])
"""Work arrays of one scene's MLP rollout (their contents carry nothing between calls)."""


@njit(cache=True, error_model="numpy")
def rollout_buffers(n, lane_count, hidden0, hidden1, outputs):
    """Fresh :data:`RolloutBuffers` for scenes of ``n`` vehicles and an MLP of the given layer sizes."""
    return RolloutBuffers(np.empty(SLOT_COUNT, dtype=np.int64), np.empty(OBSERVATION_SIZE),
                          np.empty(OBSERVATION_SIZE, dtype=np.float32), np.empty(hidden0), np.empty(hidden1),
                          np.empty(outputs), workspace(n, lane_count))


@njit(cache=True, error_model="numpy")
def copy_scene(source, target, b):
    """target's scene b := source's scene b, every array of :data:`~srmpc.sim.state.StateArrays`."""
    target.vehicles[b] = source.vehicles[b]
    target.control[b] = source.control[b]
    target.crashed[b] = source.crashed[b]
    target.impact[b] = source.impact[b]
    target.has_impact[b] = source.has_impact[b]
    target.lane[b] = source.lane[b]
    target.target_lane[b] = source.target_lane[b]
    target.target_speed[b] = source.target_speed[b]
    target.delta[b] = source.delta[b]
    target.ego_rank[b] = source.ego_rank[b]
    target.steps[b] = source.steps[b]
    target.phi[b] = source.phi[b]
    target.rng[b] = source.rng[b]
    target.order[b] = source.order[b]


@njit(cache=True, error_model="numpy")
def rollout_scene_in(s, c, b, horizon, w0, b0, w1, b1, w2, b2, low, high, squash,
                     ego_out, action_out, cost_out, reward_out, terminated_out, others_out, record_others, buffers):
    """Scene b's MLP rollout (module doc) in place on ``s``, with preallocated ``buffers`` (sized for at least
    the scene's vehicles). The vehicle count is the scene's own (``s.vehicles.shape[1]``): a scene cut by
    ``srmpc.sim.local_rollout`` runs with the full scene's constants."""
    n = s.vehicles.shape[1]
    ego = n - 1
    slot_vehicle, raw, observation, h0, h1, z, work = buffers
    phi = measure(s, c, b, observation, slot_vehicle, raw)
    for t in range(horizon + 1):
        for i in range(4):
            ego_out[b, t, i] = s.vehicles[b, ego, i]
        if record_others:
            for k in range(n - 1):
                for i in range(4):
                    others_out[b, t, k, i] = s.vehicles[b, k, i]
        if t == horizon:
            break
        steering, acceleration = mlp_action(observation, w0, b0, w1, b1, w2, b2, low, high, squash, h0, h1, z)
        steering = min(max(steering, -c.steering_max), c.steering_max)
        acceleration = min(max(acceleration, c.acceleration_min), c.acceleration_max)
        action_out[b, t, 0] = steering
        action_out[b, t, 1] = acceleration
        simulate_in(s, c, b, steering, acceleration, work)
        phi_after = measure(s, c, b, observation, slot_vehicle, raw)
        cost_out[b, t] = safety_index_cost(phi, phi_after, c.si_eta, c.si_cost_floor)
        phi = phi_after
        x, y = s.vehicles[b, ego, X], s.vehicles[b, ego, Y]
        vx = s.vehicles[b, ego, SPEED] * np.cos(s.vehicles[b, ego, HEADING])
        reward_out[b, t] = reward_prime(vx, y, c.vx_ref, c.y_ref, c.speed_weight)
        terminated_out[b, t] = s.crashed[b, ego] or not on_lane(x, y, s.lane[b, ego], c.lane_width, c.road_length, 0.0)
    s.phi[b] = phi


@njit(cache=True, error_model="numpy")
def _empty_like(s):
    """Uninitialized :data:`~srmpc.sim.state.StateArrays` of the same shapes and dtypes as ``s``."""
    return StateArrays(np.empty_like(s.vehicles), np.empty_like(s.control), np.empty_like(s.crashed),
                       np.empty_like(s.impact), np.empty_like(s.has_impact), np.empty_like(s.lane),
                       np.empty_like(s.target_lane), np.empty_like(s.target_speed), np.empty_like(s.delta),
                       np.empty_like(s.ego_rank), np.empty_like(s.steps), np.empty_like(s.phi), np.empty_like(s.rng),
                       np.empty_like(s.order))


@njit(cache=True, error_model="numpy")
def _rollout_outputs(scenes, horizon, vehicles, record_others):
    """The :class:`Rollout` arrays (ego, actions, cost, r', terminated, others); others is a (1, 1, 1, 4)
    placeholder unless ``record_others``."""
    others_shape = (scenes, horizon + 1, vehicles - 1, 4) if record_others else (1, 1, 1, 4)
    return (np.empty((scenes, horizon + 1, 4)), np.empty((scenes, horizon, 2)), np.empty((scenes, horizon)),
            np.empty((scenes, horizon)), np.zeros((scenes, horizon), dtype=np.bool_), np.empty(others_shape))


@njit(cache=True, error_model="numpy")
def _rollout_mlp_serial(source, c, horizon, w0, b0, w1, b1, w2, b2, low, high, squash, record_others):
    """Every scene of ``source`` (not modified: each scene is copied into a work state first), one after the
    other; the work state, the buffers and the outputs are allocated once per call. Returns the
    :func:`_rollout_outputs` tuple."""
    scenes, vehicles = source.vehicles.shape[0], source.vehicles.shape[1]
    ego_out, action_out, cost_out, reward_out, terminated_out, others_out = outputs = _rollout_outputs(
        scenes, horizon, vehicles, record_others)
    work = _empty_like(source)
    buffers = rollout_buffers(vehicles, c.lane_count, w0.shape[1], w1.shape[1], w2.shape[1])
    for b in range(scenes):
        copy_scene(source, work, b)
        rollout_scene_in(work, c, b, horizon, w0, b0, w1, b1, w2, b2, low, high, squash,
                         ego_out, action_out, cost_out, reward_out, terminated_out, others_out, record_others, buffers)
    return outputs


@njit(cache=True, parallel=True, error_model="numpy")
def _rollout_mlp_parallel(source, c, horizon, w0, b0, w1, b1, w2, b2, low, high, squash, record_others):
    """:func:`_rollout_mlp_serial` with the scenes spread over numba's threads (buffers per scene)."""
    scenes, vehicles = source.vehicles.shape[0], source.vehicles.shape[1]
    ego_out, action_out, cost_out, reward_out, terminated_out, others_out = outputs = _rollout_outputs(
        scenes, horizon, vehicles, record_others)
    work = _empty_like(source)
    for b in prange(scenes):
        copy_scene(source, work, b)
        buffers = rollout_buffers(vehicles, c.lane_count, w0.shape[1], w1.shape[1], w2.shape[1])
        rollout_scene_in(work, c, b, horizon, w0, b0, w1, b1, w2, b2, low, high, squash,
                         ego_out, action_out, cost_out, reward_out, terminated_out, others_out, record_others, buffers)
    return outputs


def rollout(
    state: SceneState,
    constants: SimConstants,
    policy: Callable[[np.ndarray], np.ndarray] | MlpPolicy,
    horizon: int,
    record_others: bool = False,
    parallel: bool | None = None,
) -> Rollout:
    """Roll ``policy`` out for ``horizon`` steps from every scene of ``state`` (which is not modified).

    ``parallel``: spread scenes over numba's threads (default: when there are >= 16 scenes per thread).
    """
    if horizon < 1:
        raise ValueError(f"horizon={horizon}: must be >= 1")
    scenes, vehicles = state.scenes, state.vehicle_count
    if parallel is None:
        parallel = numba.get_num_threads() > 1 and scenes >= 16 * numba.get_num_threads()
    if isinstance(policy, MlpPolicy) and len(policy.weights) == 3:
        kernel = _rollout_mlp_parallel if parallel else _rollout_mlp_serial
        (w0, w1, w2), (b0, b1, b2), low, high, squash = policy.packed
        ego, actions, cost, reward, terminated, others = kernel(state.arrays(), constants, horizon, w0, b0, w1, b1,
                                                                w2, b2, low, high, squash, record_others)
        return Rollout(ego, actions, cost, reward, terminated, others if record_others else None)
    work = state.copy()
    result = Rollout(
        ego=np.empty((scenes, horizon + 1, 4)),
        actions=np.empty((scenes, horizon, 2)),
        cost=np.empty((scenes, horizon)),
        reward_prime=np.empty((scenes, horizon)),
        terminated=np.zeros((scenes, horizon), dtype=np.bool_),
        others=np.empty((scenes, horizon + 1, vehicles - 1, 4)) if record_others else None,
    )
    out = engine.allocate_outputs(scenes)
    observation = np.empty((scenes, OBSERVATION_SIZE), dtype=np.float32)
    engine.observe(work.arrays(), constants, observation, np.empty(scenes))
    low = np.array([-constants.steering_max, constants.acceleration_min])
    high = np.array([constants.steering_max, constants.acceleration_max])
    kernel = engine.step_parallel if parallel else engine.step_serial
    for t in range(horizon):
        result.ego[:, t] = work.vehicles[:, -1]
        if record_others:
            result.others[:, t] = work.vehicles[:, :-1]
        actions = np.clip(np.asarray(policy(observation), dtype=np.float64).reshape(scenes, 2), low, high)
        result.actions[:, t] = actions
        kernel(work.arrays(), constants, out, np.ascontiguousarray(actions), False)
        observation = out.observation
        result.cost[:, t] = out.cost
        result.reward_prime[:, t] = out.reward_prime
        result.terminated[:, t] = out.terminated
    result.ego[:, horizon] = work.vehicles[:, -1]
    if record_others:
        result.others[:, horizon] = work.vehicles[:, :-1]
    return result
