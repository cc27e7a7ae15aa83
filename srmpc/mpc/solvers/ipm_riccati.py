"""The Riccati recursion of the interior point's Newton model (``interior_point``, step 2 of its method).

The model is a linear-quadratic optimal control problem on the augmented state (x_k, u_{k-1}) (6 states,
2 inputs), which makes the input-rate cost stage-wise. ``riccati_factorize`` factorizes it once per iteration
(cost-to-go Hessians P_k, gains K_k, the Cholesky factors L_k of the input Hessians and Y_k = L_k^-1 S^_k);
``riccati_backward`` maps a model gradient to the scaled feedforwards e_k (linear in the gradient, so
g_i^T K^-1 g_j = sum_k e^(i)_k . e^(j)_k for the reduced Hessian K); ``riccati_forward`` rolls the model's
minimizer out from e. ``cholesky_solve_in_place`` solves the small dense system of the Schur complement on s.
Only 4x4, 6x6 and 2x2 dense blocks occur: each pass is linear in N.
"""

from __future__ import annotations

import numba
import numpy as np

CHOLESKY_PIVOT_FLOOR = 1e-15
"""Relative size below which a Cholesky pivot counts as zero (not positive definite)."""


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
def riccati_factorize(state_matrices, input_matrices, state_hessians, input_hessians,
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
def riccati_backward(state_matrices, input_matrices, state_gradients, input_gradients,
                     cost_to_go, input_cholesky, scaled_cross, cost_to_go_vector,
                     scaled_feedforward):
    """Backward pass of the LQ model with the factorization of ``riccati_factorize``.

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
def riccati_forward(state_matrices, input_matrices, gains, input_cholesky, scaled_feedforward,
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
def cholesky_solve_in_place(matrix, rhs, n):
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
