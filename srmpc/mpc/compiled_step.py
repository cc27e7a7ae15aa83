"""The planner's default step as one compiled call: SRMPC's (Algorithm 1, steps 2-3) and LTV-MPC's.

One numba function per step runs, without returning to Python in between and in arrays allocated once
(:class:`CompiledPlannerStep`):

1. the linearization reference (x^r, u^r): SRMPC -- a copy of the live scene (``local``: cut to the vehicles
   that can matter within the horizon, ``srmpc.sim.local_rollout.local_arrays``, in the same call) and the
   policy's N-step rollout in the twin, MLP and simulator in one kernel (``srmpc.sim.rollout.rollout_scene_in``);
   LTV-MPC -- the previous plan shifted and rolled out through the exact model, else lane following
   (``LtvMpcPlanner.default_reference``); x^r_0 = the measured state;
2. the QP update: constant-velocity prediction of the observed vehicles, the exact-model Jacobians
   along (x^r, u^r) and the linearized collision rows (``LtvMpcQp.update``'s kernels, into the QP's own
   stage-wise arrays);
3. the solve: ``riccati_ipm`` warm-started from the shifted previous solution
   (``solvers.ipm_start``), then the planner's acceptance test (finite, first input within its
   box up to ``INPUT_BOUND_TOLERANCE``) and the clip of the inputs into their box.

These are the same kernels, in the same order, as the Python path (``LtvMpcPlanner.solve_about``):
with the warm start off both give bit-identical plans (``tests/mpc/test_compiled_step.py``). What is
not the default path stays on Python: other solvers, predictors and SRMPC variants, and every fallback
(rollout failure, no QP solved).

Each stage's duration is read from the CPU's cycle counter (``llvm.readcyclecounter``) into
``StepArrays.cycles`` and converted to microseconds once per step in Python (``cycles_to_us``).
"""

from __future__ import annotations

import time
from collections import namedtuple

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from srmpc.mpc.problem import (
    constant_velocity_rollout,
    linearize_collision_constraints,
    linearize_horizon,
    rollout_horizon,
)
from srmpc.mpc.solvers import STATUS_NAMES, STATUS_SOLVED, qp_tuple, solve_in
from srmpc.sim.local_rollout import LEADER_DEPTH, horizon_seconds, local_arrays
from srmpc.sim.rollout import copy_scene, rollout_buffers, rollout_scene_in

STEP_SOLVED = 0
"""The QP was solved and its plan accepted."""
STEP_NOT_SOLVED = 1
"""The solver did not reach its tolerance (status in the result)."""
STEP_REJECTED = 2
"""Solved, but non-finite or the first input outside its box (the planner's acceptance test)."""
STEP_ROLLOUT_FAILED = 3
"""SRMPC: the policy's rollout produced a non-finite value (no QP was built)."""

StepArrays = namedtuple("StepArrays", [
    "measured_state", "last_input", "tracking_reference", "linearization_states", "linearization_inputs",
    "next_states", "state_matrices", "input_matrices", "affine_offsets", "observed_others",
    "predicted_others", "coefficients", "row_lower", "sigma_upper", "critical_circle", "cycles"])
"""The step's arrays: x_hat (4,), u_hat (2,), x^ref (N + 1, 4), x^r (N + 1, 4), u^r (N, 2), then the QP's
stage-wise arrays (``LtvMpcQp``: f (N, 4), A (N, 4, 4), B (N, 4, 2), c (N, 4)), the observed vehicles (V, 4)
and their prediction (N + 1, V, 4), the collision rows (N, V, 3), (N, V), (N, V), (N, V) int; cycles (3,)
uint64 of the last step's stages (reference/rollout, QP update, solve)."""

StepConstants = namedtuple("StepConstants", [
    "model", "control_period_s", "lane_centres_m", "circle_offsets_m", "collision_semi_axes_m",
    "safety_semi_axes_m", "input_lower", "input_upper", "input_tolerance", "solver", "tolerance",
    "max_iterations", "warm_start", "warm_start_settings"])
"""The OCP's constants: the bicycle's (h, substeps, l / 2, v_max, v_min), dt, lane centres, the collision
geometry, the input box and its tolerance, ``solvers.SolverConstants``, and the solver's settings."""


