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
3. a Schur complement on s: w(s) = w_0 + W s with W's columns from the same factorization
   (one backward-forward substitution per observed vehicle), then a V_obs x V_obs Cholesky
   solve of (H_s + C_s^T W) s = -(g_s + C_s^T w_0).

Per iteration this costs one factorization, V_obs + 2 substitutions and O(N V) vector work:
linear in N, with 4x4 and 2x2 dense blocks only.

Termination: inequality residual max|C w - h - t| <= tol, dual residual (stationarity with the
dynamics multipliers nu recovered by the backward recursion nu_k = A_k^T nu_{k+1} - grad_x_k L)
<= tol (1 + scale), mean complementarity mu <= tol.  Returns a status code; anything other than
``STATUS_SOLVED`` must be treated as a failed solve.
"""

from __future__ import annotations

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


@numba.njit(cache=True, error_model="numpy")
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


@numba.njit(cache=True, error_model="numpy")
def _riccati_factorize(state_matrices, input_matrices, state_hessians, input_hessians,
                       rate_hessian, cost_to_go, gains, input_cholesky, scaled_cross):
    """Backward Riccati recursion on the augmented state (x_k, u_{k-1}).

    Stage k cost Hessian: blockdiag(H^x_k, 2S) on (x_k, u_{k-1}), diag(H^u_k) on u_k, cross
    -2S between u_{k-1} and u_k.  Dynamics (x_{k+1}, u_k) = ([A_k 0; 0 0], [B_k; I]).
    With P the cost-to-go Hessian of stage k + 1::

        R^ = H^u_k + B~^T P B~ = L L^T,  S^ = [(B^T Pxx + Pux) A_k, -2S],  Y = L^-1 S^,
        K_k = -R^^-1 S^ = -L^-T Y,  P_k = blockdiag(H^x_k + A_k^T Pxx A_k, 2S) - Y^T Y.

    Writes P_k (k = 1..N; P_N = blockdiag(H^x_N, 0)), K_k, L_k as (l00, l10, l11) and Y_k
    (k = 0..N-1).  Returns False if some R^ is not (numerically) positive definite.
    """
    horizon = state_matrices.shape[0]
    p = cost_to_go
    for a in range(6):
        for b in range(6):
            p[horizon, a, b] = 0.0
    for a in range(4):
        for b in range(4):
            p[horizon, a, b] = state_hessians[horizon - 1, a, b]
    m = np.empty((2, 4))
    s_hat = np.empty((2, 6))
    pa = np.empty((4, 4))
    for k in range(horizon - 1, -1, -1):
        nxt = p[k + 1]
        a_k = state_matrices[k]
        b_k = input_matrices[k]
        # m = B^T Pxx + Pux
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
        # R^ = L L^T (2x2 Cholesky; explicit inverses lose accuracy when R^ is ill-conditioned)
        if not r00 > 0.0:
            return False
        l00 = np.sqrt(r00)
        l10 = r01 / l00
        pivot = r11 - l10 * l10
        if not pivot > CHOLESKY_PIVOT_FLOOR * r11:
            return False
        l11 = np.sqrt(pivot)
        input_cholesky[k, 0] = l00
        input_cholesky[k, 1] = l10
        input_cholesky[k, 2] = l11
        # S^ = [m A, -2S]
        for i in range(2):
            for c in range(4):
                acc = 0.0
                for r in range(4):
                    acc += m[i, r] * a_k[r, c]
                s_hat[i, c] = acc
            s_hat[i, 4] = 0.0
            s_hat[i, 5] = 0.0
            s_hat[i, 4 + i] = -rate_hessian[i]
        # Y = L^-1 S^,  K = -L^-T Y
        y = scaled_cross[k]
        for c in range(6):
            y0 = s_hat[0, c] / l00
            y1 = (s_hat[1, c] - l10 * y0) / l11
            y[0, c] = y0
            y[1, c] = y1
            g1 = -y1 / l11
            gains[k, 1, c] = g1
            gains[k, 0, c] = -(y0 + l10 * g1) / l00
        if k == 0:
            break
        # P_k = blockdiag(H^x_k + A^T Pxx A, 2S) + S^^T K
        cur = p[k]
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
    return True


@numba.njit(cache=True, error_model="numpy")
def _riccati_solve(state_matrices, input_matrices, affine_offsets, state_gradients,
                   input_gradients, initial_state, initial_input, cost_to_go, gains,
                   input_cholesky, scaled_cross, homogeneous, cost_to_go_vector, feedforward,
                   states, inputs):
    """Minimize the LQ model with the factorization of ``_riccati_factorize``.

    Gradients: g^x_k on x_k (k = 1..N, row k - 1), g^u_k on u_k.  With ``homogeneous`` the
    offsets c_k and the initial (x_0, u_{-1}) are taken as zero (columns of W).
    Backward: v = P_{k+1} (c_k, 0) + p_{k+1}, r^ = g^u_k + B^T v_x + v_u, e = L^-1 r^,
    k_k = -L^-T e, p_k = (g^x_k + A^T v_x, 0) - Y_k^T e.  Forward: u_k = K_k (x_k, u_{k-1}) + k_k.
    """
    horizon = state_matrices.shape[0]
    p = cost_to_go_vector
    for a in range(6):
        p[horizon, a] = 0.0
    for a in range(4):
        p[horizon, a] = state_gradients[horizon - 1, a]
    v = np.empty(6)
    for k in range(horizon - 1, -1, -1):
        nxt = cost_to_go[k + 1]
        for a in range(6):
            acc = p[k + 1, a]
            if not homogeneous:
                for b in range(4):
                    acc += nxt[a, b] * affine_offsets[k, b]
            v[a] = acc
        b_k = input_matrices[k]
        r0 = input_gradients[k, 0] + v[4]
        r1 = input_gradients[k, 1] + v[5]
        for r in range(4):
            r0 += b_k[r, 0] * v[r]
            r1 += b_k[r, 1] * v[r]
        l00 = input_cholesky[k, 0]
        l10 = input_cholesky[k, 1]
        l11 = input_cholesky[k, 2]
        e0 = r0 / l00
        e1 = (r1 - l10 * e0) / l11
        feedforward[k, 1] = -e1 / l11
        feedforward[k, 0] = -(e0 + l10 * feedforward[k, 1]) / l00
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
    augmented = np.empty(6)
    for a in range(4):
        augmented[a] = 0.0 if homogeneous else initial_state[a]
        states[0, a] = augmented[a]
    augmented[4] = 0.0 if homogeneous else initial_input[0]
    augmented[5] = 0.0 if homogeneous else initial_input[1]
    for k in range(horizon):
        for i in range(2):
            acc = feedforward[k, i]
            for c in range(6):
                acc += gains[k, i, c] * augmented[c]
            inputs[k, i] = acc
        a_k = state_matrices[k]
        b_k = input_matrices[k]
        for r in range(4):
            acc = 0.0 if homogeneous else affine_offsets[k, r]
            for c in range(4):
                acc += a_k[r, c] * augmented[c]
            acc += b_k[r, 0] * inputs[k, 0] + b_k[r, 1] * inputs[k, 1]
            states[k + 1, r] = acc
        for r in range(4):
            augmented[r] = states[k + 1, r]
        augmented[4] = inputs[k, 0]
        augmented[5] = inputs[k, 1]


@numba.njit(cache=True, error_model="numpy")
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


@numba.njit(cache=True, error_model="numpy")
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
def solve_ltv_mpc_qp(measured_state, last_input, state_matrices, input_matrices,
                     affine_offsets, tracking_reference, coefficients, row_lower, sigma_upper,
                     n_observed, state_weight_hessian, input_weight_hessian, rate_hessian,
                     slack_weights, bounds, initial_inputs, tolerance, max_iterations,
                     states, inputs, slacks, sigmas):
    """Solve the LTV-MPC QP of the module doc; writes states (N+1, 4), inputs (N, 2),
    slacks (V,), sigmas (N, V).  Returns (status, iterations).

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
    horizon = state_matrices.shape[0]
    n_slots = coefficients.shape[1]
    offsets = _offsets(horizon, n_slots)
    (o_row, o_slo, o_sglo, o_sghi, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, m) = offsets
    w_s2 = slack_weights[3]
    w_c2 = slack_weights[1]

    # which inequalities exist: rows/slacks of observed slots, sigma boxes of positive width
    active = np.zeros(m, dtype=np.bool_)
    has_sigma = np.zeros((horizon, n_slots), dtype=np.bool_)
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

    # ---- starting point: inputs inside their box, states by the linear dynamics (so every
    # iterate satisfies the dynamics exactly and the Newton steps are homogeneous in them)
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
    values = np.empty(m)
    _constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower, sigma_upper,
                       bounds, offsets, values)
    t = np.ones(m)
    z = np.zeros(m)
    for i in range(m):
        if active[i]:
            t[i] = max(values[i], INITIAL_SLACK)
            z[i] = INITIAL_MULTIPLIER

    # ---- work arrays
    state_hessians = np.empty((horizon, 4, 4))
    input_hessians = np.empty((horizon, 2))
    state_gradient = np.empty((horizon, 4))
    input_gradient = np.empty((horizon, 2))
    slack_gradient = np.zeros(n_slots)
    sigma_gradient = np.zeros((horizon, n_slots))
    model_state_gradient = np.empty((horizon, 4))
    model_input_gradient = np.empty((horizon, 2))
    model_slack_gradient = np.empty(n_slots)
    row_weight = np.zeros((horizon, n_slots))  # D' of each row after eliminating sigma
    sigma_hessian = np.ones((horizon, n_slots))
    slack_hessian = np.empty(n_slots)
    cost_to_go = np.empty((horizon + 1, 6, 6))
    gains = np.empty((horizon, 2, 6))
    input_cholesky = np.empty((horizon, 3))
    scaled_cross = np.empty((horizon, 2, 6))
    cost_to_go_vector = np.empty((horizon + 1, 6))
    feedforward = np.empty((horizon, 2))
    column_states = np.empty((n_slots, horizon + 1, 4))
    column_inputs = np.empty((n_slots, horizon, 2))
    column_gradients = np.zeros((horizon, 4))
    zero_input_gradients = np.zeros((horizon, 2))
    schur_base = np.empty((n_slots, n_slots))
    schur = np.empty((n_slots, n_slots))
    step_states = np.empty((horizon + 1, 4))
    step_inputs = np.empty((horizon, 2))
    step_slacks = np.zeros(n_slots)
    step_sigmas = np.zeros((horizon, n_slots))
    zero_rows = np.zeros((horizon, n_slots))
    zero_bounds = np.zeros(8)
    primal_residuals = np.zeros(m)
    gamma = np.empty(m)
    d = np.empty(m)
    dt = np.zeros(m)
    dz = np.zeros(m)
    dt_aff = np.zeros(m)
    dz_aff = np.zeros(m)
    nu = np.empty(4)
    nu_next = np.empty(4)
    zero4 = np.zeros(4)
    zero2 = np.zeros(2)

    for iteration in range(max_iterations + 1):
        # ---------------- residuals at the current point
        _constraint_values(states, inputs, slacks, sigmas, coefficients, row_lower,
                           sigma_upper, bounds, offsets, values)
        _objective_gradient(states, inputs, slacks, sigmas, tracking_reference, last_input,
                            state_weight_hessian, input_weight_hessian, rate_hessian,
                            slack_weights, n_observed, has_sigma, state_gradient,
                            input_gradient, slack_gradient, sigma_gradient)
        primal_residual = 0.0
        mu = 0.0
        for i in range(m):
            if active[i]:
                primal_residuals[i] = values[i] - t[i]
                primal_residual = max(primal_residual, abs(primal_residuals[i]))
                mu += t[i] * z[i]
        mu /= n_active
        # dual residual, with nu_k = A_k^T nu_{k+1} - grad_x_k L making the x rows exact
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
        if not (np.isfinite(mu) and np.isfinite(dual_residual)):
            return STATUS_NUMERICAL_ERROR, iteration
        if (primal_residual <= tolerance and mu <= tolerance
                and dual_residual <= tolerance * dual_scale):
            return STATUS_SOLVED, iteration
        if iteration == max_iterations:
            break

        # ---------------- Newton matrix: D, stage Hessians, Riccati, Schur on s
        for i in range(m):
            d[i] = z[i] / t[i] if active[i] else 0.0
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
        if not _riccati_factorize(state_matrices, input_matrices, state_hessians,
                                  input_hessians, rate_hessian, cost_to_go, gains,
                                  input_cholesky, scaled_cross):
            return STATUS_NUMERICAL_ERROR, iteration
        for j in range(n_observed):
            slack_hessian[j] = 2.0 * w_c2 + d[o_slo + j]
            for k in range(horizon):
                weight = row_weight[k, j]
                slack_hessian[j] += weight
                for a in range(3):
                    column_gradients[k, a] = weight * coefficients[k, j, a]
            _riccati_solve(state_matrices, input_matrices, affine_offsets, column_gradients,
                           zero_input_gradients, zero4, zero2, cost_to_go, gains,
                           input_cholesky, scaled_cross, True, cost_to_go_vector, feedforward,
                           column_states[j], column_inputs[j])
        # Schur complement H_s + C_s^T W (C_s^T W_j = sum_k D'_ki n_ki . Wx_j,k)
        for i in range(n_observed):
            for j in range(n_observed):
                acc = slack_hessian[i] if i == j else 0.0
                for k in range(horizon):
                    weight = row_weight[k, i]
                    for a in range(3):
                        acc += weight * coefficients[k, i, a] * column_states[j, k + 1, a]
                schur_base[i, j] = acc

        # ---------------- predictor (phase 0) and corrector (phase 1)
        sigma_centering = 0.0
        step_primal = np.inf
        step_dual = np.inf
        for phase in range(2):
            for i in range(m):
                if not active[i]:
                    gamma[i] = 0.0
                elif phase == 0:
                    gamma[i] = -d[i] * primal_residuals[i]
                else:
                    gamma[i] = ((sigma_centering * mu - dt_aff[i] * dz_aff[i]) / t[i]
                                - d[i] * primal_residuals[i])
            # model gradient grad f - C^T gamma, with each sigma eliminated from its row
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
            _riccati_solve(state_matrices, input_matrices, affine_offsets, model_state_gradient,
                           model_input_gradient, zero4, zero2, cost_to_go, gains,
                           input_cholesky, scaled_cross, True, cost_to_go_vector, feedforward,
                           step_states, step_inputs)
            # ds = -(H_s + C_s^T W)^-1 (g_s + C_s^T dw_0)
            for i in range(n_observed):
                acc = model_slack_gradient[i]
                for k in range(horizon):
                    weight = row_weight[k, i]
                    for a in range(3):
                        acc += weight * coefficients[k, i, a] * step_states[k + 1, a]
                step_slacks[i] = -acc
                for j in range(n_observed):
                    schur[i, j] = schur_base[i, j]
            if not _cholesky_solve_in_place(schur, step_slacks, n_observed):
                return STATUS_NUMERICAL_ERROR, iteration
            for j in range(n_observed):
                s_j = step_slacks[j]
                for k in range(horizon):
                    for a in range(4):
                        step_states[k + 1, a] += s_j * column_states[j, k + 1, a]
                    step_inputs[k, 0] += s_j * column_inputs[j, k, 0]
                    step_inputs[k, 1] += s_j * column_inputs[j, k, 1]
            # dsigma from its row: -(D_r d_rho + g_sigma - gamma_r) / (D_r + h_sigma)
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
            # dt = C dw + r_p;  dz = (sigma mu - dt_aff dz_aff) / t - z - D dt
            _constraint_values(step_states, step_inputs, step_slacks, step_sigmas, coefficients,
                               zero_rows, zero_rows, zero_bounds, offsets, values)
            step_primal = np.inf
            step_dual = np.inf
            for i in range(m):
                if not active[i]:
                    continue
                dti = values[i] + primal_residuals[i]
                if phase == 0:
                    dzi = -z[i] - d[i] * dti
                else:
                    dzi = ((sigma_centering * mu - dt_aff[i] * dz_aff[i]) / t[i]
                           - z[i] - d[i] * dti)
                dt[i] = dti
                dz[i] = dzi
                if dti < 0.0:
                    step_primal = min(step_primal, -t[i] / dti)
                if dzi < 0.0:
                    step_dual = min(step_dual, -z[i] / dzi)
            if np.isnan(step_primal) or np.isnan(step_dual):
                return STATUS_NUMERICAL_ERROR, iteration
            if phase == 0:
                mu_affine = 0.0
                alpha_primal = min(1.0, step_primal)
                alpha_dual = min(1.0, step_dual)
                for i in range(m):
                    if active[i]:
                        dt_aff[i] = dt[i]
                        dz_aff[i] = dz[i]
                        mu_affine += (t[i] + alpha_primal * dt[i]) * (z[i] + alpha_dual * dz[i])
                mu_affine /= n_active
                ratio = mu_affine / mu
                sigma_centering = ratio * ratio * ratio
        # ---------------- take the step
        alpha_primal = min(1.0, FRACTION_TO_BOUNDARY * step_primal)
        alpha_dual = min(1.0, FRACTION_TO_BOUNDARY * step_dual)
        for k in range(horizon):
            for a in range(4):
                states[k + 1, a] += alpha_primal * step_states[k + 1, a]
            for i in range(2):
                inputs[k, i] += alpha_primal * step_inputs[k, i]
            for j in range(n_observed):
                sigmas[k, j] += alpha_primal * step_sigmas[k, j]
        for j in range(n_observed):
            slacks[j] += alpha_primal * step_slacks[j]
        for i in range(m):
            if active[i]:
                t[i] += alpha_primal * dt[i]
                z[i] += alpha_dual * dz[i]
    return STATUS_MAX_ITERATIONS, max_iterations


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
