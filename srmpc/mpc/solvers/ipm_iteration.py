"""The interior point's iterations (``interior_point``'s method): Mehrotra predictor-corrector from a start.

Per iteration (``iterate``): the residuals at the current point (``_residuals``) and the termination test
(``_convergence_status``, the module doc of ``interior_point``), the Newton matrix (``ipm_newton``), the
predictor's direction, Mehrotra's centering sigma = (mu_aff / mu)^3, the corrector's direction, the step
lengths (``FRACTION_TO_BOUNDARY`` of the way to the boundary, at most 1) and the update of (w, t, z).
"""

from __future__ import annotations

import numba
import numpy as np

from srmpc.mpc.problem import LATERAL_INDEX, SPEED_INDEX
from srmpc.mpc.solvers.ipm_newton import factorize_newton_matrix, newton_direction
from srmpc.mpc.solvers.ipm_workspace import constraint_values

STATUS_SOLVED = 0
STATUS_MAX_ITERATIONS = 1
STATUS_NUMERICAL_ERROR = 2
STATUS_NAMES = {STATUS_SOLVED: "solved", STATUS_MAX_ITERATIONS: "max_iterations",
                STATUS_NUMERICAL_ERROR: "numerical_error"}

FRACTION_TO_BOUNDARY = 0.995
"""Steps stop at this fraction of the distance to the boundary t = 0 or z = 0 (dimensionless)."""
_ITERATING = -1
"""``_convergence_status`` of a point that is neither solved nor broken."""


@numba.njit(cache=True, error_model="numpy", inline="always")
def _objective_gradient(states, inputs, slacks, sigmas, tracking_reference, last_input,
                        state_weight_hessian, input_weight_hessian, rate_hessian, slack_weights,
                        n_observed, has_sigma, state_gradient, input_gradient, slack_gradient,
                        sigma_gradient):
    """grad f = P w + q at the current point, per block (observed slots only)."""
    horizon = inputs.shape[0]
    for k in range(horizon):
        for a in range(4):
            state_gradient[k, a] = state_weight_hessian[a] * (
                states[k + 1, a] - tracking_reference[k + 1, a])
        for i in range(2):
            previous = last_input[i] if k == 0 else inputs[k - 1, i]
            grad = (input_weight_hessian[i] * inputs[k, i]
                    + rate_hessian[i] * (inputs[k, i] - previous))
            if k < horizon - 1:
                grad -= rate_hessian[i] * (inputs[k + 1, i] - inputs[k, i])
            input_gradient[k, i] = grad
        for j in range(n_observed):
            sigma_gradient[k, j] = (slack_weights[2] + 2.0 * slack_weights[3] * sigmas[k, j]
                                    if has_sigma[k, j] else 0.0)
    for j in range(n_observed):
        slack_gradient[j] = slack_weights[0] + 2.0 * slack_weights[1] * slacks[j]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _primal_residual_and_complementarity(active, values, t, z, residuals, n_active):
    """r_p = a^T w - b - t (m,) into ``residuals``; returns (max |r_p|, mu = t^T z / n_active)
    over the active inequalities."""
    primal_residual = 0.0
    mu = 0.0
    for i in range(values.shape[0]):
        if active[i]:
            residuals[i] = values[i] - t[i]
            primal_residual = max(primal_residual, abs(residuals[i]))
            mu += t[i] * z[i]
    mu /= n_active
    return primal_residual, mu