@intrinsic
def _read_cycle_counter(typingctx):
    """The CPU's cycle counter (``llvm.readcyclecounter``; rdtsc on x86-64, 0 where absent)."""
    def codegen(context, builder, signature, args):
        function = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(64), []),
                                                  "llvm.readcyclecounter")
        return builder.call(function, [])
    return types.uint64(), codegen


@numba.njit(cache=True)
def read_cycle_counter():
    """The cycle counter, callable from Python (for ``cycles_to_us``'s calibration)."""
    return _read_cycle_counter()


_CYCLES_PER_US: list[float] = []


def cycles_to_us(cycles: np.ndarray) -> np.ndarray:
    """Cycle counts in microseconds (the counter's rate measured once, over 20 ms of wall time)."""
    if not _CYCLES_PER_US:
        read_cycle_counter()
        start_cycles, start = read_cycle_counter(), time.perf_counter()
        while time.perf_counter() - start < 0.02:
            pass
        rate = (read_cycle_counter() - start_cycles) / ((time.perf_counter() - start) * 1e6)
        _CYCLES_PER_US.append(rate if rate > 0 else np.inf)
    return cycles.astype(np.float64) / _CYCLES_PER_US[0]


@numba.njit(cache=True, error_model="numpy")
def _set_measurement(arrays, ego, last_input, tracking_reference):
    """x_hat, u_hat and x^ref into the step's arrays."""
    for i in range(4):
        arrays.measured_state[i] = ego[i]
    arrays.last_input[0] = last_input[0]
    arrays.last_input[1] = last_input[1]
    arrays.tracking_reference[:, :] = tracking_reference


@numba.njit(cache=True, error_model="numpy")
def _observe(arrays, others, slot_vehicle):
    """The observed vehicles others[slot_vehicle[s]] (slots in order, empty ones skipped); returns V_obs."""
    n_observed = 0
    for slot in range(slot_vehicle.shape[0]):
        if slot_vehicle[slot] >= 0:
            arrays.observed_others[n_observed] = others[slot_vehicle[slot]]
            n_observed += 1
    return n_observed


@numba.njit(cache=True, error_model="numpy")
def _lane_following(arrays, constants):
    """``LtvMpcPlanner.lane_following_reference``: x^r_k = (x + v dt k, y_lane, 0, v), u^r = 0."""
    ego = arrays.measured_state
    states = arrays.linearization_states
    centres = constants.lane_centres_m
    lane = centres[0]
    for centre in centres:
        if abs(centre - ego[1]) < abs(lane - ego[1]):
            lane = centre
    speed = ego[3]
    step_m = speed * constants.control_period_s
    for k in range(states.shape[0]):
        states[k, 0] = ego[0] + step_m * k
        states[k, 1] = lane
        states[k, 2] = 0.0
        states[k, 3] = speed
    states[0] = ego
    arrays.linearization_inputs[:, :] = 0.0


@numba.njit(cache=True, error_model="numpy")
def _shifted_previous(arrays, constants, previous_inputs, shift):
    """``LtvMpcPlanner.default_reference``: u^r = the previous inputs advanced by ``shift``, x^r their
    exact-model rollout from x_hat."""
    inputs = arrays.linearization_inputs
    horizon = inputs.shape[0]
    for k in range(horizon):
        source = min(k + shift, horizon - 1)
        inputs[k, 0] = previous_inputs[source, 0]
        inputs[k, 1] = previous_inputs[source, 1]
    h, substeps, half_length, v_max, v_min = constants.model
    rollout_horizon(arrays.measured_state, inputs, h, substeps, half_length, v_max, v_min,
                    arrays.linearization_states)


@numba.njit(cache=True, error_model="numpy")
def _update_qp(arrays, constants, n_observed):
    """``LtvMpcQp.update``'s kernels on the step's arrays (x^r_0 := x_hat first)."""
    arrays.linearization_states[0] = arrays.measured_state
    h, substeps, half_length, v_max, v_min = constants.model
    linearize_horizon(arrays.linearization_states, arrays.linearization_inputs, h, substeps, half_length,
                      v_max, v_min, arrays.next_states, arrays.state_matrices, arrays.input_matrices,
                      arrays.affine_offsets)
    horizon = arrays.linearization_inputs.shape[0]
    constant_velocity_rollout(arrays.observed_others[:n_observed], horizon, constants.control_period_s,
                              arrays.predicted_others)
    linearize_collision_constraints(arrays.linearization_states, arrays.predicted_others, n_observed,
                                    constants.circle_offsets_m, constants.collision_semi_axes_m,
                                    constants.safety_semi_axes_m, arrays.coefficients, arrays.row_lower,
                                    arrays.sigma_upper, arrays.critical_circle)


