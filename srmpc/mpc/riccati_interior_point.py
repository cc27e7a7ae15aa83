"""Structure-exploiting primal-dual interior-point solver for the LTV-MPC QP (HPIPM style).

Solves exactly the QP that ``qp_builder.LtvMpcQp`` assembles (same variables, objective and
constraints; see its module doc), but works on the stage-wise data instead of sparse matrices:

    min  sum_{k=1..N} (x_k - x^ref_k)^T Q (x_k - x^ref_k) + sum_{k=0..N-1} u_k^T R u_k
         + sum_{k=0..N-1} (u_k - u_{k-1})^T S (u_k - u_{k-1})            (u_{-1} = u_hat)
         + sum_j (w_c1 s_j + w_c2 s_j^2) + sum_{k,j} (w_s1 sigma_kj + w_s2 sigma_kj^2)
    s.t. x_0 = x_hat,  x_{k+1} = A_k x_k + B_k u_k + c_k,
         n_kj^T x_k[0:3] + s_j + sigma_kj >= h_kj                      (collision rows)
         y_lo <= y_k <= y_hi, v_lo <= v_k <= v_hi (k >= 1), u_lo <= u_k <= u_hi,
         s_j >= 0, 0 <= sigma_kj <= sigma_hi_kj.

Only the observed vehicle slots j < V_obs enter; empty slots have s_j = sigma_kj = 0, which is
the unique optimum of the full QP for them (their row reads s_j + sigma_kj >= 0 with
0 <= sigma_kj <= 0 and a positive cost on s_j).

Method: Mehrotra predictor-corrector on the inequalities C w >= h written with slacks t >= 0
and multipliers z >= 0 (T = diag t, Z = diag z, D = Z T^-1).  Each Newton system is solved in
"absolute" form: the new primal point w+ minimizes the quadratic model

    1/2 w^T (H + C^T D C) w + (g - C^T gamma)^T w   s.t. the dynamics (exactly),
    gamma = D (h + t) + (sigma_c mu - dt_aff * dz_aff) / t,

so the equality multipliers never enter; then dt = C w+ - h - t and
dz = -z + (sigma_c mu - dt_aff * dz_aff) / t - D dt.

The model is a linear-quadratic optimal control problem plus an "arrow" (the collision slacks
s_j couple every stage).  It is solved by

1. eliminating each safety slack sigma_kj from its own row (scalar Schur complement: the row
   keeps weight D' = D_r h_sigma / (D_r + h_sigma));
2. a Riccati recursion over the stages on the augmented state (x_k, u_{k-1}) (6 states,
   2 inputs), which makes the input-rate cost stage-wise;
3. a Schur complement on s: w(s) = w_0 + W s, then a V_obs x V_obs Cholesky solve of
   (H_s + C_s^T W) s = -(g_s + C_s^T w_0).  Neither W nor w_0 is formed: the Riccati backward
   pass maps a model gradient g linearly to scaled feedforwards e_k (N, 2) with
   g_i^T K^-1 g_j = sum_k e^(i)_k . e^(j)_k (K the reduced Hessian), so one backward pass per
   observed vehicle gives C_s^T W, the backward pass of w_0 gives C_s^T w_0, and w(s) is one
   forward pass from e^(0) + sum_j s_j e^(j).

Per iteration this costs one factorization, V_obs + 2 backward passes, 2 forward passes and
O(N V) vector work: linear in N, with 4x4 and 2x2 dense blocks only.

Termination: inequality residual max|C w - h - t| <= tol, dual residual (stationarity with the
dynamics multipliers nu recovered by the backward recursion nu_k = A_k^T nu_{k+1} - grad_x_k L)
<= tol (1 + scale), mean complementarity mu <= tol.  Returns a status code; anything other than
``STATUS_SOLVED`` must be treated as a failed solve.

Code layout: ``solve_cold_in`` reads as the method's steps -- active inequalities
(``prepare_inequalities``), starting point (``cold_start``; ``interior_point_warm_start`` has the warm
one), then ``iterate``: per iteration ``_residuals`` and ``_convergence_status``, ``_factorize_newton_matrix``
(D, stage Hessians, Riccati factorization, Schur complement on s), ``_newton_direction`` for the
predictor and the corrector (``_mehrotra_centering`` between them), ``_step_lengths`` and
``_update_iterate``.  The steps are compiled functions that receive the solver's arrays grouped
in the named tuples ``_Qp`` (the QP data), ``_Primal`` (a point or a direction),
``_Inequalities``, ``_Gradients`` and ``_Newton``; each unpacks what it needs and calls helpers
on plain arrays that are compiled into it (``inline="always"``).  Tuples passed into inlined
helpers, or compiled calls out of a step, leave numba reference-count updates on every array per
call that its pruning pass cannot remove (they cost about 15% of the solve time).  All arrays are
allocated once (``allocate_workspace``); ``solve_ltv_mpc_qp`` allocates them per call.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

STATUS_SOLVED = 0
STATUS_MAX_ITERATIONS = 1
STATUS_NUMERICAL_ERROR = 2
STATUS_NAMES = {STATUS_SOLVED: "solved", STATUS_MAX_ITERATIONS: "max_iterations",
                STATUS_NUMERICAL_ERROR: "numerical_error"}

FRACTION_TO_BOUNDARY = 0.995
"""Steps stop at this fraction of the distance to the boundary t = 0 or z = 0 (dimensionless)."""
INITIAL_SLACK = 1.0
"""Lower bound on the starting inequality slacks t_0 = max(a^T w_0 - b, .) (constraint units)."""
INITIAL_MULTIPLIER = 100.0
"""Starting inequality multipliers z_0 (objective units per constraint unit)."""
INITIAL_INPUT_MARGIN = 0.01
"""The starting inputs keep this fraction of their box width from its bounds (dimensionless)."""
SIGMA_BOX_MIN_WIDTH = 1e-9
"""A safety slack whose box [0, sigma_hi] is narrower than this is fixed at 0 (ellipse units)."""
CHOLESKY_PIVOT_FLOOR = 1e-15
"""Relative size below which a Cholesky pivot counts as zero (not positive definite)."""

_LATERAL = 1
_SPEED = 3
_ITERATING = -1
"""``_convergence_status`` of a point that is neither solved nor broken."""

_Qp = namedtuple("_Qp", ["last_input", "state_matrices", "input_matrices", "affine_offsets",
                         "tracking_reference", "coefficients", "row_lower", "sigma_upper",
                         "n_observed", "state_weight_hessian", "input_weight_hessian",
                         "rate_hessian", "slack_weights", "bounds"])
"""The QP data: ``solve_ltv_mpc_qp``'s arguments of the same names (shapes there)."""
_Primal = namedtuple("_Primal", ["states", "inputs", "slacks", "sigmas"])
"""A primal point w or direction dw: x (N + 1, 4), u (N, 2), s (V,), sigma (N, V)."""
_Inequalities = namedtuple("_Inequalities", [
    "offsets", "active", "has_sigma", "n_active", "values", "t", "z", "d", "residuals", "gamma",
    "dt", "dz", "dt_aff", "dz_aff", "zero_rows", "zero_bounds", "t_inverse", "z_inverse"])
