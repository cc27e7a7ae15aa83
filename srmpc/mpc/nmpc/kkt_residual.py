"""The NMPC plan's KKT residual with multipliers: how far a plan is from a KKT point of the NLP (``sqp``).

``sqp``'s convergence test (theta_inf <= 1e-6 and ||p||_inf <= 1e-4) is a proxy: it uses no multipliers and no
scaling. This module measures the NLP's first-order conditions themselves at the returned plan w, with the
multipliers of the last QP subproblem.

The NLP (``sqp``'s module doc) with its inequalities written c_i(w) >= 0:

    collision  c_kj = g_kj(x_k) + s_j - 1,   safety  c'_kj = g'_kj(x_k) + s'_j + sigma_kj - 1   (k = 1..N, j < V),
    s_j >= 0,  s'_j >= 0,  sigma_kj >= 0,  y and v boxes on x_1..N,  delta and a boxes on u_0..N-1,

(g, g' = min over the ego's circles of the ellipse norm; s'_j the safety rows' own slacks), and its Lagrangian

    L(w, nu, z) = F(w) - sum_i z_i c_i(w) + sum_{k=0..N-1} nu_{k+1}^T (f(x_k, u_k) - x_{k+1})

(x_0 = x_hat is fixed, not a variable).

Multipliers:

- z: the inequality multipliers of the last QP the SQP solved (the Riccati interior point's z at its solution,
  read from its workspace by ``solvers.compact_multipliers``). The QP's rows are the NLP's
  constraints linearized at the last iterate with the same sign convention, so its z are the NLP's multiplier
  estimates, row by row. The QP's box sigma <= ``SAFETY_SLACK_UPPER`` is no NLP constraint: its multiplier is left
  out (it shows in the stationarity if it is not 0). A screened vehicle's rows (``sqp``'s module doc) get
  z = 0, and its slacks' bounds the multipliers that make their stationarity exact (w_col,1 + 2 w_col,2 s and
  w_safe,1 + 2 w_safe,2 sigma; its slacks are 0, so their complementarity holds).
- nu: the adjoint recursion

      nu_N = grad_{x_N} F - sum_i z_i grad_{x_N} c_i,   nu_k = grad_{x_k} F - sum_i z_i grad_{x_k} c_i + A_k^T nu_{k+1},

  with A_k, B_k = df/d(x, u) at (x_k, u_k) of w: it makes the stationarity in x_1..N exact, as the Riccati solver
  recovers its own nu (``solvers.ipm_iteration``'s dual residual). The Jacobians are evaluated at w, not at the
  QP's linearization point; grad g is the closest circle's (``linearize_ellipse_rows``).

Residuals (unscaled):

    r_d = || grad_{u, s, s', sigma} L(w, nu, z) ||_inf       (stationarity; objective units per variable unit)
    r_c = max_i |z_i c_i(w)|                                  (complementarity; objective units)
    r_p = theta_inf(w)                                        (primal infeasibility, ``sqp_kernels.infeasibility``)

and IPOPT's overall NLP error (Waechter & Biegler 2006, eq. 5), with s_max = 100, n_E = 4 N equality and n_I
inequality multipliers:

    s_d = max(s_max, (||nu||_1 + ||z||_1) / (n_E + n_I)) / s_max,   s_c = max(s_max, ||z||_1 / n_I) / s_max,
    E = max(r_d / s_d, r_p, r_c / s_c).

Small E certifies an approximate KKT point on its own (no second solver needed). Both residuals grow with the
last step p: a plan that stopped at the last iterate (not at the QP's point) has stationarity ~ P p and
complementarity ~ z (c(w) - c_lin(w + p)), up to ~1e-4 times the multipliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from srmpc.mpc.nmpc.nonlinear_constraints import linearize_ellipse_rows
from srmpc.mpc.nmpc.sqp_kernels import linearize_dynamics, point_parts
from srmpc.mpc.solvers import compact_multipliers

SCALE_THRESHOLD = 100.0
"""s_max of IPOPT's error scaling (its option ``s_max``, default 100; multiplier units)."""