@numba.njit(cache=True, error_model="numpy")
def _solve(arrays, constants, n_observed, workspace, memory):
    """The warm-started solve and the planner's acceptance test: (step outcome, solver status, iterations,
    started warm); an accepted plan's inputs are clipped into their box in ``workspace[0]``."""
    c = constants.solver
    qp = qp_tuple(arrays.last_input, arrays.state_matrices, arrays.input_matrices, arrays.affine_offsets,
                  arrays.tracking_reference, arrays.coefficients, arrays.row_lower, arrays.sigma_upper,
                  n_observed, c.state_weight_hessian, c.input_weight_hessian, c.rate_hessian, c.slack_weights,
                  c.bounds)
    status, iterations, started_warm = solve_in(
        arrays.measured_state, qp, arrays.linearization_inputs, constants.tolerance, constants.max_iterations,
        workspace, memory, constants.warm_start, constants.warm_start_settings)
    if status != STATUS_SOLVED:
        return STEP_NOT_SOLVED, status, iterations, started_warm
    point = workspace[0]
    finite = (np.isfinite(point.states).all() and np.isfinite(point.inputs).all()
              and np.isfinite(point.slacks).all() and np.isfinite(point.sigmas).all())
    lower, upper, tolerance = constants.input_lower, constants.input_upper, constants.input_tolerance
    for i in range(2):
        if not lower[i] - tolerance <= point.inputs[0, i] <= upper[i] + tolerance:
            finite = False
    if not finite:
        memory.valid[0] = False
        return STEP_REJECTED, status, iterations, started_warm
    for k in range(point.inputs.shape[0]):
        for i in range(2):
            point.inputs[k, i] = min(max(point.inputs[k, i], lower[i]), upper[i])
    return STEP_SOLVED, status, iterations, started_warm


@numba.njit(cache=True, error_model="numpy")
def ltv_mpc_step(arrays, constants, workspace, memory, ego, others, last_input, tracking_reference,
                 previous_inputs, shift):
    """LTV-MPC's planner step (module doc): about the previous inputs advanced by ``shift`` (0: lane
    following); ``others`` (V_obs, 4) the observed vehicles.  Returns ``_solve``'s tuple."""
    start = _read_cycle_counter()
    _set_measurement(arrays, ego, last_input, tracking_reference)
    n_observed = others.shape[0]
    for j in range(n_observed):
        arrays.observed_others[j] = others[j]
    if shift > 0:
        _shifted_previous(arrays, constants, previous_inputs, shift)
    else:
        _lane_following(arrays, constants)
    referenced = _read_cycle_counter()
    _update_qp(arrays, constants, n_observed)
    updated = _read_cycle_counter()
    result = _solve(arrays, constants, n_observed, workspace, memory)
    arrays.cycles[0] = referenced - start
    arrays.cycles[1] = updated - referenced
    arrays.cycles[2] = _read_cycle_counter() - updated
    return result


@numba.njit(cache=True, error_model="numpy")
def _policy_rollout(scene, scene_copy, sim_constants, policy, rollout, local, horizon_s, leader_depth):
    """The policy's rollout (``rollout``'s arrays) from a copy of ``scene`` (scene 0): the whole scene into
    ``scene_copy``, or with ``local`` its cut to the horizon (``local_arrays``, its leader chains
    ``leader_depth`` deep, on the rollout's work buffers). ``rollout``'s ``kept`` := the simulated vehicles'
    storage indices in the full scene (ascending, the ego last), -1 after them; returns their count."""
    w0, b0, w1, b1, w2, b2, low, high, squash = policy
    ego_out, action_out, cost_out, reward_out, terminated_out, others_out, buffers, kept_out = rollout
    horizon = action_out.shape[1]
    if local:
        reduced, kept = local_arrays(scene, sim_constants, 0, horizon_s, leader_depth, buffers.work)
        rollout_scene_in(reduced, sim_constants, 0, horizon, w0, b0, w1, b1, w2, b2, low, high, squash,
                         ego_out, action_out, cost_out, reward_out, terminated_out, others_out, False, buffers)
        count = kept.shape[0]
        kept_out[:count] = kept
    else:
        copy_scene(scene, scene_copy, 0)
        rollout_scene_in(scene_copy, sim_constants, 0, horizon, w0, b0, w1, b1, w2, b2, low, high, squash,
                         ego_out, action_out, cost_out, reward_out, terminated_out, others_out, False, buffers)
        count = kept_out.shape[0]
        for k in range(count):
            kept_out[k] = k
    kept_out[count:] = -1
    return count


