"""The interior point's Newton step (``interior_point``'s method): the Newton matrix and the direction.

``factorize_newton_matrix``, once per iteration: D = Z T^-1 (``_barrier_weights``), the stage Hessians of
H + C^T D C with each safety slack sigma_kj eliminated from its own row (``_stage_hessians``: the row keeps
weight D' = D_r h_sigma / (D_r + h_sigma)), the Riccati factorization (``ipm_riccati``), one backward pass per
observed vehicle for the columns W of w(s) and the Schur complement H_s + C_s^T W on the collision slacks s.

``newton_direction``, twice per iteration (predictor, corrector): the model's gamma and gradient, its backward
pass, the Cholesky solve for ds, dw = dw_0 + W ds in one forward pass, dsigma from its row, and (dt, dz) with
the largest steps to the boundary.
"""

from __future__ import annotations

import numba
import numpy as np

from srmpc.mpc.problem import LATERAL_INDEX, SPEED_INDEX
from srmpc.mpc.solvers.ipm_riccati import (
    cholesky_solve_in_place,
    riccati_backward,
    riccati_factorize,
    riccati_forward,
)
from srmpc.mpc.solvers.ipm_workspace import constraint_values


@numba.njit(cache=True, error_model="numpy", inline="always")
def _barrier_weights(active, t, z, d, t_inverse, z_inverse):
    """1 / t, 1 / z and D = z / t (m,) on the active inequalities, 0 elsewhere."""
    for i in range(d.shape[0]):
        if active[i]:
            t_inverse[i] = 1.0 / t[i]
            z_inverse[i] = 1.0 / z[i]
            d[i] = z[i] * t_inverse[i]
        else:
            t_inverse[i] = 0.0
            z_inverse[i] = 0.0
            d[i] = 0.0


@numba.njit(cache=True, error_model="numpy", inline="always")
def _stage_hessians(offsets, d, has_sigma, n_observed, coefficients, state_weight_hessian,
                    input_weight_hessian, rate_hessian, w_s2, row_weight, sigma_hessian,
                    state_hessians, input_hessians):
    """Stage Hessians of the Newton matrix H + C^T D C with each sigma eliminated from its row.

    Writes h_sigma = 2 w_s2 + D_lo + D_hi and the row weight D' = D_r h_sigma / (D_r + h_sigma)
    (D_r where sigma is fixed) (N, V), H^x_k = 2Q + bound and row terms (N, 4, 4) and
    H^u_k = 2R + 2S + bound terms (N, 2).
    """
    (o_row, _, o_sglo, o_sghi, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, _) = offsets
    horizon, n_slots = has_sigma.shape
    for k in range(horizon):
        for j in range(n_slots):
            i = k * n_slots + j
            d_row = d[o_row + i]
            if has_sigma[k, j]:
                h_sigma = 2.0 * w_s2 + d[o_sglo + i] + d[o_sghi + i]
                sigma_hessian[k, j] = h_sigma
                row_weight[k, j] = d_row * h_sigma / (d_row + h_sigma)
            else:
                row_weight[k, j] = d_row
        h = state_hessians[k]
        for r in range(4):
            for c in range(4):
                h[r, c] = 0.0
            h[r, r] = state_weight_hessian[r]
        h[LATERAL_INDEX, LATERAL_INDEX] += d[o_ylo + k] + d[o_yhi + k]
        h[SPEED_INDEX, SPEED_INDEX] += d[o_vlo + k] + d[o_vhi + k]
        for j in range(n_observed):
            weight = row_weight[k, j]
            for r in range(3):
                for c in range(3):
                    h[r, c] += weight * coefficients[k, j, r] * coefficients[k, j, c]
        for i in range(2):
            input_hessians[k, i] = (input_weight_hessian[i] + rate_hessian[i]
                                    + d[o_ulo + 2 * k + i] + d[o_uhi + 2 * k + i])


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slack_column_gradient(j, d_slack, w_c2, coefficients, row_weight, slack_hessian,
                           column_gradients):
    """Slot j's H_s,j = 2 w_c2 + D_s,j + sum_k D'_kj and the gradient D'_kj n_kj (N, 4; last
    column 0) of the LQ model whose solution is the column W_j of w(s)."""
    slack_hessian[j] = 2.0 * w_c2 + d_slack
    for k in range(row_weight.shape[0]):
        weight = row_weight[k, j]
        slack_hessian[j] += weight
        for a in range(3):
            column_gradients[k, a] = weight * coefficients[k, j, a]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slack_schur_complement(n_observed, slack_hessian, column_scaled, schur_base):
    """H_s + C_s^T W (V_obs x V_obs) into ``schur_base``: C_s^T W_j = -g_i^T K^-1 g_j
    = -sum_k e^(i)_k . e^(j)_k (see ``riccati_backward``), symmetric."""
    horizon = column_scaled.shape[1]
    for i in range(n_observed):
        for j in range(i + 1):
            acc = 0.0
            for k in range(horizon):
                acc += (column_scaled[i, k, 0] * column_scaled[j, k, 0]
                        + column_scaled[i, k, 1] * column_scaled[j, k, 1])
            schur_base[i, j] = -acc
            schur_base[j, i] = -acc
        schur_base[i, i] += slack_hessian[i]


