"""The interior point's starting points (``interior_point``): cold, and warm from the (shifted) previous solution.

Cold start (``cold_start``): the inputs ``initial_inputs`` (N, 2) clipped into their box, ``INITIAL_INPUT_MARGIN``
of its width from the bounds; the states rolled out from x_hat through the linear dynamics (so every iterate
satisfies them exactly and the Newton steps are homogeneous in them); s = 0; sigma = sigma_hi / 2 where its box
is open, else 0; t_0 = max(a^T w_0 - b, ``INITIAL_SLACK``), z_0 = ``INITIAL_MULTIPLIER``.

Warm start (``warm_start``). Consecutive planner QPs differ by one control period, so the previous solution,
shifted by one stage, is close to the new one. When the previous solve succeeded, the start is:

1. primal: the previous inputs shifted, u = (u_1, ..., u_{N-1}, u_{N-1}), clipped as the cold start
   clips them and rolled out from x_hat through the new linear dynamics (every iterate keeps satisfying
   them exactly, as from the cold start); collision slacks s_j the previous ones; safety slacks
   sigma_kj the previous stage k + 1's (the last stage repeated), clipped into [0, sigma_hi] (0 where
   sigma is fixed or the slot is empty);
2. dual: the previous inequality multipliers z, shifted the same way (each inequality group is one
   block per stage, or per slot for s_j >= 0);
3. slacks t_i = max(a_i^T w - b_i, ``WARM_SLACK_FLOOR``) at that primal point;
4. safeguarded centrality correction: the previous solution is at mu ~ tolerance, where a shifted,
   not yet optimal point would stall against the boundary. Every pair is lifted to t_i z_i >=
   ``WARM_CENTRALITY`` mu_0 (z_i raised) with mu_0 = max(mean t z, ``WARM_START_MU``), so the
   iterations start from a well-centred point of complementarity about mu_0.

The shift is the settings' stage shift: 1 for the planner's QPs, 0 for the QPs of one SQP solve (all at one
instant; ``srmpc.mpc.nmpc``, which writes the memory's primal part and reorders its vehicle slots with
``reorder_memory_slots`` before each warm solve). A warm start that has not solved the QP after the settings'
iteration limit is abandoned and the QP solved again from the cold start (``interior_point.solve_in``).

The memory of the last solved QP (``WarmStartMemory``) is kept by ``remember``; the solves that use both
starts are ``interior_point.solve_in`` and ``solve_cold_in``.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from srmpc.mpc.solvers.ipm_workspace import constraint_values, inequality_offsets

INITIAL_SLACK = 1.0
"""Lower bound on the starting inequality slacks t_0 = max(a^T w_0 - b, .) (constraint units)."""
INITIAL_MULTIPLIER = 100.0
"""Starting inequality multipliers z_0 (objective units per constraint unit)."""
INITIAL_INPUT_MARGIN = 0.01
"""The starting inputs keep this fraction of their box width from its bounds (dimensionless)."""

WARM_START_MU = 1e-1
"""Lowest complementarity mu_0 of a warm start (objective units): lower stalls the shifted point."""
WARM_CENTRALITY = 0.5
"""Each warm pair starts with t_i z_i >= this fraction of mu_0 (dimensionless)."""
WARM_SLACK_FLOOR = 1e-1
"""Smallest starting slack t_i of a warm start (constraint units)."""

WARM_STAGE_SHIFT = 1
"""Stages the previous solution is shifted by (stages): the planner's consecutive QPs are one control period apart."""
WARM_MAX_ITERATIONS = 50
"""Most iterations of a warm-started solve before it is retried cold (iterations); ``RiccatiInteriorPointSolver``
puts its own ``max_iterations`` here, so that the planner's warm start is bounded by that limit alone."""

WARM_START_SETTINGS = (WARM_START_MU, WARM_CENTRALITY, WARM_SLACK_FLOOR, WARM_STAGE_SHIFT, WARM_MAX_ITERATIONS)
"""The warm start's (mu_0 floor, centrality fraction, slack floor, stage shift, iteration limit), the planner's;
``interior_point.solve_in``'s ``settings``."""

WarmStartMemory = namedtuple("WarmStartMemory", ["inputs", "slacks", "sigmas", "z", "valid"])
"""The last solved QP's inputs (N, 2), slacks (V,), sigmas (N, V), multipliers z (m,); valid (1,) bool:
whether they come from a solved QP (cleared by a failed solve and a new episode)."""


def allocate_memory(horizon: int, n_slots: int, n_inequalities: int) -> WarmStartMemory:
    """An empty (invalid) memory for an (N, V) QP with m inequalities."""
    return WarmStartMemory(np.zeros((horizon, 2)), np.zeros(n_slots), np.zeros((horizon, n_slots)),
                           np.zeros(n_inequalities), np.zeros(1, dtype=np.bool_))


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
    constraint_values(point.states, point.inputs, point.slacks, point.sigmas, qp.coefficients,
                      qp.row_lower, qp.sigma_upper, qp.bounds, ineq.offsets, values)
    for i in range(values.shape[0]):
        if active[i]:
            t[i] = max(values[i], INITIAL_SLACK)
            z[i] = INITIAL_MULTIPLIER
        else:
            t[i] = 1.0
            z[i] = 0.0


@numba.njit(cache=True, error_model="numpy")
def cold_start(qp, measured_state, initial_inputs, ineq, point):
    """The cold start (module doc; ``_starting_point``, ``_starting_inequalities``) into point and ineq."""
    _starting_point(qp, measured_state, initial_inputs, ineq.has_sigma, point)
    _starting_inequalities(qp, point, ineq)