"""The m inequalities C w >= h: group starts (``_offsets``), which exist (active (m,), has_sigma
(N, V), their count n_active), then vectors (m,): a^T w - b, slacks t, multipliers z, D = z / t,
r_p = a^T w - b - t, gamma, the step (dt, dz) and the predictor's (dt_aff, dz_aff); zero_rows
(N, V) and zero_bounds (8,) make ``_constraint_values`` of a direction give C dw; 1 / t and
1 / z (m,) at the current point (0 on inactive rows)."""
_InequalityArrays = namedtuple("_InequalityArrays", [
    "active", "has_sigma", "values", "t", "z", "d", "residuals", "gamma", "dt", "dz", "dt_aff",
    "dz_aff", "t_inverse", "z_inverse", "spare", "zero_rows", "zero_bounds"])
"""The arrays of ``_Inequalities`` (``spare`` (m,): scratch of the warm start), allocated once
(``allocate_workspace``)."""
_Gradients = namedtuple("_Gradients", ["states", "inputs", "slacks", "sigmas", "model_states",
                                       "model_inputs", "model_slacks", "nu", "nu_next"])
"""grad f on x_1..N (N, 4), u (N, 2), s (V,), sigma (N, V); the model gradient grad f - C^T gamma
with each sigma eliminated on x (N, 4), u (N, 2), s (V,); scratch nu_k, nu_{k+1} (4,)."""
_Newton = namedtuple("_Newton", [
    "state_hessians", "input_hessians", "row_weight", "sigma_hessian", "slack_hessian",
    "cost_to_go", "gains", "input_cholesky", "scaled_cross", "cost_to_go_vector",
    "scaled_feedforward", "column_scaled", "column_gradients", "zero_input_gradients",
    "schur_base", "schur"])
