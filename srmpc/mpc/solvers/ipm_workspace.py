"""The interior point's data (``interior_point``): the QP as a tuple, the inequalities' layout, the arrays.

The QP (``interior_point``'s module doc) reaches the compiled steps as ``QpData`` (``qp_tuple``). Its m
inequalities C w >= h are one flat vector in groups (``inequality_offsets``), each one entry per stage and
vehicle slot, per slot or per stage::

    collision rows (N V) | s >= 0 (V) | sigma >= 0 (N V) | sigma <= sigma_hi (N V)
    | y >= y_lo (N) | y <= y_hi (N) | v >= v_lo (N) | v <= v_hi (N) | u >= u_lo (2 N) | u <= u_hi (2 N)

Rows of empty slots (j >= V_obs) and safety slacks whose box is closed are inactive (``_active_inequalities``).
A point w or a direction dw is ``Primal``; the inequalities' vectors are ``Inequalities`` on the arrays of
``InequalityArrays``; the objective's and the Newton model's gradients ``Gradients``; the factorized Newton
matrix ``NewtonMatrix``. All arrays are allocated once (``allocate_workspace``); each solve resets what it reads
before writing (``prepare_inequalities``), so a reused workspace solves bit for bit as a fresh one.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from srmpc.mpc.problem import LATERAL_INDEX, SPEED_INDEX

SIGMA_BOX_MIN_WIDTH = 1e-9
"""A safety slack whose box [0, sigma_hi] is narrower than this is fixed at 0 (ellipse units)."""

QpData = namedtuple("QpData", ["last_input", "state_matrices", "input_matrices", "affine_offsets",
                               "tracking_reference", "coefficients", "row_lower", "sigma_upper",
                               "n_observed", "state_weight_hessian", "input_weight_hessian",
                               "rate_hessian", "slack_weights", "bounds"])
"""The QP data: ``solve_ltv_mpc_qp``'s arguments of the same names (shapes there)."""

Primal = namedtuple("Primal", ["states", "inputs", "slacks", "sigmas"])
"""A primal point w or direction dw: x (N + 1, 4), u (N, 2), s (V,), sigma (N, V)."""

Inequalities = namedtuple("Inequalities", [
    "offsets", "active", "has_sigma", "n_active", "values", "t", "z", "d", "residuals", "gamma",
    "dt", "dz", "dt_aff", "dz_aff", "zero_rows", "zero_bounds", "t_inverse", "z_inverse"])
"""The m inequalities C w >= h: group starts (``inequality_offsets``), which exist (active (m,), has_sigma
(N, V), their count n_active), then vectors (m,): a^T w - b, slacks t, multipliers z, D = z / t,
r_p = a^T w - b - t, gamma, the step (dt, dz) and the predictor's (dt_aff, dz_aff); zero_rows
(N, V) and zero_bounds (8,) make ``constraint_values`` of a direction give C dw; 1 / t and
1 / z (m,) at the current point (0 on inactive rows)."""

InequalityArrays = namedtuple("InequalityArrays", [
    "active", "has_sigma", "values", "t", "z", "d", "residuals", "gamma", "dt", "dz", "dt_aff",
    "dz_aff", "t_inverse", "z_inverse", "spare", "zero_rows", "zero_bounds"])
"""The arrays of ``Inequalities`` (``spare`` (m,): scratch of the warm start), allocated once
(``allocate_workspace``)."""

Gradients = namedtuple("Gradients", ["states", "inputs", "slacks", "sigmas", "model_states",
                                     "model_inputs", "model_slacks", "nu", "nu_next"])
"""grad f on x_1..N (N, 4), u (N, 2), s (V,), sigma (N, V); the model gradient grad f - C^T gamma
with each sigma eliminated on x (N, 4), u (N, 2), s (V,); scratch nu_k, nu_{k+1} (4,)."""

NewtonMatrix = namedtuple("NewtonMatrix", [
    "state_hessians", "input_hessians", "row_weight", "sigma_hessian", "slack_hessian",
    "cost_to_go", "gains", "input_cholesky", "scaled_cross", "cost_to_go_vector",
    "scaled_feedforward", "column_scaled", "column_gradients", "zero_input_gradients",
    "schur_base", "schur"])