@numba.njit(cache=True, error_model="numpy")
def _shift_multipliers(offsets, horizon, n_slots, previous, out, shift):
    """z shifted ``shift`` stages per group (module doc, item 2; the last stage repeated); s_j >= 0 rows keep
    their slot."""
    (o_row, o_slo, o_sglo, o_sghi, o_ylo, o_yhi, o_vlo, o_vhi, o_ulo, o_uhi, _) = offsets
    for start, width in ((o_row, n_slots), (o_sglo, n_slots), (o_sghi, n_slots), (o_ylo, 1),
                         (o_yhi, 1), (o_vlo, 1), (o_vhi, 1), (o_ulo, 2), (o_uhi, 2)):
        for k in range(horizon):
            source = min(k + shift, horizon - 1)
            for r in range(width):
                out[start + k * width + r] = previous[start + source * width + r]
    for j in range(n_slots):
        out[o_slo + j] = previous[o_slo + j]


@numba.njit(cache=True, error_model="numpy")
def _warm_primal(qp, measured_state, memory, has_sigma, shifted_inputs, point, shift):
    """Module doc, item 1, shifted ``shift`` stages, into ``point`` (``shifted_inputs`` (N, 2) is scratch)."""
    horizon = shifted_inputs.shape[0]
    for k in range(horizon):
        source = min(k + shift, horizon - 1)
        shifted_inputs[k, 0] = memory.inputs[source, 0]
        shifted_inputs[k, 1] = memory.inputs[source, 1]
    _starting_point(qp, measured_state, shifted_inputs, has_sigma, point)
    for j in range(qp.n_observed):
        point.slacks[j] = max(memory.slacks[j], 0.0)
        for k in range(horizon):
            if has_sigma[k, j]:
                sigma = memory.sigmas[min(k + shift, horizon - 1), j]
                point.sigmas[k, j] = min(max(sigma, 0.0), qp.sigma_upper[k, j])


@numba.njit(cache=True, error_model="numpy")
def _warm_inequalities(qp, memory, point, ineq, settings):
    """Module doc, items 2-4: t and z of the warm start on the active rows (t = 1, z = 0 elsewhere)."""
    horizon, n_slots = qp.coefficients.shape[0], qp.coefficients.shape[1]
    mu_floor, centrality, slack_floor, shift, _ = settings
    values, active, t, z = ineq.values, ineq.active, ineq.t, ineq.z
    constraint_values(point.states, point.inputs, point.slacks, point.sigmas, qp.coefficients,
                      qp.row_lower, qp.sigma_upper, qp.bounds, ineq.offsets, values)
    _shift_multipliers(ineq.offsets, horizon, n_slots, memory.z, z, shift)
    complementarity = 0.0
    for i in range(values.shape[0]):
        if active[i]:
            t[i] = max(values[i], slack_floor)
            z[i] = max(z[i], 0.0)
            complementarity += t[i] * z[i]
        else:
            t[i] = 1.0
            z[i] = 0.0
    mu = max(complementarity / ineq.n_active, mu_floor)
    for i in range(values.shape[0]):
        if active[i] and t[i] * z[i] < centrality * mu:
            z[i] = centrality * mu / t[i]


@numba.njit(cache=True, error_model="numpy")
def remember(point, ineq, memory):
    """Keep a solved QP's inputs, slacks, sigmas and multipliers for the next warm start."""
    memory.inputs[:, :] = point.inputs
    memory.slacks[:] = point.slacks
    memory.sigmas[:, :] = point.sigmas
    memory.z[:] = ineq.z
    memory.valid[0] = True


@numba.njit(cache=True, error_model="numpy")
def warm_start(qp, measured_state, memory, ineq, point, shifted_inputs, settings):
    """The warm start (module doc; ``_warm_primal``, ``_warm_inequalities``) from a valid ``memory`` into point and
    ineq; ``shifted_inputs`` (N, 2) is scratch, ``settings`` ``WARM_START_SETTINGS``."""
    _warm_primal(qp, measured_state, memory, ineq.has_sigma, shifted_inputs, point, settings[3])
    _warm_inequalities(qp, memory, point, ineq, settings)


@numba.njit(cache=True, error_model="numpy")
def reorder_memory_slots(memory, sources, n_slots, previous_z):
    """The memory's multipliers of the vehicle-slot groups (rows, s >= 0, sigma >= 0, sigma <= sigma_hi) moved
    between slots: slot j < n_slots takes those of slot ``sources[j]`` (-1: none, z = 0, which the warm start's
    centrality correction lifts), the slots from n_slots on get 0; the stage groups (state and input bounds) keep
    theirs. ``previous_z`` (m,) is scratch. The primal part (inputs, slacks, sigmas) is left to the caller."""
    horizon, n_full = memory.sigmas.shape
    offsets = inequality_offsets(horizon, n_full)
    o_row, o_slo, o_sglo, o_sghi, o_ylo = offsets[0], offsets[1], offsets[2], offsets[3], offsets[4]
    previous_z[:] = memory.z
    memory.z[:o_ylo] = 0.0
    for j in range(n_slots):
        source = sources[j]
        if source < 0:
            continue
        memory.z[o_slo + j] = previous_z[o_slo + source]
        for k in range(horizon):
            memory.z[o_row + k * n_full + j] = previous_z[o_row + k * n_full + source]
            memory.z[o_sglo + k * n_full + j] = previous_z[o_sglo + k * n_full + source]
            memory.z[o_sghi + k * n_full + j] = previous_z[o_sghi + k * n_full + source]