@numba.njit(cache=True, error_model="numpy")
def factorize_newton_matrix(qp, ineq, newton):
    """Step: factorize the Newton matrix at the current point -- D, the stage Hessians, the
    Riccati recursion, the columns W of w(s) (backward passes only) and the Schur complement on
    s.  Returns False if
    some R^ is not (numerically) positive definite."""
    (_, state_matrices, input_matrices, _, _, coefficients, _, _, n_observed,
     state_weight_hessian, input_weight_hessian, rate_hessian, slack_weights, _) = qp
    (offsets, active, has_sigma, _, _, t, z, d, _, _, _, _, _, _, _, _, t_inverse,
     z_inverse) = ineq
    (state_hessians, input_hessians, row_weight, sigma_hessian, slack_hessian, cost_to_go,
     gains, input_cholesky, scaled_cross, cost_to_go_vector, _, column_scaled,
     column_gradients, zero_input_gradients, schur_base, _) = newton
    _barrier_weights(active, t, z, d, t_inverse, z_inverse)
    _stage_hessians(offsets, d, has_sigma, n_observed, coefficients, state_weight_hessian,
                    input_weight_hessian, rate_hessian, slack_weights[3], row_weight,
                    sigma_hessian, state_hessians, input_hessians)
    if not riccati_factorize(state_matrices, input_matrices, state_hessians, input_hessians,
                             rate_hessian, cost_to_go, gains, input_cholesky, scaled_cross):
        return False
    for j in range(n_observed):
        _slack_column_gradient(j, d[offsets[1] + j], slack_weights[1], coefficients,
                               row_weight, slack_hessian, column_gradients)
        riccati_backward(state_matrices, input_matrices, column_gradients,
                         zero_input_gradients, cost_to_go, input_cholesky, scaled_cross,
                         cost_to_go_vector, column_scaled[j])
    _slack_schur_complement(n_observed, slack_hessian, column_scaled, schur_base)
    return True


@numba.njit(cache=True, error_model="numpy", inline="always")
def _model_gamma(phase, sigma_centering, mu, active, t_inverse, d, residuals, dt_aff, dz_aff,
                 gamma):
    """gamma (m,) of the Newton model: -D r_p for the predictor (phase 0), plus
    (sigma mu - dt_aff dz_aff) / t for the corrector (phase 1); 0 on inactive rows."""
    for i in range(gamma.shape[0]):
        if not active[i]:
            gamma[i] = 0.0
        elif phase == 0:
            gamma[i] = -d[i] * residuals[i]
        else:
            gamma[i] = ((sigma_centering * mu - dt_aff[i] * dz_aff[i]) * t_inverse[i]
                        - d[i] * residuals[i])


