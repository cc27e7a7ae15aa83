"""Ego prediction model: highway-env's kinematic bicycle, discretised exactly as the plant runs it.

Continuous model (the paper's eq. kin_1spur with l_r = l / 2, highway-env ``Vehicle.step``)::

    beta      = arctan(0.5 tan(delta))
    x_dot     = v cos(psi + beta)
    y_dot     = v sin(psi + beta)
    psi_dot   = v sin(beta) / (l / 2)
    v_dot     = a_eff,   a_eff = min(a, v_max - v) if v > v_max
                               = max(a, v_min - v) if v < v_min
                               = a                 otherwise

State ``x = (x [m], y [m], psi [rad], v [m/s])``, input ``u = (delta [rad], a [m/s^2])``.

The plant applies one control for ``dt = 0.2 s`` and integrates it with ``n_substeps = 3``
explicit-Euler sub-steps of ``dt / n_substeps = 1/15 s``.  The discrete prediction model is the
composition of those sub-steps,

    f(x, u) = g(g(g(x, u), u), u),   g(x, u) = x + h * x_dot(x, u),   h = dt / n_substeps,

and its Jacobians follow from the chain rule,

    A = J_x g_3 J_x g_2 J_x g_1,   B = J_x g_3 (J_x g_2 J_u g_1 + J_u g_2) + J_u g_3,

which are exact (up to round-off) for this map, including the speed-clipping branch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from srmpc.scenario.road import MAX_SPEED, VEHICLE_LENGTH, VEHICLE_WIDTH

STATE_DIM = 4
"""(x [m], y [m], heading psi [rad], speed v [m/s])"""
INPUT_DIM = 2
"""(steering delta [rad], acceleration a [m/s^2])"""
LATERAL_INDEX = 1
"""Index of the lateral position y [m] in the state x."""
SPEED_INDEX = 3
"""Index of the speed v [m/s] in the state x."""

VEHICLE_LENGTH_M = VEHICLE_LENGTH
"""Ego length [m] (the scenario's, highway-env ``Vehicle.LENGTH``)."""
VEHICLE_WIDTH_M = VEHICLE_WIDTH
"""Ego width [m]."""
MAX_SPEED_MPS = MAX_SPEED
"""Speed above which the plant clips acceleration [m/s]."""
MIN_SPEED_MPS = -MAX_SPEED
"""Speed below which the plant clips acceleration [m/s] (highway-env: -MAX_SPEED)."""
CONTROL_PERIOD_S = 0.2
"""Control period dt [s] (policy frequency 5 Hz)."""
SUBSTEPS_PER_CONTROL = 3
"""Explicit-Euler plant sub-steps per control period (simulation frequency 15 Hz)."""


@dataclass(frozen=True)
class BicycleParameters:
    """Parameters of the discrete kinematic bicycle.

    Attributes:
        length_m: vehicle length l [m]; the rear axle-to-centre distance is l / 2.
        control_period_s: duration dt [s] for which one input is held.
        n_substeps: explicit-Euler sub-steps per control period (each dt / n_substeps [s]).
        max_speed_mps: speed above which the acceleration is clipped [m/s].
        min_speed_mps: speed below which the acceleration is clipped [m/s].
    """

    length_m: float = VEHICLE_LENGTH_M
    control_period_s: float = CONTROL_PERIOD_S
    n_substeps: int = SUBSTEPS_PER_CONTROL
    max_speed_mps: float = MAX_SPEED_MPS
    min_speed_mps: float = MIN_SPEED_MPS

    @property
    def substep_s(self) -> float:
        """Sub-step length h = dt / n_substeps [s]."""
        return self.control_period_s / self.n_substeps


@numba.njit(cache=True)
def _substep_with_jacobians(state, steering, acceleration, h, half_length, v_max, v_min,
                            out_state, jac_state, jac_input):
    """One Euler sub-step g(x, u) = x + h x_dot(x, u); writes g, dg/dx (4x4), dg/du (4x2)."""
    px, py, psi, v = state[0], state[1], state[2], state[3]
    tan_delta = np.tan(steering)
    beta = np.arctan(0.5 * tan_delta)
    # d beta / d delta = 0.5 sec^2(delta) / (1 + 0.25 tan^2(delta))
    dbeta = 0.5 * (1.0 + tan_delta * tan_delta) / (1.0 + 0.25 * tan_delta * tan_delta)
    course = psi + beta
    cos_c = np.cos(course)
    sin_c = np.sin(course)
    sin_b = np.sin(beta)
    cos_b = np.cos(beta)
    accel = acceleration
    daccel_dv = 0.0
    daccel_da = 1.0
    if v > v_max and accel > v_max - v:
        accel = v_max - v
        daccel_dv = -1.0
        daccel_da = 0.0
    elif v < v_min and accel < v_min - v:
        accel = v_min - v
        daccel_dv = -1.0
        daccel_da = 0.0
    out_state[0] = px + h * v * cos_c
    out_state[1] = py + h * v * sin_c
    out_state[2] = psi + h * v * sin_b / half_length
    out_state[3] = v + h * accel
    for i in range(4):
        for j in range(4):
            jac_state[i, j] = 0.0
        jac_input[i, 0] = 0.0
        jac_input[i, 1] = 0.0
        jac_state[i, i] = 1.0
    jac_state[0, 2] = -h * v * sin_c
    jac_state[0, 3] = h * cos_c
    jac_state[1, 2] = h * v * cos_c
    jac_state[1, 3] = h * sin_c
    jac_state[2, 3] = h * sin_b / half_length
    jac_state[3, 3] = 1.0 + h * daccel_dv
    jac_input[0, 0] = -h * v * sin_c * dbeta
    jac_input[1, 0] = h * v * cos_c * dbeta
    jac_input[2, 0] = h * v * cos_b * dbeta / half_length
    jac_input[3, 1] = h * daccel_da


@numba.njit(cache=True)
def _discrete_step_with_jacobians(state, control, h, n_substeps, half_length, v_max, v_min,
                                  out_state, transition_state_matrix, transition_input_matrix):
    """Compose n_substeps sub-steps; accumulate A and B by the chain rule.

    Explicit loops on 4x4 blocks (no temporaries, no BLAS calls: this runs N times a step).
    """
    current = np.empty(4)
    nxt = np.empty(4)
    jx = np.empty((4, 4))
    ju = np.empty((4, 2))
    product = np.empty((4, 4))
    product_input = np.empty((4, 2))
    for i in range(4):
        current[i] = state[i]
        for j in range(4):
            transition_state_matrix[i, j] = 1.0 if i == j else 0.0
        transition_input_matrix[i, 0] = 0.0
        transition_input_matrix[i, 1] = 0.0
    for _ in range(n_substeps):
        _substep_with_jacobians(current, control[0], control[1], h, half_length, v_max, v_min,
                                nxt, jx, ju)
        # A <- Jx A,  B <- Jx B + Ju
        for i in range(4):
            for j in range(4):
                acc = 0.0
                for t in range(4):
                    acc += jx[i, t] * transition_state_matrix[t, j]
                product[i, j] = acc
            for j in range(2):
                acc = ju[i, j]
                for t in range(4):
                    acc += jx[i, t] * transition_input_matrix[t, j]
                product_input[i, j] = acc
        for i in range(4):
            for j in range(4):
                transition_state_matrix[i, j] = product[i, j]
            transition_input_matrix[i, 0] = product_input[i, 0]
            transition_input_matrix[i, 1] = product_input[i, 1]
            current[i] = nxt[i]
    for i in range(4):
        out_state[i] = current[i]


@numba.njit(cache=True)
def linearize_horizon(states, controls, h, n_substeps, half_length, v_max, v_min,
                      next_states, state_matrices, input_matrices, affine_offsets):
    """Per stage: f(x_k, u_k), A_k, B_k and c_k = f(x_k, u_k) - A_k x_k - B_k u_k, the model's arguments
    (h, n_substeps, l / 2, v_max, v_min) as in ``KinematicBicycle.kernel_args``."""
    for k in range(controls.shape[0]):
        _discrete_step_with_jacobians(states[k], controls[k], h, n_substeps, half_length, v_max,
                                      v_min, next_states[k], state_matrices[k],
                                      input_matrices[k])
        for i in range(4):
            offset = next_states[k, i]
            for j in range(4):
                offset -= state_matrices[k, i, j] * states[k, j]
            for j in range(2):
                offset -= input_matrices[k, i, j] * controls[k, j]
            affine_offsets[k, i] = offset


@numba.njit(cache=True)
def rollout_horizon(initial_state, controls, h, n_substeps, half_length, v_max, v_min, states):
    """States x_0..x_N (N + 1, 4) into ``states`` from x_0 under the inputs u_0..u_{N-1} (N, 2), the model's
    arguments as in ``KinematicBicycle.kernel_args``."""
    states[0] = initial_state
    jx = np.empty((4, 4))
    ju = np.empty((4, 2))
    current = initial_state.copy()
    nxt = np.empty(4)
    for k in range(controls.shape[0]):
        for _ in range(n_substeps):
            _substep_with_jacobians(current, controls[k, 0], controls[k, 1], h, half_length,
                                    v_max, v_min, nxt, jx, ju)
            current[:] = nxt
        states[k + 1] = current


def _as_float_array(values, shape_tail: tuple[int, ...]) -> np.ndarray:
    array = np.ascontiguousarray(values, dtype=np.float64)
    if array.shape[-len(shape_tail):] != shape_tail:
        raise ValueError(f"expected trailing shape {shape_tail}, got {array.shape}")
    return array


class KinematicBicycle:
    """Discrete kinematic bicycle f(x, u) composed of explicit-Euler sub-steps (see module doc)."""

    def __init__(self, parameters: BicycleParameters | None = None) -> None:
        self.parameters = parameters or BicycleParameters()
        p = self.parameters
        self.kernel_args = (p.substep_s, p.n_substeps, p.length_m / 2.0, p.max_speed_mps,
                            p.min_speed_mps)
        """The compiled kernels' model arguments (h, n_substeps, l / 2, v_max, v_min) (``linearize_horizon``,
        ``rollout_horizon``)."""

    def step(self, state: np.ndarray, control: np.ndarray) -> np.ndarray:
        """x_{k+1} = f(x_k, u_k) for one control period; shape (4,)."""
        next_state, _, _ = self.step_with_jacobians(state, control)
        return next_state

    def step_with_jacobians(
        self, state: np.ndarray, control: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (f(x, u), A = df/dx (4x4), B = df/du (4x2))."""
        state = _as_float_array(state, (STATE_DIM,))
        control = _as_float_array(control, (INPUT_DIM,))
        next_state = np.empty(STATE_DIM)
        transition_state_matrix = np.empty((STATE_DIM, STATE_DIM))
        transition_input_matrix = np.empty((STATE_DIM, INPUT_DIM))
        _discrete_step_with_jacobians(state, control, *self.kernel_args, next_state,
                                      transition_state_matrix, transition_input_matrix)
        return next_state, transition_state_matrix, transition_input_matrix

    def linearize(
        self,
        states: np.ndarray,
        controls: np.ndarray,
        next_states: np.ndarray | None = None,
        state_matrices: np.ndarray | None = None,
        input_matrices: np.ndarray | None = None,
        affine_offsets: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Linearize along a trajectory: x_{k+1} ~= A_k x_k + B_k u_k + c_k for k < N.

        Returns (f(x^r_k, u^r_k), A_k, B_k, c_k = f(x^r_k, u^r_k) - A_k x^r_k - B_k u^r_k).

        Args:
            states: (>= N, 4) linearization states x_k^r (only the first N are used).
            controls: (N, 2) linearization inputs u_k^r.
            next_states, state_matrices, input_matrices, affine_offsets: optional output
                buffers of shapes (N, 4), (N, 4, 4), (N, 4, 2), (N, 4), written in place.
        """
        controls = _as_float_array(controls, (INPUT_DIM,))
        states = _as_float_array(states, (STATE_DIM,))
        horizon = controls.shape[0]
        if next_states is None:
            next_states = np.empty((horizon, STATE_DIM))
        if state_matrices is None:
            state_matrices = np.empty((horizon, STATE_DIM, STATE_DIM))
        if input_matrices is None:
            input_matrices = np.empty((horizon, STATE_DIM, INPUT_DIM))
        if affine_offsets is None:
            affine_offsets = np.empty((horizon, STATE_DIM))
        linearize_horizon(states, controls, *self.kernel_args, next_states, state_matrices,
                          input_matrices, affine_offsets)
        return next_states, state_matrices, input_matrices, affine_offsets

    def rollout(self, initial_state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """States x_0..x_N (shape (N + 1, 4)) from x_0 under inputs u_0..u_{N-1}."""
        initial_state = _as_float_array(initial_state, (STATE_DIM,))
        controls = _as_float_array(controls, (INPUT_DIM,))
        states = np.empty((controls.shape[0] + 1, STATE_DIM))
        rollout_horizon(initial_state, controls, *self.kernel_args, states)
        return states
