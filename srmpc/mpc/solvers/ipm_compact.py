"""The interior point on the leading vehicle slots of a larger QP's arrays: the same floats, in less time.

A QP built for V vehicle slots (``allocate_workspace(N, V)``, a warm-start memory for V slots) whose rows use
only the first n <= V slots is solved by ``solve_compact`` as a QP of max(n, 1) slots: its row data is copied
into a ``CompactQp`` (``allocate_compact``), the workspace is viewed as that of n slots
(``compact_workspace``: views of the leading entries of each array) and the memory translated to the compact
layout and back (``compact_memory``, ``expand_memory``). The solver's loops skip the empty slots' rows and the
order of the others is kept, so the solution is that of the V-slot QP bit for bit; the Riccati passes, one per
slot's slack, are what it saves. The NMPC's SQP (``srmpc.mpc.nmpc``) solves its subproblems this way.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from srmpc.mpc.solvers.interior_point import solve_in
from srmpc.mpc.solvers.ipm_start import WarmStartMemory, allocate_memory
from srmpc.mpc.solvers.ipm_workspace import (
    Gradients,
    InequalityArrays,
    NewtonMatrix,
    Primal,
    inequality_offsets,
    qp_tuple,
)

CompactQp = namedtuple("CompactQp", ["coefficients", "row_lower", "sigma_upper", "memory"])
"""The QP with only its rows' slots (``solve_compact``): row data (flat, room for N 2V 3, N 2V, N 2V values)
and a warm-start memory (``allocate_memory`` for 2V slots) whose leading entries take the compact layout."""


def allocate_compact(horizon: int, n_slots: int) -> CompactQp:
    """``CompactQp`` for horizon N and up to ``n_slots`` QP slots."""
    m = inequality_offsets(horizon, n_slots)[10]
    return CompactQp(np.zeros(horizon * n_slots * 3), np.zeros(horizon * n_slots), np.zeros(horizon * n_slots),
                     allocate_memory(horizon, n_slots, m))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _leading(array, n):
    """The first n entries of a contiguous array (a view)."""
    return array.reshape(array.size)[:n]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _leading_2d(array, rows, columns):
    """The first rows x columns entries of a contiguous array as a (rows, columns) view."""
    return array.reshape(array.size)[:rows * columns].reshape((rows, columns))


@numba.njit(cache=True, error_model="numpy")
def compact_workspace(workspace, n_slots):
    """Views of the leading entries of ``workspace`` (``allocate_workspace(N, V)``) shaped as
    ``allocate_workspace(N, n_slots)``'s arrays, n_slots <= V. A solve reads only what it wrote or
    ``prepare_inequalities`` reset, so it solves in these views as in a fresh workspace of n_slots slots."""
    point, arrays, gradients, newton, direction = workspace
    horizon = point.inputs.shape[0]
    m = inequality_offsets(horizon, n_slots)[10]
    compact_point = Primal(point.states, point.inputs, _leading(point.slacks, n_slots),
                           _leading_2d(point.sigmas, horizon, n_slots))
    compact_direction = Primal(direction.states, direction.inputs, _leading(direction.slacks, n_slots),
                               _leading_2d(direction.sigmas, horizon, n_slots))
    compact_arrays = InequalityArrays(
        _leading(arrays.active, m), _leading_2d(arrays.has_sigma, horizon, n_slots), _leading(arrays.values, m),
        _leading(arrays.t, m), _leading(arrays.z, m), _leading(arrays.d, m), _leading(arrays.residuals, m),
        _leading(arrays.gamma, m), _leading(arrays.dt, m), _leading(arrays.dz, m), _leading(arrays.dt_aff, m),
        _leading(arrays.dz_aff, m), _leading(arrays.t_inverse, m), _leading(arrays.z_inverse, m),
        _leading(arrays.spare, m), _leading_2d(arrays.zero_rows, horizon, n_slots), arrays.zero_bounds)
    compact_gradients = Gradients(
        gradients.states, gradients.inputs, _leading(gradients.slacks, n_slots),
        _leading_2d(gradients.sigmas, horizon, n_slots), gradients.model_states, gradients.model_inputs,
        _leading(gradients.model_slacks, n_slots), gradients.nu, gradients.nu_next)
    columns = newton.column_scaled
    compact_newton = NewtonMatrix(
        newton.state_hessians, newton.input_hessians, _leading_2d(newton.row_weight, horizon, n_slots),
        _leading_2d(newton.sigma_hessian, horizon, n_slots), _leading(newton.slack_hessian, n_slots),
        newton.cost_to_go, newton.gains, newton.input_cholesky, newton.scaled_cross, newton.cost_to_go_vector,
        newton.scaled_feedforward,
        columns.reshape(columns.size)[:n_slots * horizon * 2].reshape((n_slots, horizon, 2)),
        newton.column_gradients, newton.zero_input_gradients, _leading_2d(newton.schur_base, n_slots, n_slots),
        _leading_2d(newton.schur, n_slots, n_slots))
    return compact_point, compact_arrays, compact_gradients, compact_newton, compact_direction


@numba.njit(cache=True, error_model="numpy", inline="always")
def _slot_groups(horizon, n_slots):
    """The starts of the inequality groups with one entry per stage and slot (collision rows, sigma lower, sigma
    upper), of the slack group (one per slot), of the box groups (8 N entries), and m (``inequality_offsets``)."""
    offsets = inequality_offsets(horizon, n_slots)
    return (offsets[0], offsets[2], offsets[3]), offsets[1], offsets[4], offsets[10]


@numba.njit(cache=True, error_model="numpy")
def compact_memory(memory, n_slots, compact):
    """The warm-start ``memory`` of a V-slot QP as the memory of its first n_slots slots, into ``compact``'s
    leading entries (returned as a ``WarmStartMemory`` of views)."""
    horizon, n_full = memory.sigmas.shape
    groups, slack, boxes, m = _slot_groups(horizon, n_slots)
    full_groups, full_slack, full_boxes, full_m = _slot_groups(horizon, n_full)
    out = WarmStartMemory(compact.inputs, _leading(compact.slacks, n_slots),
                          _leading_2d(compact.sigmas, horizon, n_slots), _leading(compact.z, m), compact.valid)
    out.valid[0] = memory.valid[0]
    if not memory.valid[0]:
        return out
    out.inputs[:, :] = memory.inputs
    for j in range(n_slots):
        out.slacks[j] = memory.slacks[j]
        out.z[slack + j] = memory.z[full_slack + j]
        for k in range(horizon):
            out.sigmas[k, j] = memory.sigmas[k, j]
            for group in range(3):
                out.z[groups[group] + k * n_slots + j] = memory.z[full_groups[group] + k * n_full + j]
    out.z[boxes:m] = memory.z[full_boxes:full_m]
    return out


@numba.njit(cache=True, error_model="numpy")
def expand_memory(compact, memory):
    """The memory of a compact QP (``compact_memory``'s) as that of the V-slot QP into ``memory``: the slots past
    the compact ones hold 0 (the values a V-slot solve leaves in its unobserved slots and inactive rows)."""
    memory.valid[0] = compact.valid[0]
    if not compact.valid[0]:
        return
    horizon, n_slots = compact.sigmas.shape
    n_full = memory.sigmas.shape[1]
    groups, slack, boxes, m = _slot_groups(horizon, n_slots)
    full_groups, full_slack, full_boxes, full_m = _slot_groups(horizon, n_full)
    memory.inputs[:, :] = compact.inputs
    memory.slacks[:] = 0.0
    memory.sigmas[:, :] = 0.0
    memory.z[:] = 0.0
    for j in range(n_slots):
        memory.slacks[j] = compact.slacks[j]
        memory.z[full_slack + j] = compact.z[slack + j]
        for k in range(horizon):
            memory.sigmas[k, j] = compact.sigmas[k, j]
            for group in range(3):
                memory.z[full_groups[group] + k * n_full + j] = compact.z[groups[group] + k * n_slots + j]
    memory.z[full_boxes:full_m] = compact.z[boxes:m]


@numba.njit(cache=True, error_model="numpy")
def compact_multipliers(workspace, n_rows):
    """The inequality multipliers z (m,) of the last QP that ``solve_compact`` solved with n_rows vehicle rows
    (a view into ``workspace``), and the starts of its inequality groups (``inequality_offsets``' layout on
    max(n_rows, 1) slots: rows, slack lower, sigma lower, sigma upper, y lower, y upper, v lower, v upper, input
    lower, input upper, then m)."""
    n_slots = max(n_rows, 1)
    offsets = inequality_offsets(workspace[0].inputs.shape[0], n_slots)
    return _leading(workspace[1].z, offsets[10]), offsets


@numba.njit(cache=True, error_model="numpy")
def solve_compact(qp, n_rows, measured_state, qp_settings, workspace, memory, compact):
    """The QP in ``qp``'s arrays with its n_rows vehicle rows, solved by ``solve_in`` as
    ``RiccatiInteriorPointSolver.solve`` solves it, but on a QP of max(n_rows, 1) slots instead of the V of
    ``workspace`` (in ``compact_workspace`` views, the warm-start memory translated by ``compact_memory`` and
    ``expand_memory``): the same floats (the solver's loops skip the empty slots' rows, and the order of the
    others is kept), in less time. Returns (status, iterations, the solution as a ``Primal`` of the compact
    QP).

    ``qp`` holds the stage-wise arrays of ``LtvMpcQp`` by name (last_input, state_matrices, input_matrices,
    affine_offsets, tracking_reference, linearization_inputs, coefficients, row_lower, sigma_upper); ``qp_settings``
    the solver's (constants: ``SolverConstants``, tolerance, max_iterations, warm_start, warm_start_settings).
    """
    horizon = qp.coefficients.shape[0]
    n_slots = max(n_rows, 1)
    coefficients = compact.coefficients[:horizon * n_slots * 3].reshape((horizon, n_slots, 3))
    row_lower = _leading_2d(compact.row_lower, horizon, n_slots)
    sigma_upper = _leading_2d(compact.sigma_upper, horizon, n_slots)
    for k in range(horizon):
        for j in range(n_slots):
            coefficients[k, j, 0] = qp.coefficients[k, j, 0]
            coefficients[k, j, 1] = qp.coefficients[k, j, 1]
            coefficients[k, j, 2] = qp.coefficients[k, j, 2]
            row_lower[k, j] = qp.row_lower[k, j]
            sigma_upper[k, j] = qp.sigma_upper[k, j]
    constants = qp_settings.constants
    problem = qp_tuple(qp.last_input, qp.state_matrices, qp.input_matrices, qp.affine_offsets, qp.tracking_reference,
                       coefficients, row_lower, sigma_upper, n_rows, constants.state_weight_hessian,
                       constants.input_weight_hessian, constants.rate_hessian, constants.slack_weights,
                       constants.bounds)
    compact_work = compact_workspace(workspace, n_slots)
    compact_memory_ = compact_memory(memory, n_slots, compact.memory)
    status, iterations, _ = solve_in(measured_state, problem, qp.linearization_inputs, qp_settings.tolerance,
                                     qp_settings.max_iterations, compact_work, compact_memory_,
                                     qp_settings.warm_start, qp_settings.warm_start_settings)
    expand_memory(compact_memory_, memory)
    return status, iterations, compact_work[0]