@dataclass(frozen=True)
class KktResidual:
    """The residuals of the module doc at a plan.

    Attributes:
        stationarity: r_d [objective units per variable unit].
        complementarity: r_c [objective units].
        primal_infeasibility: r_p = theta_inf [m, rad, m/s, ellipse norm, m/s^2].
        stationarity_scale, complementarity_scale: s_d, s_c (>= 1, dimensionless).
        error: E, IPOPT's scaled overall error (mixed units, as IPOPT's).
    """

    stationarity: float
    complementarity: float
    primal_infeasibility: float
    stationarity_scale: float
    complementarity_scale: float
    error: float

    @classmethod
    def unavailable(cls, primal_infeasibility: float) -> KktResidual:
        """No multipliers (the last QP failed): NaN residuals."""
        nan = float("nan")
        return cls(nan, nan, float(primal_infeasibility), nan, nan, nan)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _nlp_multipliers(z, offsets, n_rows, n_obs, sigma_upper, collision_rows, safety_rows, slacks, sigmas, weights,
                     z_collision, z_safety, z_slacks, z_sigmas):
    """The QP's z in the NLP's layout (module doc): rows (N, V) x 2, slack bounds (2 V,), sigma bounds (N, V); the
    screened vehicles' slack bounds from their gradients. Returns the number of collision rows."""
    horizon = z_collision.shape[0]
    n_slots = max(n_rows, 1)
    o_row, o_slack, o_sigma = offsets[0], offsets[1], offsets[2]
    n_collision = 0
    while n_collision < n_rows and sigma_upper[0, n_collision] == 0.0:  # collision rows first, their sigma closed
        n_collision += 1
    for j in range(2 * n_obs):
        z_slacks[j] = weights[0] + 2.0 * weights[1] * slacks[j]
    for k in range(horizon):
        for j in range(n_obs):
            z_collision[k, j] = 0.0
            z_safety[k, j] = 0.0
            z_sigmas[k, j] = weights[2] + 2.0 * weights[3] * sigmas[k, j]
    for row in range(n_rows):
        safety = row >= n_collision
        vehicle = safety_rows[row - n_collision] if safety else collision_rows[row]
        z_slacks[vehicle + (n_obs if safety else 0)] = z[o_slack + row]
        for k in range(horizon):
            value = z[o_row + k * n_slots + row]
            if safety:
                z_safety[k, vehicle] = value
                z_sigmas[k, vehicle] = z[o_sigma + k * n_slots + row]
            else:
                z_collision[k, vehicle] = value
    return n_collision


@numba.njit(cache=True, error_model="numpy", inline="always")
def _input_gradient(inputs, last_input, r, s, k, c):
    """d F / d u_kc = 2 R u_k + 2 S (u_k - u_{k-1}) - 2 S (u_{k+1} - u_k) (u_{-1} = u_hat; no last term at N - 1)."""
    horizon = inputs.shape[0]
    previous = last_input[c] if k == 0 else inputs[k - 1, c]
    gradient = 2.0 * r[c] * inputs[k, c] + 2.0 * s[c] * (inputs[k, c] - previous)
    if k < horizon - 1:
        gradient -= 2.0 * s[c] * (inputs[k + 1, c] - inputs[k, c])
    return gradient


@numba.njit(cache=True, error_model="numpy", inline="always")
def _jacobians_at(states, inputs, frames, n_obs, constants):
    """The Jacobians at w (module doc): A_k, B_k of the dynamics, and the ellipse rows' gradients on (x, y, psi) of
    x_k with the norms g, g'. Returns (A, B, grad g, grad g', g, g')."""
    horizon = inputs.shape[0]
    next_states, state_matrices = np.empty((horizon, 4)), np.empty((horizon, 4, 4))
    input_matrices, affine_offsets = np.empty((horizon, 4, 2)), np.empty((horizon, 4))
    linearize_dynamics(states, inputs, constants.model, next_states, state_matrices, input_matrices, affine_offsets)
    collision_gradient, safety_gradient = np.empty((horizon, n_obs, 3)), np.empty((horizon, n_obs, 3))
    collision_norm, safety_norm = np.empty((horizon, n_obs)), np.empty((horizon, n_obs))
    row_lower = np.empty((horizon, n_obs))
    if n_obs:
        linearize_ellipse_rows(states, frames, n_obs, constants.circle_offsets_m, constants.collision_semi_axes_m,
                               collision_gradient, row_lower, collision_norm)
        linearize_ellipse_rows(states, frames, n_obs, constants.circle_offsets_m, constants.safety_semi_axes_m,
                               safety_gradient, row_lower, safety_norm)
    return state_matrices, input_matrices, collision_gradient, safety_gradient, collision_norm, safety_norm