@numba.njit(cache=True, error_model="numpy", inline="always")
def _model_gradient(offsets, gamma, d, has_sigma, n_observed, coefficients, sigma_hessian,
                    state_gradient, input_gradient, slack_gradient, sigma_gradient,
                    model_state_gradient, model_input_gradient, model_slack_gradient):
    """Model gradient grad f - C^T gamma on x (N, 4), u (N, 2) and s (V,), with each sigma
    eliminated from its row (row gradient -(gamma_r h_sigma + D_r g_sigma) / (D_r + h_sigma))."""
    (o_row, o_slo, o_sglo, o_sghi, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, _) = offsets
    horizon, n_slots = has_sigma.shape
    for k in range(horizon):
        for a in range(4):
            model_state_gradient[k, a] = state_gradient[k, a]
        model_state_gradient[k, LATERAL_INDEX] += -gamma[o_ylo + k] + gamma[o_yhi + k]
        model_state_gradient[k, SPEED_INDEX] += -gamma[o_vlo + k] + gamma[o_vhi + k]
        for i in range(2):
            model_input_gradient[k, i] = (input_gradient[k, i] - gamma[o_ulo + 2 * k + i]
                                          + gamma[o_uhi + 2 * k + i])
    for j in range(n_observed):
        model_slack_gradient[j] = slack_gradient[j] - gamma[o_slo + j]
        for k in range(horizon):
            i = k * n_slots + j
            if has_sigma[k, j]:
                h_sigma = sigma_hessian[k, j]
                g_sigma = sigma_gradient[k, j] - gamma[o_sglo + i] + gamma[o_sghi + i]
                d_row = d[o_row + i]
                g_row = -(gamma[o_row + i] * h_sigma + d_row * g_sigma) / (d_row + h_sigma)
            else:
                g_row = -gamma[o_row + i]
            model_slack_gradient[j] += g_row
            for a in range(3):
                model_state_gradient[k, a] += g_row * coefficients[k, j, a]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slack_schur_rhs(n_observed, model_slack_gradient, column_scaled, scaled_feedforward,
                     schur_base, schur, step_slacks):
    """-(g_s + C_s^T dw_0) (V_obs,) into ``step_slacks`` and a fresh copy of H_s + C_s^T W into
    ``schur`` (the Cholesky solve overwrites both); dw_0 is the model's minimizer for s = 0,
    whose backward pass wrote e^(0) = ``scaled_feedforward``: C_s^T dw_0 = -sum_k e^(i)_k . e^(0)_k."""
    horizon = scaled_feedforward.shape[0]
    for i in range(n_observed):
        acc = model_slack_gradient[i]
        for k in range(horizon):
            acc -= (column_scaled[i, k, 0] * scaled_feedforward[k, 0]
                    + column_scaled[i, k, 1] * scaled_feedforward[k, 1])
        step_slacks[i] = -acc
        for j in range(n_observed):
            schur[i, j] = schur_base[i, j]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _add_slack_columns(n_observed, step_slacks, column_scaled, scaled_feedforward):
    """dw = dw_0 + W ds, on the backward passes: e = e^(0) + sum_j ds_j e^(j) (N, 2) into
    ``scaled_feedforward`` (e is linear in the model gradient)."""
    for j in range(n_observed):
        s_j = step_slacks[j]
        for k in range(scaled_feedforward.shape[0]):
            scaled_feedforward[k, 0] += s_j * column_scaled[j, k, 0]
            scaled_feedforward[k, 1] += s_j * column_scaled[j, k, 1]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _safety_slack_direction(offsets, gamma, d, has_sigma, n_observed, coefficients,
                            sigma_gradient, sigma_hessian, step_states, step_slacks,
                            step_sigmas):
    """dsigma (N, V) from its row: -(D_r rho + g_sigma - gamma_r) / (D_r + h_sigma), with
    rho = n^T dx[0:3] + ds the row's change; left 0 where sigma is fixed."""
    (o_row, _, o_sglo, o_sghi, _, _, _, _, _, _, _) = offsets
    horizon, n_slots = has_sigma.shape
    for k in range(horizon):
        for j in range(n_observed):
            if has_sigma[k, j]:
                i = k * n_slots + j
                x = step_states[k + 1]
                rho = (coefficients[k, j, 0] * x[0] + coefficients[k, j, 1] * x[1]
                       + coefficients[k, j, 2] * x[2] + step_slacks[j])
                g_sigma = sigma_gradient[k, j] - gamma[o_sglo + i] + gamma[o_sghi + i]
                d_row = d[o_row + i]
                step_sigmas[k, j] = -(d_row * rho + g_sigma - gamma[o_row + i]) / (
                    d_row + sigma_hessian[k, j])