"""The factorized Newton matrix: stage Hessians H^x (N, 4, 4), H^u (N, 2), row weights D' and
sigma Hessians h_sigma (N, V), slack Hessians H_s (V,); the Riccati factorization (see
``_riccati_factorize``), its backward pass's scratch p_k (N + 1, 6) and e_k (N, 2); the
columns W of w(s) as their backward passes' e^(j) (V, N, 2) with their gradients (N, 4),
(N, 2); H_s + C_s^T W (V, V) and its Cholesky copy."""


@numba.njit(cache=True, error_model="numpy")
def _offsets(horizon, n_slots):
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
def _constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower, sigma_upper,
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
        out[o_ylo + k] = x[_LATERAL] - bounds[0]
        out[o_yhi + k] = bounds[1] - x[_LATERAL]
        out[o_vlo + k] = x[_SPEED] - bounds[2]
        out[o_vhi + k] = bounds[3] - x[_SPEED]
        for i in range(2):
            out[o_ulo + 2 * k + i] = inputs[k, i] - bounds[4 + i]
            out[o_uhi + 2 * k + i] = bounds[6 + i] - inputs[k, i]
    for j in range(n_slots):
        out[o_slo + j] = slacks[j]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _terminal_cost_to_go(state_hessians, p):
    """P_N = blockdiag(H^x_N, 0) (6, 6) on (x_N, u_{N-1}) into p[N]."""
    horizon = state_hessians.shape[0]
    for a in range(6):
        for b in range(6):
            p[horizon, a, b] = 0.0
    for a in range(4):
        for b in range(4):
            p[horizon, a, b] = state_hessians[horizon - 1, a, b]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _stage_input_hessian(b_k, nxt, input_hessians, k, m):
    """Stage k's m = B^T Pxx + Pux (2, 4) into ``m`` and R^ = H^u_k + B~^T P B~ (2 x 2,
    symmetric), returned as (r00, r01, r11); ``nxt`` is P_{k+1} (6, 6)."""
    for i in range(2):
        for c in range(4):
            acc = nxt[4 + i, c]
            for r in range(4):
                acc += b_k[r, i] * nxt[r, c]
            m[i, c] = acc
    # R^ = H^u + m B + B^T Pxu + Puu
    r00 = input_hessians[k, 0] + nxt[4, 4]
    r01 = nxt[4, 5]
    r11 = input_hessians[k, 1] + nxt[5, 5]
    for r in range(4):
        r00 += m[0, r] * b_k[r, 0] + b_k[r, 0] * nxt[r, 4]
        r01 += m[0, r] * b_k[r, 1] + b_k[r, 0] * nxt[r, 5]
        r11 += m[1, r] * b_k[r, 1] + b_k[r, 1] * nxt[r, 5]
    return r00, r01, r11


@numba.njit(cache=True, error_model="numpy", inline="always")
def _stage_gains(m, a_k, rate_hessian, cholesky, s_hat, y, gains, k):
    """Stage k's S^ = [m A_k, -2S] (2, 6), Y = L^-1 S^ (2, 6) into ``y`` and K_k = -L^-T Y
    (2, 6) into gains[k]; ``cholesky`` is L as (1 / l00, l10, 1 / l11)."""
    inverse00, l10, inverse11 = cholesky[0], cholesky[1], cholesky[2]
    for i in range(2):
        for c in range(4):
            acc = 0.0
            for r in range(4):
                acc += m[i, r] * a_k[r, c]
            s_hat[i, c] = acc
        s_hat[i, 4] = 0.0
        s_hat[i, 5] = 0.0
        s_hat[i, 4 + i] = -rate_hessian[i]
    for c in range(6):
        y0 = s_hat[0, c] * inverse00
        y1 = (s_hat[1, c] - l10 * y0) * inverse11
        y[0, c] = y0
        y[1, c] = y1
        g1 = -y1 * inverse11
        gains[k, 1, c] = g1
        gains[k, 0, c] = -(y0 + l10 * g1) * inverse00