@numba.njit(cache=True, error_model="numpy", inline="always")
def _stage_residuals(states, inputs, last_input, tracking_reference, constants, z, offsets, z_collision, z_safety,
                     state_matrices, input_matrices, collision_gradient, safety_gradient):
    """x_k, k = N..1 (module doc): nu_k by the adjoint recursion, then u_{k-1}'s stationarity and the stage's bound
    complementarity. Returns (r_d, r_c, ||z||_1, ||nu||_1) over the stages' variables and bounds."""
    horizon, n_obs = inputs.shape[0], z_collision.shape[1]
    q, r, s = constants.state_weight, constants.input_weight, constants.rate_weight
    o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi = offsets[4], offsets[5], offsets[6], offsets[7], offsets[8], offsets[9]
    lower, upper = constants.state_lower, constants.state_upper
    input_lower, input_upper = constants.input_lower, constants.input_upper
    stationarity, complementarity, z_norm, nu_norm = 0.0, 0.0, 0.0, 0.0
    nu, nu_next = np.zeros(4), np.zeros(4)
    for k in range(horizon, 0, -1):
        stage = k - 1
        for c in range(4):
            nu[c] = 2.0 * q[c] * (states[k, c] - tracking_reference[k, c])
        for j in range(n_obs):
            for c in range(3):
                nu[c] -= (z_collision[stage, j] * collision_gradient[stage, j, c]
                          + z_safety[stage, j] * safety_gradient[stage, j, c])
        nu[1] -= z[o_ylo + stage] - z[o_yhi + stage]
        nu[3] -= z[o_vlo + stage] - z[o_vhi + stage]
        if k < horizon:
            for c in range(4):
                for a in range(4):
                    nu[c] += state_matrices[k, a, c] * nu_next[a]
        for c in range(2):
            coupling = 0.0
            for a in range(4):
                coupling += input_matrices[stage, a, c] * nu[a]
            bound = z[o_ulo + 2 * stage + c] - z[o_uhi + 2 * stage + c]
            gradient = _input_gradient(inputs, last_input, r, s, stage, c)
            stationarity = max(stationarity, abs(gradient - bound + coupling))
            complementarity = max(complementarity,
                                  abs(z[o_ulo + 2 * stage + c] * (inputs[stage, c] - input_lower[c])),
                                  abs(z[o_uhi + 2 * stage + c] * (input_upper[c] - inputs[stage, c])))
            z_norm += abs(z[o_ulo + 2 * stage + c]) + abs(z[o_uhi + 2 * stage + c])
        complementarity = max(complementarity, abs(z[o_ylo + stage] * (states[k, 1] - lower[1])),
                              abs(z[o_yhi + stage] * (upper[1] - states[k, 1])),
                              abs(z[o_vlo + stage] * (states[k, 3] - lower[3])),
                              abs(z[o_vhi + stage] * (upper[3] - states[k, 3])))
        z_norm += abs(z[o_ylo + stage]) + abs(z[o_yhi + stage]) + abs(z[o_vlo + stage]) + abs(z[o_vhi + stage])
        for c in range(4):
            nu_norm += abs(nu[c])
            nu_next[c] = nu[c]
    return stationarity, complementarity, z_norm, nu_norm


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slack_residuals(slacks, sigmas, weights, z_collision, z_safety, z_slacks, z_sigmas, collision_norm, safety_norm,
                     stationarity, complementarity, z_norm):
    """The slacks s_j, s'_j and sigma_kj (module doc): their stationarity, the complementarity of their bounds and
    of the rows, continuing the running (r_d, r_c, ||z||_1), which it returns."""
    horizon, n_obs = z_collision.shape
    for j in range(n_obs):
        collision_sum, safety_sum = 0.0, 0.0
        for k in range(horizon):
            collision_sum += z_collision[k, j]
            safety_sum += z_safety[k, j]
            sigma_gradient = weights[2] + 2.0 * weights[3] * sigmas[k, j]
            stationarity = max(stationarity, abs(sigma_gradient - z_safety[k, j] - z_sigmas[k, j]))
            complementarity = max(
                complementarity, abs(z_collision[k, j] * (collision_norm[k, j] + slacks[j] - 1.0)),
                abs(z_safety[k, j] * (safety_norm[k, j] + slacks[n_obs + j] + sigmas[k, j] - 1.0)),
                abs(z_sigmas[k, j] * sigmas[k, j]))
            z_norm += abs(z_collision[k, j]) + abs(z_safety[k, j]) + abs(z_sigmas[k, j])
        for part in range(2):  # s_j (collision rows), then s'_j (safety rows)
            index = part * n_obs + j
            row_sum = collision_sum if part == 0 else safety_sum
            slack_gradient = weights[0] + 2.0 * weights[1] * slacks[index]
            stationarity = max(stationarity, abs(slack_gradient - row_sum - z_slacks[index]))
            complementarity = max(complementarity, abs(z_slacks[index] * slacks[index]))
            z_norm += abs(z_slacks[index])
    return stationarity, complementarity, z_norm


