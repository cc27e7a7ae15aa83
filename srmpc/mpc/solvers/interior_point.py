"""Structure-exploiting primal-dual interior-point solver for the LTV-MPC QP (HPIPM style): the solves.

Solves exactly the QP that ``problem.qp_builder.LtvMpcQp`` assembles (same variables, objective and
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

Warm start: ``solve_in`` starts from the shifted previous solution when asked to and its memory is valid
(``ipm_start``); if the warm-started iterations do not reach ``STATUS_SOLVED`` within the warm start's
iteration limit (its settings'; at most ``max_iterations``), the QP is solved again from the cold start (the
reported iterations are then the sum). A failed or absent previous solution (new episode,
a fallback step) means the cold start.

Code layout, one module per part, in the order a solve runs them:

- ``ipm_workspace``: the QP as a tuple (``qp_tuple``), the inequalities' layout, the arrays allocated once
  (``allocate_workspace``) and the active inequalities (``prepare_inequalities``);
- ``ipm_start``: the starting points, cold (``cold_start``) and warm (``warm_start``);
- ``ipm_iteration``: ``iterate``, per iteration the residuals and the termination test, the Newton
  matrix and the predictor's and corrector's directions (``ipm_newton``, on the Riccati recursion of
  ``ipm_riccati``), Mehrotra's centering, the step lengths and the update;
- this module: the solves (``solve_cold_in``, ``solve_in``, ``solve_ltv_mpc_qp``).

The steps are compiled functions that receive the solver's arrays grouped in the named tuples
``QpData`` (the QP data), ``Primal`` (a point or a direction), ``Inequalities``, ``Gradients`` and
``NewtonMatrix`` (``ipm_workspace``); each unpacks what it needs and calls helpers on plain arrays that are
compiled into it (``inline="always"``).  Tuples passed into inlined helpers, or compiled calls out of a step,
leave numba reference-count updates on every array per call that its pruning pass cannot remove (they cost
about 15% of the solve time).  ``solve_ltv_mpc_qp`` allocates the arrays per call.
"""

from __future__ import annotations

import numba

from srmpc.mpc.solvers.ipm_iteration import STATUS_SOLVED, iterate
from srmpc.mpc.solvers.ipm_start import WARM_START_SETTINGS, cold_start, remember, warm_start
from srmpc.mpc.solvers.ipm_workspace import Primal, allocate_workspace, prepare_inequalities, qp_tuple


@numba.njit(cache=True, error_model="numpy")
def solve_cold_in(measured_state, qp, initial_inputs, tolerance, max_iterations, workspace):
    """``solve_ltv_mpc_qp`` on a ``qp_tuple`` in an ``allocate_workspace``: (status, iterations);
    the solution is in ``workspace[0]``."""
    point, _, gradients, newton, direction = workspace
    ineq = prepare_inequalities(qp, workspace)
    cold_start(qp, measured_state, initial_inputs, ineq, point)
    return iterate(qp, point, ineq, gradients, newton, direction, tolerance, max_iterations)


@numba.njit(cache=True, error_model="numpy")
def solve_in(measured_state, qp, initial_inputs, tolerance, max_iterations, workspace, memory,
             warm, settings=WARM_START_SETTINGS):
    """Solve a ``qp_tuple`` in an ``allocate_workspace``, warm if ``warm`` and ``memory`` is valid, else
    from the cold start about ``initial_inputs`` (as ``solve_ltv_mpc_qp``); a failed warm start is retried cold.

    ``settings``: ``WARM_START_SETTINGS``' layout (its last entry bounds the warm iterations). Returns (status,
    iterations, started warm); the solution is in ``workspace[0]``, and in ``memory`` for the next call if solved.
    """
    point, arrays, gradients, newton, direction = workspace
    iterations = 0
    started_warm = warm and memory.valid[0]
    if started_warm:
        ineq = prepare_inequalities(qp, workspace)
        warm_start(qp, measured_state, memory, ineq, point, direction.inputs, settings)
        status, iterations = iterate(qp, point, ineq, gradients, newton, direction, tolerance,
                                     min(settings[4], max_iterations))
        if status == STATUS_SOLVED:
            remember(point, ineq, memory)
            return status, iterations, True
    ineq = prepare_inequalities(qp, workspace)
    cold_start(qp, measured_state, initial_inputs, ineq, point)
    status, cold_iterations = iterate(qp, point, ineq, gradients, newton, direction, tolerance,
                                      max_iterations)
    if status == STATUS_SOLVED:
        remember(point, ineq, memory)
    else:
        memory.valid[0] = False
    return status, iterations + cold_iterations, started_warm


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
    workspace = (Primal(states, inputs, slacks, sigmas), arrays, gradients, newton, direction)
    return solve_cold_in(measured_state, qp, initial_inputs, tolerance, max_iterations, workspace)