@numba.njit(cache=True, error_model="numpy", inline="always")
def _stage_cost_to_go(nxt, a_k, state_hessians, k, rate_hessian, y, pa, cur):
    """P_k = blockdiag(H^x_k + A_k^T Pxx A_k, 2S) - Y^T Y (6, 6) into ``cur`` from P_{k+1} =
    ``nxt`` (H^x_k is state_hessians[k - 1])."""
    for r in range(4):
        for c in range(4):
            acc = 0.0
            for t in range(4):
                acc += nxt[r, t] * a_k[t, c]
            pa[r, c] = acc
    for r in range(4):
        for c in range(4):
            acc = state_hessians[k - 1, r, c]
            for t in range(4):
                acc += a_k[t, r] * pa[t, c]
            cur[r, c] = acc
    for r in range(4):
        cur[r, 4] = 0.0
        cur[r, 5] = 0.0
        cur[4, r] = 0.0
        cur[5, r] = 0.0
    cur[4, 4] = rate_hessian[0]
    cur[5, 5] = rate_hessian[1]
    cur[4, 5] = 0.0
    cur[5, 4] = 0.0
    for r in range(6):
        for c in range(r, 6):
            value = cur[r, c] - y[0, r] * y[0, c] - y[1, r] * y[1, c]
            cur[r, c] = value
            cur[c, r] = value


@numba.njit(cache=True, error_model="numpy", inline="always")
def _riccati_factorize(state_matrices, input_matrices, state_hessians, input_hessians,
                       rate_hessian, cost_to_go, gains, input_cholesky, scaled_cross):
    """Backward Riccati recursion on the augmented state (x_k, u_{k-1}).

    Stage k cost Hessian: blockdiag(H^x_k, 2S) on (x_k, u_{k-1}), diag(H^u_k) on u_k, cross
    -2S between u_{k-1} and u_k.  Dynamics (x_{k+1}, u_k) = ([A_k 0; 0 0], [B_k; I]).
    With P the cost-to-go Hessian of stage k + 1::

        R^ = H^u_k + B~^T P B~ = L L^T,  S^ = [(B^T Pxx + Pux) A_k, -2S],  Y = L^-1 S^,
        K_k = -R^^-1 S^ = -L^-T Y,  P_k = blockdiag(H^x_k + A_k^T Pxx A_k, 2S) - Y^T Y.

    Writes P_k (k = 1..N; P_N = blockdiag(H^x_N, 0)), K_k, L_k as (1 / l00, l10, 1 / l11) and Y_k
    (k = 0..N-1).  Returns False if some R^ is not (numerically) positive definite.
    """
    horizon = state_matrices.shape[0]
    p = cost_to_go
    _terminal_cost_to_go(state_hessians, p)
    m = np.empty((2, 4))
    s_hat = np.empty((2, 6))
    pa = np.empty((4, 4))
    for k in range(horizon - 1, -1, -1):
        nxt = p[k + 1]
        a_k = state_matrices[k]
        b_k = input_matrices[k]
        r00, r01, r11 = _stage_input_hessian(b_k, nxt, input_hessians, k, m)
        # R^ = L L^T (2x2 Cholesky; explicit inverses lose accuracy when R^ is ill-conditioned)
        if not r00 > 0.0:
            return False
        l00 = np.sqrt(r00)
        l10 = r01 / l00
        pivot = r11 - l10 * l10
        if not pivot > CHOLESKY_PIVOT_FLOOR * r11:
            return False
        l11 = np.sqrt(pivot)
        input_cholesky[k, 0] = 1.0 / l00
        input_cholesky[k, 1] = l10
        input_cholesky[k, 2] = 1.0 / l11
        y = scaled_cross[k]
        _stage_gains(m, a_k, rate_hessian, input_cholesky[k], s_hat, y, gains, k)
        if k == 0:
            break
        cur = p[k]
        _stage_cost_to_go(nxt, a_k, state_hessians, k, rate_hessian, y, pa, cur)
    return True