@numba.njit(cache=True, error_model="numpy")
def kkt_residuals(w, n_obs, last_input, tracking_reference, frames, constants, workspace, n_rows, sigma_upper,
                  collision_rows, safety_rows):
    """(r_d, r_c, ||nu||_1 + ||z||_1, ||z||_1, n_E, n_I) of the module doc at the plan w, with the multipliers of
    the last QP in the Riccati solver's ``workspace`` (``solvers.solve_compact``'s, n_rows rows, the row vehicles and
    sigma_hi in the subproblem's arrays): the QP's z in the NLP's layout, the Jacobians at w, the stages' residuals
    (with nu), then the slacks'."""
    horizon = tracking_reference.shape[0] - 1
    states, inputs, slacks, sigmas = point_parts(w, horizon, n_obs)
    weights = constants.slack_weights
    z, offsets = compact_multipliers(workspace, n_rows)
    z_collision, z_safety, z_sigmas = np.empty((horizon, n_obs)), np.empty((horizon, n_obs)), np.empty((horizon, n_obs))
    z_slacks = np.empty(2 * n_obs)
    _nlp_multipliers(z, offsets, n_rows, n_obs, sigma_upper, collision_rows, safety_rows, slacks, sigmas, weights,
                     z_collision, z_safety, z_slacks, z_sigmas)
    state_matrices, input_matrices, collision_gradient, safety_gradient, collision_norm, safety_norm = _jacobians_at(
        states, inputs, frames, n_obs, constants)
    stationarity, complementarity, z_norm, nu_norm = _stage_residuals(
        states, inputs, last_input, tracking_reference, constants, z, offsets, z_collision, z_safety, state_matrices,
        input_matrices, collision_gradient, safety_gradient)
    stationarity, complementarity, z_norm = _slack_residuals(
        slacks, sigmas, weights, z_collision, z_safety, z_slacks, z_sigmas, collision_norm, safety_norm,
        stationarity, complementarity, z_norm)
    n_equalities = 4 * horizon
    n_inequalities = 3 * horizon * n_obs + 2 * n_obs + 8 * horizon
    return stationarity, complementarity, nu_norm + z_norm, z_norm, n_equalities, n_inequalities


def scaled_residual(stationarity: float, complementarity: float, primal_infeasibility: float, multiplier_norm: float,
                    inequality_norm: float, n_equalities: int, n_inequalities: int) -> KktResidual:
    """IPOPT's scaled error E from the unscaled residuals and the multipliers' l1 norms (module doc)."""
    stationarity_scale = max(SCALE_THRESHOLD, multiplier_norm / (n_equalities + n_inequalities)) / SCALE_THRESHOLD
    complementarity_scale = max(SCALE_THRESHOLD, inequality_norm / n_inequalities) / SCALE_THRESHOLD
    error = max(stationarity / stationarity_scale, primal_infeasibility, complementarity / complementarity_scale)
    return KktResidual(float(stationarity), float(complementarity), float(primal_infeasibility),
                       float(stationarity_scale), float(complementarity_scale), float(error))


__all__ = ["KktResidual", "SCALE_THRESHOLD", "kkt_residuals", "scaled_residual"]