"""The factorized Newton matrix: stage Hessians H^x (N, 4, 4), H^u (N, 2), row weights D' and
sigma Hessians h_sigma (N, V), slack Hessians H_s (V,); the Riccati factorization (see
``riccati_factorize``), its backward pass's scratch p_k (N + 1, 6) and e_k (N, 2); the
columns W of w(s) as their backward passes' e^(j) (V, N, 2) with their gradients (N, 4),
(N, 2); H_s + C_s^T W (V, V) and its Cholesky copy."""


@numba.njit(cache=True, error_model="numpy")
def inequality_offsets(horizon, n_slots):
    """Start of each inequality group in the flat (t, z) vectors, and their total m."""
    row = 0
    slack_lower = row + horizon * n_slots
    sigma_lower = slack_lower + n_slots
    sigma_upper = sigma_lower + horizon * n_slots
    lateral_lower = sigma_upper + horizon * n_slots
    lateral_upper = lateral_lower + horizon
    speed_lower = lateral_upper + horizon
    speed_upper = speed_lower + horizon
    input_lower = speed_upper + horizon
    input_upper = input_lower + 2 * horizon
    total = input_upper + 2 * horizon
    return (row, slack_lower, sigma_lower, sigma_upper, lateral_lower, lateral_upper,
            speed_lower, speed_upper, input_lower, input_upper, total)


@numba.njit(cache=True, error_model="numpy", inline="always")
def constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower, sigma_upper,
                      bounds, offsets, out):
    """out_i = a_i^T w - b_i for every inequality (>= 0 when satisfied)."""
    horizon = inputs.shape[0]
    n_slots = coefficients.shape[1]
    (o_row, o_slo, o_sglo, o_sghi, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, _) = offsets
    for k in range(horizon):
        x = states[k + 1]
        for j in range(n_slots):
            i = k * n_slots + j
            out[o_row + i] = (coefficients[k, j, 0] * x[0] + coefficients[k, j, 1] * x[1]
                              + coefficients[k, j, 2] * x[2] + slacks[j] + sigmas[k, j]
                              - row_lower[k, j])
            out[o_sglo + i] = sigmas[k, j]
            out[o_sghi + i] = sigma_upper[k, j] - sigmas[k, j]
        out[o_ylo + k] = x[LATERAL_INDEX] - bounds[0]
        out[o_yhi + k] = bounds[1] - x[LATERAL_INDEX]
        out[o_vlo + k] = x[SPEED_INDEX] - bounds[2]
        out[o_vhi + k] = bounds[3] - x[SPEED_INDEX]
        for i in range(2):
            out[o_ulo + 2 * k + i] = inputs[k, i] - bounds[4 + i]
            out[o_uhi + 2 * k + i] = bounds[6 + i] - inputs[k, i]
    for j in range(n_slots):
        out[o_slo + j] = slacks[j]


@numba.njit(cache=True, error_model="numpy")
def _active_inequalities(sigma_upper, n_observed, offsets, active, has_sigma):
    """Which inequalities exist: rows and slacks of observed slots, safety-slack boxes wider than
    ``SIGMA_BOX_MIN_WIDTH``, all state and input bounds.

    Writes active (m,) bool and has_sigma (N, V) bool; returns n_active.
    """
    (o_row, o_slo, o_sglo, o_sghi, o_ylo, _, _, _, _, _, m) = offsets
    horizon, n_slots = has_sigma.shape
    active[:] = False
    has_sigma[:, :] = False
    for j in range(n_observed):
        active[o_slo + j] = True
        for k in range(horizon):
            i = k * n_slots + j
            active[o_row + i] = True
            if sigma_upper[k, j] > SIGMA_BOX_MIN_WIDTH:
                has_sigma[k, j] = True
                active[o_sglo + i] = True
                active[o_sghi + i] = True
    for i in range(o_ylo, m):
        active[i] = True
    n_active = 0
    for i in range(m):
        if active[i]:
            n_active += 1
    return n_active