@numba.njit(cache=True, error_model="numpy", inline="always")
def _dual_residual_states_inputs(offsets, z, n_observed, coefficients, state_matrices,
                                 input_matrices, state_gradient, input_gradient, nu, nu_next):
    """Stationarity in x and u: with nu_k = A_k^T nu_{k+1} - grad_x_k L (4,) making the x rows
    exact, returns (max |grad_u L|, its scale max(1, |terms|)) over the stages."""
    (o_row, _, _, _, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, _) = offsets
    horizon = state_matrices.shape[0]
    n_slots = coefficients.shape[1]
    dual_residual = 0.0
    dual_scale = 1.0
    for a in range(4):
        nu_next[a] = 0.0
    for k in range(horizon, 0, -1):
        for a in range(4):
            nu[a] = -state_gradient[k - 1, a]
            dual_scale = max(dual_scale, abs(nu[a]))
        for j in range(n_observed):
            zr = z[o_row + (k - 1) * n_slots + j]
            for a in range(3):
                nu[a] += zr * coefficients[k - 1, j, a]
        nu[LATERAL_INDEX] += z[o_ylo + k - 1] - z[o_yhi + k - 1]
        nu[SPEED_INDEX] += z[o_vlo + k - 1] - z[o_vhi + k - 1]
        if k < horizon:
            a_k = state_matrices[k]
            for c in range(4):
                acc = 0.0
                for r in range(4):
                    acc += a_k[r, c] * nu_next[r]
                nu[c] += acc
        for a in range(4):
            nu_next[a] = nu[a]
        kk = k - 1
        b_k = input_matrices[kk]
        for i in range(2):
            coupling = 0.0
            for r in range(4):
                coupling += b_k[r, i] * nu[r]
            multiplier = z[o_ulo + 2 * kk + i] - z[o_uhi + 2 * kk + i]
            grad = input_gradient[kk, i]
            dual_scale = max(dual_scale, abs(grad), abs(coupling), abs(multiplier))
            dual_residual = max(dual_residual, abs(grad - multiplier - coupling))
    return dual_residual, dual_scale


@numba.njit(cache=True, error_model="numpy", inline="always")
def _dual_residual_slacks(offsets, z, has_sigma, n_observed, sigma_gradient, slack_gradient,
                          dual_residual, dual_scale):
    """``(dual_residual, dual_scale)`` extended by stationarity in sigma (N, V) and s (V,) of the
    observed slots."""
    (o_row, o_slo, o_sglo, o_sghi, _, _, _, _, _, _, _) = offsets
    horizon, n_slots = has_sigma.shape
    for j in range(n_observed):
        multiplier = z[o_slo + j]
        for k in range(horizon):
            i = k * n_slots + j
            multiplier += z[o_row + i]
            if has_sigma[k, j]:
                mult_sigma = z[o_row + i] + z[o_sglo + i] - z[o_sghi + i]
                grad_sigma = sigma_gradient[k, j]
                dual_scale = max(dual_scale, abs(grad_sigma), abs(mult_sigma))
                dual_residual = max(dual_residual, abs(grad_sigma - mult_sigma))
        dual_scale = max(dual_scale, abs(slack_gradient[j]), abs(multiplier))
        dual_residual = max(dual_residual, abs(slack_gradient[j] - multiplier))
    return dual_residual, dual_scale


@numba.njit(cache=True, error_model="numpy")
def _residuals(qp, point, ineq, gradients):
    """Step: residuals at the current point w.

    Writes a^T w - b into ``ineq.values``, grad f into ``gradients`` and r_p into
    ``ineq.residuals``.  Returns (primal residual max |r_p|, complementarity mu, dual residual,
    dual scale) as in the module doc's termination rule.
    """
    states, inputs, slacks, sigmas = point
    (last_input, state_matrices, input_matrices, _, tracking_reference, coefficients, row_lower,
     sigma_upper, n_observed, state_weight_hessian, input_weight_hessian, rate_hessian,
     slack_weights, bounds) = qp
    (offsets, active, has_sigma, n_active, values, t, z, _, residuals, _, _, _, _, _, _, _, _,
     _) = ineq
    (state_gradient, input_gradient, slack_gradient, sigma_gradient, _, _, _, nu,
     nu_next) = gradients
    constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower, sigma_upper,
                      bounds, offsets, values)
    _objective_gradient(states, inputs, slacks, sigmas, tracking_reference, last_input,
                        state_weight_hessian, input_weight_hessian, rate_hessian, slack_weights,
                        n_observed, has_sigma, state_gradient, input_gradient, slack_gradient,
                        sigma_gradient)
    primal_residual, mu = _primal_residual_and_complementarity(active, values, t, z, residuals,
                                                               n_active)
    dual_residual, dual_scale = _dual_residual_states_inputs(
        offsets, z, n_observed, coefficients, state_matrices, input_matrices, state_gradient,
        input_gradient, nu, nu_next)
    dual_residual, dual_scale = _dual_residual_slacks(offsets, z, has_sigma, n_observed,
                                                      sigma_gradient, slack_gradient,
                                                      dual_residual, dual_scale)
    return primal_residual, mu, dual_residual, dual_scale