@numba.njit(cache=True, error_model="numpy", inline="always")
def _riccati_backward(state_matrices, input_matrices, state_gradients, input_gradients,
                      cost_to_go, input_cholesky, scaled_cross, cost_to_go_vector,
                      scaled_feedforward):
    """Backward pass of the LQ model with the factorization of ``_riccati_factorize``.

    Gradients: g^x_k on x_k (k = 1..N, row k - 1), g^u_k on u_k; the dynamics are homogeneous
    (c_k = 0, x_0 = 0, u_{-1} = 0: every iterate satisfies them exactly).  With p_{N} = (g^x_N, 0):
    v = p_{k+1}, r^ = g^u_k + B^T v_x + v_u, e_k = L^-1 r^, p_k = (g^x_k + A^T v_x, 0) - Y_k^T e_k.
    Writes e_k (N, 2) into ``scaled_feedforward`` (the feedforward input is k_k = -L^-T e_k);
    p_k (N + 1, 6) is scratch.  e is linear in the gradients and the model's optimal value is
    -1/2 sum_k |e_k|^2, so g_i^T K^-1 g_j = sum_k e^(i)_k . e^(j)_k (K the reduced Hessian).
    """
    horizon = state_matrices.shape[0]
    p = cost_to_go_vector
    for a in range(6):
        p[horizon, a] = 0.0
    for a in range(4):
        p[horizon, a] = state_gradients[horizon - 1, a]
    for k in range(horizon - 1, -1, -1):
        v = p[k + 1]
        b_k = input_matrices[k]
        r0 = input_gradients[k, 0] + v[4]
        r1 = input_gradients[k, 1] + v[5]
        for r in range(4):
            r0 += b_k[r, 0] * v[r]
            r1 += b_k[r, 1] * v[r]
        e0 = r0 * input_cholesky[k, 0]
        e1 = (r1 - input_cholesky[k, 1] * e0) * input_cholesky[k, 2]
        scaled_feedforward[k, 0] = e0
        scaled_feedforward[k, 1] = e1
        if k == 0:
            break
        a_k = state_matrices[k]
        y = scaled_cross[k]
        for c in range(4):
            acc = state_gradients[k - 1, c]
            for r in range(4):
                acc += a_k[r, c] * v[r]
            p[k, c] = acc - y[0, c] * e0 - y[1, c] * e1
        p[k, 4] = -y[0, 4] * e0 - y[1, 4] * e1
        p[k, 5] = -y[0, 5] * e0 - y[1, 5] * e1


@numba.njit(cache=True, error_model="numpy", inline="always")
def _riccati_forward(state_matrices, input_matrices, gains, input_cholesky, scaled_feedforward,
                     states, inputs):
    """Forward pass of the LQ model: u_k = K_k (x_k, u_{k-1}) + k_k, k_k = -L^-T e_k, and the
    homogeneous dynamics from (x_0, u_{-1}) = 0; writes states (N + 1, 4) and inputs (N, 2)."""
    horizon = state_matrices.shape[0]
    for a in range(4):
        states[0, a] = 0.0
    previous0 = 0.0
    previous1 = 0.0
    for k in range(horizon):
        x = states[k]
        g = gains[k]
        feed1 = -scaled_feedforward[k, 1] * input_cholesky[k, 2]
        feed0 = -(scaled_feedforward[k, 0] + input_cholesky[k, 1] * feed1) * input_cholesky[k, 0]
        u0 = (feed0 + g[0, 0] * x[0] + g[0, 1] * x[1] + g[0, 2] * x[2] + g[0, 3] * x[3]
              + g[0, 4] * previous0 + g[0, 5] * previous1)
        u1 = (feed1 + g[1, 0] * x[0] + g[1, 1] * x[1] + g[1, 2] * x[2] + g[1, 3] * x[3]
              + g[1, 4] * previous0 + g[1, 5] * previous1)
        inputs[k, 0] = u0
        inputs[k, 1] = u1
        a_k = state_matrices[k]
        b_k = input_matrices[k]
        for r in range(4):
            acc = b_k[r, 0] * u0 + b_k[r, 1] * u1
            for c in range(4):
                acc += a_k[r, c] * x[c]
            states[k + 1, r] = acc
        previous0 = u0
        previous1 = u1


@numba.njit(cache=True, error_model="numpy", inline="always")
def _cholesky_solve_in_place(matrix, rhs, n):
    """Solve matrix[:n, :n] x = rhs[:n] (SPD) in place; False if not positive definite."""
    for j in range(n):
        acc = matrix[j, j]
        for t in range(j):
            acc -= matrix[j, t] * matrix[j, t]
        if not acc > 0.0:
            return False
        diag = np.sqrt(acc)
        matrix[j, j] = diag
        for i in range(j + 1, n):
            acc = matrix[i, j]
            for t in range(j):
                acc -= matrix[i, t] * matrix[j, t]
            matrix[i, j] = acc / diag
    for i in range(n):
        acc = rhs[i]
        for t in range(i):
            acc -= matrix[i, t] * rhs[t]
        rhs[i] = acc / matrix[i, i]
    for i in range(n - 1, -1, -1):
        acc = rhs[i]
        for t in range(i + 1, n):
            acc -= matrix[t, i] * rhs[t]
        rhs[i] = acc / matrix[i, i]
    return True


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