@numba.njit(cache=True, error_model="numpy")
def srmpc_step(arrays, constants, workspace, memory, scene, scene_copy, sim_constants, policy, rollout,
               ego, others, slot_vehicle, last_input, tracking_reference, local, horizon_s, leader_depth):
    """SRMPC's step (Algorithm 1, steps 2-3; module doc): the policy's rollout from a copy of ``scene``
    (``policy`` = ``MlpPolicy.packed`` flattened, ``rollout`` = (ego, actions, cost, reward', terminated,
    others, buffers, kept) arrays of one scene; ``local``, ``horizon_s`` [s], ``leader_depth``: the scene cut to
    the horizon, :func:`_policy_rollout`), then the QP about it.  Returns ``_solve``'s tuple
    (``STEP_ROLLOUT_FAILED`` if the rollout is not finite).  The QP's prediction of the observed vehicles is
    constant velocity from ``others`` (the live scene), so no vehicle the cut dropped needs one here."""
    start = _read_cycle_counter()
    _set_measurement(arrays, ego, last_input, tracking_reference)
    _policy_rollout(scene, scene_copy, sim_constants, policy, rollout, local, horizon_s, leader_depth)
    ego_out, action_out = rollout[0], rollout[1]
    referenced = _read_cycle_counter()
    arrays.cycles[0] = referenced - start
    arrays.cycles[1] = 0
    arrays.cycles[2] = 0
    if not (np.isfinite(ego_out).all() and np.isfinite(action_out).all()):
        return STEP_ROLLOUT_FAILED, -1, 0, False
    arrays.linearization_states[:, :] = ego_out[0]
    arrays.linearization_inputs[:, :] = action_out[0]
    n_observed = _observe(arrays, others, slot_vehicle)
    _update_qp(arrays, constants, n_observed)
    updated = _read_cycle_counter()
    result = _solve(arrays, constants, n_observed, workspace, memory)
    arrays.cycles[1] = updated - referenced
    arrays.cycles[2] = _read_cycle_counter() - updated
    return result


def status_name(status: int) -> str:
    """The solver status text of a step's status code (``STATUS_NAMES``; -1: no QP)."""
    return STATUS_NAMES.get(int(status), "no policy reference")