@numba.njit(cache=True, error_model="numpy")
def _convergence_status(primal_residual, mu, dual_residual, dual_scale, tolerance):
    """``STATUS_NUMERICAL_ERROR`` if mu or the dual residual is not finite, ``STATUS_SOLVED`` if
    all three residuals are within ``tolerance`` (dual: relative to its scale), else
    ``_ITERATING``."""
    if not (np.isfinite(mu) and np.isfinite(dual_residual)):
        return STATUS_NUMERICAL_ERROR
    if (primal_residual <= tolerance and mu <= tolerance
            and dual_residual <= tolerance * dual_scale):
        return STATUS_SOLVED
    return _ITERATING


@numba.njit(cache=True, error_model="numpy")
def _mehrotra_centering(ineq, step_primal, step_dual, mu):
    """Step: keep the predictor's (dt, dz) as (dt_aff, dz_aff) and return Mehrotra's centering
    sigma = (mu_aff / mu)^3, mu_aff the complementarity after the predictor's step."""
    (_, active, _, n_active, _, t, z, _, _, _, dt, dz, dt_aff, dz_aff, _, _, _, _) = ineq
    mu_affine = 0.0
    alpha_primal = min(1.0, step_primal)
    alpha_dual = min(1.0, step_dual)
    for i in range(t.shape[0]):
        if active[i]:
            dt_aff[i] = dt[i]
            dz_aff[i] = dz[i]
            mu_affine += (t[i] + alpha_primal * dt[i]) * (z[i] + alpha_dual * dz[i])
    mu_affine /= n_active
    ratio = mu_affine / mu
    return ratio * ratio * ratio


@numba.njit(cache=True, error_model="numpy")
def _step_lengths(step_primal, step_dual):
    """(alpha_primal, alpha_dual): ``FRACTION_TO_BOUNDARY`` of the steps to the boundary, at
    most 1."""
    return (min(1.0, FRACTION_TO_BOUNDARY * step_primal),
            min(1.0, FRACTION_TO_BOUNDARY * step_dual))


@numba.njit(cache=True, error_model="numpy")
def _update_iterate(point, direction, ineq, alpha_primal, alpha_dual, n_observed):
    """Step: w += alpha_primal dw and, on the active rows, t += alpha_primal dt and
    z += alpha_dual dz."""
    states, inputs, slacks, sigmas = point
    step_states, step_inputs, step_slacks, step_sigmas = direction
    (_, active, _, _, _, t, z, _, _, _, dt, dz, _, _, _, _, _, _) = ineq
    for k in range(step_inputs.shape[0]):
        for a in range(4):
            states[k + 1, a] += alpha_primal * step_states[k + 1, a]
        for i in range(2):
            inputs[k, i] += alpha_primal * step_inputs[k, i]
        for j in range(n_observed):
            sigmas[k, j] += alpha_primal * step_sigmas[k, j]
    for j in range(n_observed):
        slacks[j] += alpha_primal * step_slacks[j]
    for i in range(t.shape[0]):
        if active[i]:
            t[i] += alpha_primal * dt[i]
            z[i] += alpha_dual * dz[i]


@numba.njit(cache=True, error_model="numpy")
def iterate(qp, point, ineq, gradients, newton, direction, tolerance, max_iterations):
    """Mehrotra predictor-corrector iterations from a started (point, ineq): (status, iterations)."""
    for iteration in range(max_iterations + 1):
        primal_residual, mu, dual_residual, dual_scale = _residuals(qp, point, ineq, gradients)
        status = _convergence_status(primal_residual, mu, dual_residual, dual_scale, tolerance)
        if status != _ITERATING:
            return status, iteration
        if iteration == max_iterations:
            break
        if not factorize_newton_matrix(qp, ineq, newton):
            return STATUS_NUMERICAL_ERROR, iteration
        sigma_centering = 0.0
        step_primal = np.inf
        step_dual = np.inf
        for phase in range(2):  # predictor (affine scaling), then corrector
            ok, step_primal, step_dual = newton_direction(phase, sigma_centering, mu, qp, ineq,
                                                          gradients, newton, direction)
            if not ok:
                return STATUS_NUMERICAL_ERROR, iteration
            if phase == 0:
                sigma_centering = _mehrotra_centering(ineq, step_primal, step_dual, mu)
        alpha_primal, alpha_dual = _step_lengths(step_primal, step_dual)
        _update_iterate(point, direction, ineq, alpha_primal, alpha_dual, qp.n_observed)
    return STATUS_MAX_ITERATIONS, max_iterations