@numba.njit(cache=True, error_model="numpy")
def _starting_point(qp, measured_state, initial_inputs, has_sigma, point):
    """Write the starting point w_0 into ``point``.

    Inputs: ``initial_inputs`` (N, 2) clipped into their box, ``INITIAL_INPUT_MARGIN`` of its
    width from the bounds; states rolled out from x_hat through the linear dynamics (so every
    iterate satisfies them exactly and the Newton steps are homogeneous in them); s = 0;
    sigma = sigma_hi / 2 where its box is open, else 0.
    """
    states, inputs, slacks, sigmas = point
    state_matrices, input_matrices, affine_offsets = (qp.state_matrices, qp.input_matrices,
                                                      qp.affine_offsets)
    bounds = qp.bounds
    sigma_upper = qp.sigma_upper
    horizon = state_matrices.shape[0]
    n_slots = qp.coefficients.shape[1]
    for k in range(horizon):
        for i in range(2):
            lo = bounds[4 + i]
            hi = bounds[6 + i]
            margin = INITIAL_INPUT_MARGIN * (hi - lo)
            inputs[k, i] = min(max(initial_inputs[k, i], lo + margin), hi - margin)
    for a in range(4):
        states[0, a] = measured_state[a]
    for k in range(horizon):
        for r in range(4):
            acc = affine_offsets[k, r]
            for c in range(4):
                acc += state_matrices[k, r, c] * states[k, c]
            acc += input_matrices[k, r, 0] * inputs[k, 0] + input_matrices[k, r, 1] * inputs[k, 1]
            states[k + 1, r] = acc
    for j in range(n_slots):
        slacks[j] = 0.0
        for k in range(horizon):
            sigmas[k, j] = 0.5 * sigma_upper[k, j] if has_sigma[k, j] else 0.0


@numba.njit(cache=True, error_model="numpy")
def _starting_inequalities(qp, point, ineq):
    """The cold start of the inequalities: a^T w_0 - b, t_0 = max(a^T w_0 - b, ``INITIAL_SLACK``)
    and z_0 = ``INITIAL_MULTIPLIER`` where active (t = 1, z = 0 elsewhere)."""
    values, active, t, z = ineq.values, ineq.active, ineq.t, ineq.z
    _constraint_values(point.states, point.inputs, point.slacks, point.sigmas, qp.coefficients,
                       qp.row_lower, qp.sigma_upper, qp.bounds, ineq.offsets, values)
    for i in range(values.shape[0]):
        if active[i]:
            t[i] = max(values[i], INITIAL_SLACK)
            z[i] = INITIAL_MULTIPLIER
        else:
            t[i] = 1.0
            z[i] = 0.0