@numba.njit(cache=True, error_model="numpy", inline="always")
def _inequality_direction(active, z, d, t_inverse, z_inverse, direction_values, residuals,
                          gamma, dt, dz):
    """dt = C dw + r_p and dz = (sigma mu - dt_aff dz_aff) / t - z - D dt (predictor: without the
    first term) = gamma - z - D C dw (m,), from ``direction_values`` = C dw.  Returns the largest
    primal and dual steps to the boundary t = 0, z = 0 (inf if unbounded)."""
    primal_ratio = 0.0
    dual_ratio = 0.0
    for i in range(dt.shape[0]):
        if not active[i]:
            continue
        dti = direction_values[i] + residuals[i]
        dzi = gamma[i] - z[i] - d[i] * direction_values[i]
        dt[i] = dti
        dz[i] = dzi
        primal_ratio = max(primal_ratio, -dti * t_inverse[i])
        dual_ratio = max(dual_ratio, -dzi * z_inverse[i])
    step_primal = 1.0 / primal_ratio if primal_ratio > 0.0 else np.inf
    step_dual = 1.0 / dual_ratio if dual_ratio > 0.0 else np.inf
    return step_primal, step_dual


@numba.njit(cache=True, error_model="numpy")
def newton_direction(phase, sigma_centering, mu, qp, ineq, gradients, newton, direction):
    """Step: one Newton direction with the factorized Newton matrix -- the predictor (phase 0)
    or the corrector (phase 1, centering ``sigma_centering`` mu).

    Writes dw into ``direction`` and (dt, dz) into ``ineq``.  Returns (ok, largest primal step,
    largest dual step); ok is False if the Schur complement on s is not positive definite or a
    step length is NaN.
    """
    (_, state_matrices, input_matrices, _, _, coefficients, _, _, n_observed, _, _, _, _,
     _) = qp
    (offsets, active, has_sigma, _, values, _, z, d, residuals, gamma, dt, dz, dt_aff, dz_aff,
     zero_rows, zero_bounds, t_inverse, z_inverse) = ineq
    (_, _, _, sigma_hessian, _, cost_to_go, gains, input_cholesky, scaled_cross,
     cost_to_go_vector, scaled_feedforward, column_scaled, _, _, schur_base, schur) = newton
    (state_gradient, input_gradient, slack_gradient, sigma_gradient, model_state_gradient,
     model_input_gradient, model_slack_gradient, _, _) = gradients
    step_states, step_inputs, step_slacks, step_sigmas = direction
    _model_gamma(phase, sigma_centering, mu, active, t_inverse, d, residuals, dt_aff, dz_aff,
                 gamma)
    _model_gradient(offsets, gamma, d, has_sigma, n_observed, coefficients, sigma_hessian,
                    state_gradient, input_gradient, slack_gradient, sigma_gradient,
                    model_state_gradient, model_input_gradient, model_slack_gradient)
    riccati_backward(state_matrices, input_matrices, model_state_gradient, model_input_gradient,
                     cost_to_go, input_cholesky, scaled_cross, cost_to_go_vector,
                     scaled_feedforward)
    _slack_schur_rhs(n_observed, model_slack_gradient, column_scaled, scaled_feedforward,
                     schur_base, schur, step_slacks)
    if not cholesky_solve_in_place(schur, step_slacks, n_observed):
        return False, np.inf, np.inf
    _add_slack_columns(n_observed, step_slacks, column_scaled, scaled_feedforward)
    riccati_forward(state_matrices, input_matrices, gains, input_cholesky, scaled_feedforward,
                    step_states, step_inputs)
    _safety_slack_direction(offsets, gamma, d, has_sigma, n_observed, coefficients,
                            sigma_gradient, sigma_hessian, step_states, step_slacks,
                            step_sigmas)
    constraint_values(step_states, step_inputs, step_slacks, step_sigmas, coefficients,
                      zero_rows, zero_rows, zero_bounds, offsets, values)
    step_primal, step_dual = _inequality_direction(active, z, d, t_inverse, z_inverse, values,
                                                   residuals, gamma, dt, dz)
    if np.isnan(step_primal) or np.isnan(step_dual):
        return False, step_primal, step_dual
    return True, step_primal, step_dual