def allocate_workspace(horizon, n_slots):
    """The solver's arrays for an (N, V) QP, allocated once: (point, inequality arrays, gradients,
    Newton matrix, direction) as the named tuples ``Primal``, ``InequalityArrays``,
    ``Gradients``, ``NewtonMatrix``, ``Primal`` (each solve resets what it reads before writing)."""
    m = inequality_offsets(horizon, n_slots)[10]
    point = Primal(np.empty((horizon + 1, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
                   np.zeros((horizon, n_slots)))
    inequalities = InequalityArrays(
        np.zeros(m, dtype=np.bool_), np.zeros((horizon, n_slots), dtype=np.bool_),
        *(np.zeros(m) for _ in range(13)), np.zeros((horizon, n_slots)), np.zeros(8))
    gradients = Gradients(np.empty((horizon, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
                          np.zeros((horizon, n_slots)), np.empty((horizon, 4)),
                          np.empty((horizon, 2)), np.empty(n_slots), np.empty(4), np.empty(4))
    newton = NewtonMatrix(
        np.empty((horizon, 4, 4)), np.empty((horizon, 2)), np.zeros((horizon, n_slots)),
        np.ones((horizon, n_slots)), np.empty(n_slots), np.empty((horizon + 1, 6, 6)),
        np.empty((horizon, 2, 6)), np.empty((horizon, 3)), np.empty((horizon, 2, 6)),
        np.empty((horizon + 1, 6)), np.empty((horizon, 2)), np.empty((n_slots, horizon, 2)),
        np.zeros((horizon, 4)), np.zeros((horizon, 2)), np.empty((n_slots, n_slots)),
        np.empty((n_slots, n_slots)))
    direction = Primal(np.empty((horizon + 1, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
                       np.zeros((horizon, n_slots)))
    return point, inequalities, gradients, newton, direction


@numba.njit(cache=True, error_model="numpy")
def _reset_workspace(arrays, gradients, newton, direction):
    """Give the arrays that a solve reads before writing them their allocation values (zeros;
    ones for h_sigma): a reused workspace then solves bit for bit as a fresh one."""
    for vector in (arrays.d, arrays.residuals, arrays.gamma, arrays.dt, arrays.dz, arrays.dt_aff,
                   arrays.dz_aff, arrays.t_inverse, arrays.z_inverse):
        vector[:] = 0.0
    arrays.zero_rows[:, :] = 0.0
    arrays.zero_bounds[:] = 0.0
    gradients.slacks[:] = 0.0
    gradients.sigmas[:, :] = 0.0
    newton.row_weight[:, :] = 0.0
    newton.sigma_hessian[:, :] = 1.0
    newton.column_gradients[:, :] = 0.0
    newton.zero_input_gradients[:, :] = 0.0
    direction.slacks[:] = 0.0
    direction.sigmas[:, :] = 0.0


@numba.njit(cache=True, error_model="numpy")
def qp_tuple(last_input, state_matrices, input_matrices, affine_offsets, tracking_reference,
             coefficients, row_lower, sigma_upper, n_observed, state_weight_hessian,
             input_weight_hessian, rate_hessian, slack_weights, bounds):
    """The QP data as the steps' ``QpData`` tuple (arguments as in ``solve_ltv_mpc_qp``)."""
    return QpData(last_input, state_matrices, input_matrices, affine_offsets, tracking_reference,
                  coefficients, row_lower, sigma_upper, n_observed, state_weight_hessian,
                  input_weight_hessian, rate_hessian, slack_weights, bounds)


@numba.njit(cache=True, error_model="numpy")
def prepare_inequalities(qp, workspace):
    """Reset the workspace and mark the QP's active inequalities; returns ``Inequalities`` on
    the workspace's arrays (t and z are set by a start)."""
    _, arrays, gradients, newton, direction = workspace
    horizon, n_slots = qp.coefficients.shape[0], qp.coefficients.shape[1]
    offsets = inequality_offsets(horizon, n_slots)
    _reset_workspace(arrays, gradients, newton, direction)
    n_active = _active_inequalities(qp.sigma_upper, qp.n_observed, offsets, arrays.active,
                                    arrays.has_sigma)
    return Inequalities(offsets, arrays.active, arrays.has_sigma, n_active, arrays.values,
                        arrays.t, arrays.z, arrays.d, arrays.residuals, arrays.gamma, arrays.dt,
                        arrays.dz, arrays.dt_aff, arrays.dz_aff, arrays.zero_rows,
                        arrays.zero_bounds, arrays.t_inverse, arrays.z_inverse)


@numba.njit(cache=True, error_model="numpy")
def scatter_solution(states, inputs, slacks, sigmas, positions, z):
    """z[positions] = (states, inputs, slacks, sigmas) flattened in that order (the QP's
    variable layout); returns False if any value is not finite."""
    index = 0
    finite = True
    for block in (states.ravel(), inputs.ravel(), slacks.ravel(), sigmas.ravel()):
        for value in block:
            z[positions[index]] = value
            finite = finite and np.isfinite(value)
            index += 1
    return finite