class CompiledPlannerStep:
    """The compiled step's arrays for one planner, allocated once: its QP's stage-wise arrays and its
    ``riccati_ipm`` solver's workspace and warm-start memory (shared with the solver's Python path).

    Args:
        planner: an ``LtvMpcPlanner`` whose solver is a ``RiccatiInteriorPointSolver``.
        input_tolerance: the planner's ``INPUT_BOUND_TOLERANCE``.
    """

    def __init__(self, planner, input_tolerance: float) -> None:
        qp, solver, config = planner.qp, planner.solver, planner.config
        solver.bind(qp)
        self.qp, self.solver = qp, solver
        horizon, n_slots = config.horizon, config.max_vehicles
        self.arrays = StepArrays(
            qp.measured_state, qp.last_input, qp.tracking_reference, np.zeros((horizon + 1, 4)),
            qp.linearization_inputs, qp.next_states, qp.state_matrices, qp.input_matrices, qp.affine_offsets,
            np.zeros((n_slots, 4)), np.zeros((horizon + 1, n_slots, 4)), qp.collision_coefficients,
            qp.collision_row_lower, qp.safety_slack_upper, qp.critical_circle, np.zeros(3, dtype=np.uint64))
        self.constants = StepConstants(
            tuple(planner.model.kernel_args), float(config.control_period_s),
            np.asarray(planner.lane_centres_m, dtype=np.float64), qp.circle_offsets_m,
            np.asarray(qp.collision_semi_axes_m, dtype=np.float64), np.asarray(qp.safety_semi_axes_m, dtype=np.float64),
            planner.input_lower, planner.input_upper, float(input_tolerance), solver.constants,
            solver.tolerance, solver.max_iterations, solver.warm_start, tuple(solver.warm_start_settings))
        self._rollout_arrays: dict = {}

    def _finish(self, result: tuple, n_observed: int) -> tuple[int, int, int, bool]:
        """Mark the QP's values as changed (its sparse forms resync on access) and return the result."""
        self.qp.n_observed = n_observed
        self.qp.stagewise_data_changed()
        self.solver.last_started_warm = bool(result[3])
        return int(result[0]), int(result[1]), int(result[2]), bool(result[3])

    def ltv_mpc(self, ego, others, last_input, tracking_reference, previous_inputs, shift):
        """``ltv_mpc_step``; returns (step outcome, solver status, iterations, started warm)."""
        result = ltv_mpc_step(self.arrays, self.constants, self.solver.workspace, self.solver.memory, ego,
                              others, last_input, tracking_reference, previous_inputs, shift)
        return self._finish(result, others.shape[0])

    def rollout_arrays(self, scene, sim_constants, policy) -> tuple:
        """(scene copy, rollout outputs) for scenes like ``scene`` and this policy, allocated once."""
        (w0, w1, w2), _, _, _, _ = policy.packed
        key = (scene.vehicle_count, w0.shape, w1.shape, w2.shape)
        if key not in self._rollout_arrays:
            horizon = self.arrays.linearization_inputs.shape[0]
            self._rollout_arrays.clear()
            self._rollout_arrays[key] = (scene.take([0]).arrays(), (
                np.empty((1, horizon + 1, 4)), np.empty((1, horizon, 2)), np.empty((1, horizon)),
                np.empty((1, horizon)), np.zeros((1, horizon), dtype=np.bool_), np.empty((1, 1, 1, 4)),
                rollout_buffers(scene.vehicle_count, sim_constants.lane_count, w0.shape[1], w1.shape[1],
                                w2.shape[1]), np.full(scene.vehicle_count, -1, dtype=np.int64)))
        return self._rollout_arrays[key]

    def srmpc(self, scene, sim_constants, policy, ego, others, slot_vehicle, last_input, tracking_reference,
              local: bool = False, leader_depth: int = LEADER_DEPTH):
        """``srmpc_step`` from ``scene`` (a ``SceneState``, scene 0) with ``policy`` (a 2-hidden-layer
        ``MlpPolicy``), on the whole scene or (``local``) its cut to the horizon with leader chains
        ``leader_depth`` deep; returns (step outcome, solver status, iterations, started warm)."""
        scene_copy, rollout = self.rollout_arrays(scene, sim_constants, policy)
        (w0, w1, w2), (b0, b1, b2), low, high, squash = policy.packed
        horizon_s = horizon_seconds(self.arrays.linearization_inputs.shape[0], sim_constants)
        result = srmpc_step(self.arrays, self.constants, self.solver.workspace, self.solver.memory,
                            scene.arrays(), scene_copy, sim_constants,
                            (w0, b0, w1, b1, w2, b2, low, high, squash), rollout, ego, others, slot_vehicle,
                            last_input, tracking_reference, bool(local), float(horizon_s), int(leader_depth))
        return self._finish(result, int(np.count_nonzero(slot_vehicle >= 0)))

    def last_rollout(self) -> tuple[np.ndarray, ...]:
        """The last SRMPC step's rollout outputs (ego, actions, cost, r', terminated), views of (1, ...) arrays."""
        return next(iter(self._rollout_arrays.values()))[1][:5]

    def last_kept(self) -> np.ndarray:
        """The last SRMPC step's simulated vehicles: their storage indices in the full scene, the ego last (a copy)."""
        kept = next(iter(self._rollout_arrays.values()))[1][7]
        return kept[kept >= 0].copy()

    def plan_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Copies of the last solution: states (N + 1, 4), inputs (N, 2), slacks (V,), sigmas (N, V)."""
        point = self.solver.workspace[0]
        return point.states.copy(), point.inputs.copy(), point.slacks.copy(), point.sigmas.copy()

    def stage_us(self) -> np.ndarray:
        """The last step's (reference or rollout, QP update, solve) durations [us]."""
        return cycles_to_us(self.arrays.cycles)