def allocate_workspace(horizon, n_slots):
    """The solver's arrays for an (N, V) QP, allocated once: (point, inequality arrays, gradients,
    Newton matrix, direction) as the named tuples ``_Primal``, ``_InequalityArrays``,
    ``_Gradients``, ``_Newton``, ``_Primal`` (each solve resets what it reads before writing)."""
    m = _offsets(horizon, n_slots)[10]
    point = _Primal(np.empty((horizon + 1, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
                    np.zeros((horizon, n_slots)))
    inequalities = _InequalityArrays(
        np.zeros(m, dtype=np.bool_), np.zeros((horizon, n_slots), dtype=np.bool_),
        *(np.zeros(m) for _ in range(13)), np.zeros((horizon, n_slots)), np.zeros(8))
    gradients = _Gradients(np.empty((horizon, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
                           np.zeros((horizon, n_slots)), np.empty((horizon, 4)),
                           np.empty((horizon, 2)), np.empty(n_slots), np.empty(4), np.empty(4))
    newton = _Newton(
        np.empty((horizon, 4, 4)), np.empty((horizon, 2)), np.zeros((horizon, n_slots)),
        np.ones((horizon, n_slots)), np.empty(n_slots), np.empty((horizon + 1, 6, 6)),
        np.empty((horizon, 2, 6)), np.empty((horizon, 3)), np.empty((horizon, 2, 6)),
        np.empty((horizon + 1, 6)), np.empty((horizon, 2)), np.empty((n_slots, horizon, 2)),
        np.zeros((horizon, 4)), np.zeros((horizon, 2)), np.empty((n_slots, n_slots)),
        np.empty((n_slots, n_slots)))
    direction = _Primal(np.empty((horizon + 1, 4)), np.empty((horizon, 2)), np.zeros(n_slots),
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
        nu[_LATERAL] += z[o_ylo + k - 1] - z[o_yhi + k - 1]
        nu[_SPEED] += z[o_vlo + k - 1] - z[o_vhi + k - 1]
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
    _constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower, sigma_upper,
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
        h[_LATERAL, _LATERAL] += d[o_ylo + k] + d[o_yhi + k]
        h[_SPEED, _SPEED] += d[o_vlo + k] + d[o_vhi + k]
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
    = -sum_k e^(i)_k . e^(j)_k (see ``_riccati_backward``), symmetric."""
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
def _factorize_newton_matrix(qp, ineq, newton):
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
    if not _riccati_factorize(state_matrices, input_matrices, state_hessians, input_hessians,
                              rate_hessian, cost_to_go, gains, input_cholesky, scaled_cross):
        return False
    for j in range(n_observed):
        _slack_column_gradient(j, d[offsets[1] + j], slack_weights[1], coefficients,
                               row_weight, slack_hessian, column_gradients)
        _riccati_backward(state_matrices, input_matrices, column_gradients,
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
        model_state_gradient[k, _LATERAL] += -gamma[o_ylo + k] + gamma[o_yhi + k]
        model_state_gradient[k, _SPEED] += -gamma[o_vlo + k] + gamma[o_vhi + k]
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
def _newton_direction(phase, sigma_centering, mu, qp, ineq, gradients, newton, direction):
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
    _riccati_backward(state_matrices, input_matrices, model_state_gradient, model_input_gradient,
                      cost_to_go, input_cholesky, scaled_cross, cost_to_go_vector,
                      scaled_feedforward)
    _slack_schur_rhs(n_observed, model_slack_gradient, column_scaled, scaled_feedforward,
                     schur_base, schur, step_slacks)
    if not _cholesky_solve_in_place(schur, step_slacks, n_observed):
        return False, np.inf, np.inf
    _add_slack_columns(n_observed, step_slacks, column_scaled, scaled_feedforward)
    _riccati_forward(state_matrices, input_matrices, gains, input_cholesky, scaled_feedforward,
                     step_states, step_inputs)
    _safety_slack_direction(offsets, gamma, d, has_sigma, n_observed, coefficients,
                            sigma_gradient, sigma_hessian, step_states, step_slacks,
                            step_sigmas)
    _constraint_values(step_states, step_inputs, step_slacks, step_sigmas, coefficients,
                       zero_rows, zero_rows, zero_bounds, offsets, values)
    step_primal, step_dual = _inequality_direction(active, z, d, t_inverse, z_inverse, values,
                                                   residuals, gamma, dt, dz)
    if np.isnan(step_primal) or np.isnan(step_dual):
        return False, step_primal, step_dual
    return True, step_primal, step_dual


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
def qp_tuple(last_input, state_matrices, input_matrices, affine_offsets, tracking_reference,
             coefficients, row_lower, sigma_upper, n_observed, state_weight_hessian,
             input_weight_hessian, rate_hessian, slack_weights, bounds):
    """The QP data as the steps' ``_Qp`` tuple (arguments as in ``solve_ltv_mpc_qp``)."""
    return _Qp(last_input, state_matrices, input_matrices, affine_offsets, tracking_reference,
               coefficients, row_lower, sigma_upper, n_observed, state_weight_hessian,
               input_weight_hessian, rate_hessian, slack_weights, bounds)


@numba.njit(cache=True, error_model="numpy")
def prepare_inequalities(qp, workspace):
    """Reset the workspace and mark the QP's active inequalities; returns ``_Inequalities`` on
    the workspace's arrays (t and z are set by a start)."""
    _, arrays, gradients, newton, direction = workspace
    horizon, n_slots = qp.coefficients.shape[0], qp.coefficients.shape[1]
    offsets = _offsets(horizon, n_slots)
    _reset_workspace(arrays, gradients, newton, direction)
    n_active = _active_inequalities(qp.sigma_upper, qp.n_observed, offsets, arrays.active,
                                    arrays.has_sigma)
    return _Inequalities(offsets, arrays.active, arrays.has_sigma, n_active, arrays.values,
                         arrays.t, arrays.z, arrays.d, arrays.residuals, arrays.gamma, arrays.dt,
                         arrays.dz, arrays.dt_aff, arrays.dz_aff, arrays.zero_rows,
                         arrays.zero_bounds, arrays.t_inverse, arrays.z_inverse)


@numba.njit(cache=True, error_model="numpy")
def cold_start(qp, measured_state, initial_inputs, ineq, point):
    """The cold start (``_starting_point``, ``_starting_inequalities``) into point and ineq."""
    _starting_point(qp, measured_state, initial_inputs, ineq.has_sigma, point)
    _starting_inequalities(qp, point, ineq)


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
        if not _factorize_newton_matrix(qp, ineq, newton):
            return STATUS_NUMERICAL_ERROR, iteration
        sigma_centering = 0.0
        step_primal = np.inf
        step_dual = np.inf
        for phase in range(2):  # predictor (affine scaling), then corrector
            ok, step_primal, step_dual = _newton_direction(phase, sigma_centering, mu, qp, ineq,
                                                           gradients, newton, direction)
            if not ok:
                return STATUS_NUMERICAL_ERROR, iteration
            if phase == 0:
                sigma_centering = _mehrotra_centering(ineq, step_primal, step_dual, mu)
        alpha_primal, alpha_dual = _step_lengths(step_primal, step_dual)
        _update_iterate(point, direction, ineq, alpha_primal, alpha_dual, qp.n_observed)
    return STATUS_MAX_ITERATIONS, max_iterations


@numba.njit(cache=True, error_model="numpy")
def solve_cold_in(measured_state, qp, initial_inputs, tolerance, max_iterations, workspace):
    """``solve_ltv_mpc_qp`` on a ``qp_tuple`` in an ``allocate_workspace``: (status, iterations);
    the solution is in ``workspace[0]``."""
    point, _, gradients, newton, direction = workspace
    ineq = prepare_inequalities(qp, workspace)
    cold_start(qp, measured_state, initial_inputs, ineq, point)
    return iterate(qp, point, ineq, gradients, newton, direction, tolerance, max_iterations)


def solve_ltv_mpc_qp(measured_state, last_input, state_matrices, input_matrices,
                     affine_offsets, tracking_reference, coefficients, row_lower, sigma_upper,
                     n_observed, state_weight_hessian, input_weight_hessian, rate_hessian,
                     slack_weights, bounds, initial_inputs, tolerance, max_iterations,
                     states, inputs, slacks, sigmas):
    """Solve the LTV-MPC QP of the module doc from the cold start; writes states (N+1, 4),
    inputs (N, 2), slacks (V,), sigmas (N, V).  Returns (status, iterations).

    Args:
        measured_state, last_input: x_hat (4,), u_hat (2,).
        state_matrices, input_matrices, affine_offsets: A_k (N, 4, 4), B_k (N, 4, 2), c_k (N, 4).
        tracking_reference: (N + 1, 4) x^ref_k (row 0 unused).
        coefficients, row_lower, sigma_upper: collision rows (N, V, 3), h (N, V), sigma_hi (N, V).
        n_observed: V_obs, slots j >= V_obs are empty.
        state_weight_hessian, input_weight_hessian, rate_hessian: diagonals 2Q (4), 2R (2), 2S (2).
        slack_weights: (w_c1, w_c2, w_s1, w_s2).
        bounds: (y_lo, y_hi, v_lo, v_hi, delta_lo, a_lo, delta_hi, a_hi).
        initial_inputs: (N, 2) inputs of the starting point (clipped into their box).
        tolerance: residual and complementarity tolerance (see module doc).
        max_iterations: iteration limit.
    """
    _, arrays, gradients, newton, direction = allocate_workspace(*coefficients.shape[:2])
    qp = qp_tuple(last_input, state_matrices, input_matrices, affine_offsets, tracking_reference,
                  coefficients, row_lower, sigma_upper, n_observed, state_weight_hessian,
                  input_weight_hessian, rate_hessian, slack_weights, bounds)
    workspace = (_Primal(states, inputs, slacks, sigmas), arrays, gradients, newton, direction)
    return solve_cold_in(measured_state, qp, initial_inputs, tolerance, max_iterations, workspace)


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
