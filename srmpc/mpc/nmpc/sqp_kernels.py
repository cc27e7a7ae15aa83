"""The NMPC's NLP functions and SQP steps as compiled kernels on a flat point (``sqp``'s module doc).

A point w = (x, u, s, sigma) is one flat array in the order of Anderson acceleration's vectors:
x_0..N (N + 1, 4), u_0..N-1 (N, 2), s (2 V_obs: the collision rows' s_j, then the safety rows' s'_j),
sigma (N, V_obs); ``point_parts`` gives the four views.

Kernels (``sqp._sqp`` calls them in the order of the module doc's steps):

- ``objective``: F(w); ``infeasibility``: (theta_1, theta_inf), the l1 and max norms of the dynamics
  defects |x_{k+1} - f(x_k, u_k)|, |x_0 - x_hat| and the violations of the boxes, the exact collision and
  safety constraints and the slacks' signs;
- ``initial_point``: the guess clipped into the boxes, x_0 = x_hat, the smallest feasible slacks;
- ``screen`` and ``linearize_subproblem``: the QP's rows at w (screening), written into the QP's stage-wise
  arrays with the dynamics' Jacobians, as ``LtvMpcQp.update`` and ``linearize_ellipse_rows`` write them;
- ``warm_start_memory``: the QP solver's warm start for the next subproblem (w and the last QP's multipliers);
- ``qp_candidate``: the QP's solution as a point (the screened slacks keep their values);
- ``anderson_point``: the type-II Anderson point of the stored pairs (w, G(w)), projected into the boxes.

Every sum is numpy's pairwise summation (``pairwise_sum``) over the terms in the order numpy's array
expressions produce them (``tests/mpc/test_nmpc.py`` holds those expressions), and Anderson's least squares
and product are numpy's LAPACK/BLAS calls: F, theta and w_AA equal the numpy evaluation bit for bit, so the
SQP's decisions (penalty, line search, Anderson's acceptance, convergence) are those of the numpy SQP of
earlier revisions.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from srmpc.mpc.nmpc.nonlinear_constraints import linearize_ellipse_rows, min_ellipse_norms
from srmpc.mpc.problem import linearize_horizon
from srmpc.mpc.solvers import reorder_memory_slots

SAFETY_SLACK_UPPER = 10.0
"""Upper box of the safety slacks sigma_kj in the QP subproblem (ellipse-norm units, dimensionless).
Never active at an NLP solution (sigma = max(0, 1 - g') <= 1); it only bounds the QP's interior."""

PAIRWISE_BLOCK = 128
"""numpy's ``PW_BLOCKSIZE``: sums of up to this many terms use 8 partial sums, longer ones are split in two."""

_EPSILON = float(np.finfo(np.float64).eps)
"""Machine epsilon: numpy's ``lstsq(rcond=None)`` cuts singular values below eps max(rows, columns) s_max."""

NlpConstants = namedtuple("NlpConstants", [
    "model", "circle_offsets_m", "collision_semi_axes_m", "safety_semi_axes_m", "state_weight", "input_weight",
    "rate_weight", "slack_weights", "state_lower", "state_upper", "input_lower", "input_upper", "screening_norm"])
"""The NLP's constants: the bicycle's (h, substeps, l / 2, v_max, v_min), the circle offsets d_c (C,) and the
ellipses' semi-axes (a, b), (a', b'); Q (4,), R (2,), S (2,), (w_col,1, w_col,2, w_safe,1, w_safe,2); the state
box (4,) x 2 (+-inf where unbounded) and the input box (2,) x 2; the screening norm."""

KernelScratch = namedtuple("KernelScratch", ["terms", "state", "collision", "safety"])
"""Scratch of the kernels: the terms of a sum (``infeasibility``'s longest), f(x, u) (4,), the ellipse norms
(N, V) x 2."""

Subproblem = namedtuple("Subproblem", [
    "measured_state", "last_input", "tracking_reference", "linearization_inputs", "next_states",
    "state_matrices", "input_matrices", "affine_offsets", "coefficients", "row_lower", "sigma_upper",
    "row_frames", "row_norms", "collision_rows", "safety_rows"])
"""The QP subproblem: ``LtvMpcQp``'s stage-wise arrays (for 2 V slots; the QP solver reads them), the
frames (``vehicle_frames``) of its rows' vehicles (N + 1, 2 V, 4) and their norms (N, 2 V), the screened
vehicles' indices (V,) x 2."""


def allocate_scratch(horizon: int, max_vehicles: int) -> KernelScratch:
    """``KernelScratch`` for horizon N and up to ``max_vehicles`` observed vehicles."""
    n_terms = 16 * horizon + 4 + (3 * horizon + 2) * max_vehicles
    return KernelScratch(np.empty(n_terms), np.empty(4), np.empty((horizon, max_vehicles)),
                         np.empty((horizon, max_vehicles)))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _block_sum(values, start, n):
    """numpy's sum of one block (n <= ``PAIRWISE_BLOCK``): in order below 8 terms, else 8 interleaved partial
    sums added pairwise, then the remainder in order."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += values[i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    i = start + 8
    end = start + n - n % 8
    while i < end:
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < start + n:
        total += values[i]
        i += 1
    return total


@numba.njit(cache=True, error_model="numpy")
def pairwise_sum(values, start, n):
    """sum(values[start:start + n]) in numpy's order (its ``pairwise_sum``), so that it equals ``np.sum`` bit
    for bit: blocks of <= ``PAIRWISE_BLOCK`` terms by ``_block_sum``; a longer range is split at
    half - half % 8 and its halves' sums added. The recursion runs on an explicit stack (numba's cache does
    not load recursive functions into their callers)."""
    if n <= PAIRWISE_BLOCK:
        return _block_sum(values, start, n)
    frame_start = np.empty(64, dtype=np.int64)
    frame_length = np.empty(64, dtype=np.int64)
    frame_stage = np.empty(64, dtype=np.int64)  # 0: split, 1: left summed, 2: both summed
    sums = np.empty(64)
    frame_start[0], frame_length[0], frame_stage[0] = start, n, 0
    frames, n_sums = 1, 0
    while frames:
        top = frames - 1
        first, length = frame_start[top], frame_length[top]
        if length <= PAIRWISE_BLOCK:
            sums[n_sums] = _block_sum(values, first, length)
            n_sums += 1
            frames -= 1
            continue
        half = length // 2
        half -= half % 8
        if frame_stage[top] == 2:
            sums[n_sums - 2] = sums[n_sums - 2] + sums[n_sums - 1]
            n_sums -= 1
            frames -= 1
            continue
        child_start = first if frame_stage[top] == 0 else first + half
        child_length = half if frame_stage[top] == 0 else length - half
        frame_stage[top] += 1
        frame_start[frames], frame_length[frames], frame_stage[frames] = child_start, child_length, 0
        frames += 1
    return sums[0]


@numba.njit(cache=True, error_model="numpy", inline="always")
def point_size(horizon, n_obs):
    """Length of a flat point: 4 (N + 1) + 2 N + 2 V_obs + N V_obs."""
    return 4 * (horizon + 1) + 2 * horizon + 2 * n_obs + horizon * n_obs


@numba.njit(cache=True, error_model="numpy", inline="always")
def point_parts(w, horizon, n_obs):
    """Views (x (N + 1, 4), u (N, 2), s (2 V_obs,), sigma (N, V_obs)) of the flat point w."""
    slack_start = 4 * (horizon + 1) + 2 * horizon
    sigma_start = slack_start + 2 * n_obs
    return (w[:4 * (horizon + 1)].reshape((horizon + 1, 4)), w[4 * (horizon + 1):slack_start].reshape((horizon, 2)),
            w[slack_start:sigma_start], w[sigma_start:sigma_start + horizon * n_obs].reshape((horizon, n_obs)))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _positive_part(value):
    """max(value, 0) as ``np.maximum(value, 0.0)`` (NaN propagates)."""
    return value if value > 0.0 or value != value else 0.0


@numba.njit(cache=True, error_model="numpy")
def objective(w, horizon, n_obs, tracking_reference, last_input, constants, scratch):
    """F(w) (``sqp``'s module doc); ``scratch`` (>= 4 N) holds the terms of each sum."""
    states, inputs, _, _ = point_parts(w, horizon, n_obs)
    q, r, s = constants.state_weight, constants.input_weight, constants.rate_weight
    for k in range(horizon):
        for c in range(4):
            error = states[k + 1, c] - tracking_reference[k + 1, c]
            scratch[4 * k + c] = q[c] * (error * error)
    tracking = pairwise_sum(scratch, 0, 4 * horizon)
    for k in range(horizon):
        for c in range(2):
            scratch[2 * k + c] = r[c] * (inputs[k, c] * inputs[k, c])
    effort = pairwise_sum(scratch, 0, 2 * horizon)
    for k in range(horizon):
        for c in range(2):
            rate = inputs[k, c] - (last_input[c] if k == 0 else inputs[k - 1, c])
            scratch[2 * k + c] = s[c] * (rate * rate)
    smoothness = pairwise_sum(scratch, 0, 2 * horizon)
    slack_start = 4 * (horizon + 1) + 2 * horizon
    n_slacks, n_sigmas = 2 * n_obs, horizon * n_obs
    sigma_start = slack_start + n_slacks
    slack_sum = pairwise_sum(w, slack_start, n_slacks)
    for i in range(n_slacks):
        scratch[i] = w[slack_start + i] * w[slack_start + i]
    slack_squares = pairwise_sum(scratch, 0, n_slacks)
    sigma_sum = pairwise_sum(w, sigma_start, n_sigmas)
    for i in range(n_sigmas):
        scratch[i] = w[sigma_start + i] * w[sigma_start + i]
    sigma_squares = pairwise_sum(scratch, 0, n_sigmas)
    weights = constants.slack_weights
    return (tracking + effort + smoothness + weights[0] * slack_sum + weights[1] * slack_squares
            + weights[2] * sigma_sum + weights[3] * sigma_squares)


@numba.njit(cache=True, error_model="numpy", inline="always")
def next_state(state, control, model, current):
    """f(x, u) into ``current``: the sub-steps of ``problem.vehicle_model``'s ``_substep_with_jacobians``, states
    only, in the same floating-point operations, with beta = arctan(tan(delta) / 2) and sin(beta) computed once for the
    control period (the input is held over its sub-steps)."""
    h, n_substeps, half_length, v_max, v_min = model
    beta = np.arctan(0.5 * np.tan(control[0]))
    sin_b = np.sin(beta)
    for i in range(4):
        current[i] = state[i]
    for _ in range(n_substeps):
        px, py, psi, v = current[0], current[1], current[2], current[3]
        course = psi + beta
        accel = control[1]
        if v > v_max and accel > v_max - v:
            accel = v_max - v
        elif v < v_min and accel < v_min - v:
            accel = v_min - v
        current[0] = px + h * v * np.cos(course)
        current[1] = py + h * v * np.sin(course)
        current[2] = psi + h * v * sin_b / half_length
        current[3] = v + h * accel


@numba.njit(cache=True, error_model="numpy")
def ellipse_norms(states, frames, n_obs, constants, collision, safety):
    """min_c g (collision) and min_c g' (safety) at x_1..N, (N, V_obs) each (``min_ellipse_norms``)."""
    min_ellipse_norms(states, frames, n_obs, constants.circle_offsets_m, constants.collision_semi_axes_m, collision)
    min_ellipse_norms(states, frames, n_obs, constants.circle_offsets_m, constants.safety_semi_axes_m, safety)


@numba.njit(cache=True, error_model="numpy")
def infeasibility(w, horizon, n_obs, measured_state, frames, constants, scratch):
    """(theta_1, theta_inf) of w (module doc); ``scratch``: ``allocate_scratch``'s."""
    states, inputs, slacks, sigmas = point_parts(w, horizon, n_obs)
    terms = scratch.terms
    lower, upper = constants.state_lower, constants.state_upper
    input_lower, input_upper = constants.input_lower, constants.input_upper
    current = scratch.state
    for k in range(horizon):
        next_state(states[k], inputs[k], constants.model, current)
        for c in range(4):
            terms[4 * k + c] = abs(states[k + 1, c] - current[c])
    n = 4 * horizon
    for c in range(4):
        terms[n + c] = abs(states[0, c] - measured_state[c])
    n += 4
    for k in range(horizon):
        for c in range(4):
            terms[n + 4 * k + c] = _positive_part(lower[c] - states[k + 1, c])
            terms[n + 4 * horizon + 4 * k + c] = _positive_part(states[k + 1, c] - upper[c])
    n += 8 * horizon
    for k in range(horizon):
        for c in range(2):
            terms[n + 2 * k + c] = _positive_part(input_lower[c] - inputs[k, c])
            terms[n + 2 * horizon + 2 * k + c] = _positive_part(inputs[k, c] - input_upper[c])
    n += 4 * horizon
    if n_obs:
        collision, safety = scratch.collision[:, :n_obs], scratch.safety[:, :n_obs]
        ellipse_norms(states, frames, n_obs, constants, collision, safety)
        for k in range(horizon):
            for j in range(n_obs):
                terms[n + k * n_obs + j] = _positive_part(1.0 - collision[k, j] - slacks[j])
        n += horizon * n_obs
        for k in range(horizon):
            for j in range(n_obs):
                terms[n + k * n_obs + j] = _positive_part(1.0 - safety[k, j] - sigmas[k, j] - slacks[n_obs + j])
        n += horizon * n_obs
        for i in range(2 * n_obs):
            terms[n + i] = _positive_part(-slacks[i])
        n += 2 * n_obs
        for k in range(horizon):
            for j in range(n_obs):
                terms[n + k * n_obs + j] = _positive_part(-sigmas[k, j])
        n += horizon * n_obs
    largest = 0.0
    for i in range(n):
        if terms[i] > largest or terms[i] != terms[i]:
            largest = terms[i]
    return pairwise_sum(terms, 0, n), largest


@numba.njit(cache=True, error_model="numpy")
def initial_point(measured_state, frames, n_obs, initial_states, initial_inputs, constants, scratch, w):
    """The guess clipped into the boxes, x_0 = x_hat, the smallest feasible slacks (module doc) into w."""
    horizon = initial_inputs.shape[0]
    states, inputs, slacks, sigmas = point_parts(w, horizon, n_obs)
    for k in range(horizon + 1):
        for c in range(4):
            states[k, c] = min(max(initial_states[k, c], constants.state_lower[c]), constants.state_upper[c])
    for c in range(4):
        states[0, c] = measured_state[c]
    for k in range(horizon):
        for c in range(2):
            inputs[k, c] = min(max(initial_inputs[k, c], constants.input_lower[c]), constants.input_upper[c])
    slacks[:] = 0.0
    if n_obs:
        collision, safety = scratch.collision[:, :n_obs], scratch.safety[:, :n_obs]
        ellipse_norms(states, frames, n_obs, constants, collision, safety)
        for j in range(n_obs):
            for k in range(horizon):
                slacks[j] = max(slacks[j], _positive_part(1.0 - collision[k, j]))
                sigmas[k, j] = _positive_part(1.0 - safety[k, j])


@numba.njit(cache=True, error_model="numpy")
def linearize_dynamics(states, inputs, model, next_states, state_matrices, input_matrices, affine_offsets):
    """f(x_k, u_k), A_k = df/dx, B_k = df/du and c_k at the states (N + 1, 4) and inputs (N, 2) of a point, into the
    (N, 4), (N, 4, 4), (N, 4, 2), (N, 4) arrays; ``model`` is ``NlpConstants.model`` (``linearize_subproblem``'s
    Jacobians, the same floats)."""
    h, n_substeps, half_length, v_max, v_min = model
    linearize_horizon(states, inputs, h, n_substeps, half_length, v_max, v_min, next_states, state_matrices,
                      input_matrices, affine_offsets)


@numba.njit(cache=True, error_model="numpy")
def screen(w, horizon, n_obs, frames, constants, scratch, collision_rows, safety_rows):
    """The vehicles whose collision / safety rows enter the QP at w (module doc, screening) into the row
    index arrays; returns their counts."""
    if not n_obs:
        return 0, 0
    states, _, slacks, sigmas = point_parts(w, horizon, n_obs)
    collision, safety = scratch.collision[:, :n_obs], scratch.safety[:, :n_obs]
    ellipse_norms(states, frames, n_obs, constants, collision, safety)
    threshold = constants.screening_norm
    n_collision, n_safety = 0, 0
    for j in range(n_obs):
        keep_collision = slacks[j] > 0.0
        keep_safety = slacks[n_obs + j] > 0.0
        for k in range(horizon):
            keep_collision = keep_collision or collision[k, j] < threshold
            keep_safety = keep_safety or safety[k, j] < threshold or sigmas[k, j] > 0.0
        if keep_collision:
            collision_rows[n_collision] = j
            n_collision += 1
        if keep_safety:
            safety_rows[n_safety] = j
            n_safety += 1
    return n_collision, n_safety


@numba.njit(cache=True, error_model="numpy")
def linearize_subproblem(w, horizon, n_obs, frames, n_collision, n_safety, constants, qp):
    """The QP subproblem at w (module doc, step 1) in ``qp``'s arrays: the dynamics' A_k, B_k, c_k
    (``LtvMpcQp.update``), the collision rows of ``qp.collision_rows[:n_collision]`` (sigma_hi = 0), then the
    safety rows of ``qp.safety_rows[:n_safety]`` (sigma_hi = ``SAFETY_SLACK_UPPER``), empty slots zero."""
    states, inputs, _, _ = point_parts(w, horizon, n_obs)
    h, n_substeps, half_length, v_max, v_min = constants.model
    linearize_horizon(states, inputs, h, n_substeps, half_length, v_max, v_min, qp.next_states,
                      qp.state_matrices, qp.input_matrices, qp.affine_offsets)
    qp.linearization_inputs[:, :] = inputs
    n_rows = n_collision + n_safety
    for row in range(n_rows):
        vehicle = qp.collision_rows[row] if row < n_collision else qp.safety_rows[row - n_collision]
        for k in range(horizon + 1):
            for c in range(4):
                qp.row_frames[k, row, c] = frames[k, vehicle, c]
    for k in range(horizon):
        for j in range(n_rows, qp.coefficients.shape[1]):
            qp.coefficients[k, j, 0] = 0.0
            qp.coefficients[k, j, 1] = 0.0
            qp.coefficients[k, j, 2] = 0.0
            qp.row_lower[k, j] = 0.0
            qp.sigma_upper[k, j] = 0.0
        for j in range(n_rows):
            qp.sigma_upper[k, j] = 0.0 if j < n_collision else SAFETY_SLACK_UPPER
    if n_rows:
        linearize_ellipse_rows(states, qp.row_frames, n_collision, constants.circle_offsets_m,
                               constants.collision_semi_axes_m, qp.coefficients, qp.row_lower, qp.row_norms)
        linearize_ellipse_rows(states, qp.row_frames[:, n_collision:], n_safety, constants.circle_offsets_m,
                               constants.safety_semi_axes_m, qp.coefficients[:, n_collision:],
                               qp.row_lower[:, n_collision:], qp.row_norms)
    return n_rows


@numba.njit(cache=True, error_model="numpy")
def warm_start_memory(w, horizon, n_obs, qp, n_collision, n_safety, previous_rows, previous_counts, memory, sources,
                      scratch_z):
    """The QP solver's warm-start memory (``solvers.WarmStartMemory``, its slots the rows of the subproblem in
    ``qp``) for the subproblem at w (``sqp``'s module doc, step 1): the primal part w's inputs, slacks and sigmas
    in their rows' slots (``qp_candidate`` in reverse; the solver rolls the inputs out through the linearized
    dynamics), the multipliers those the previous QP left in ``memory`` (``reorder_memory_slots``): the stage
    groups' as they are, a row's those of the previous QP's row of the same kind (collision or safety) and
    vehicle, 0 if it had none. ``previous_rows`` (2, V): the previous QP's collision and safety vehicles,
    ``previous_counts`` (2,) their numbers; ``sources`` (>= 2V,) and ``scratch_z`` (m,) are scratch."""
    _, inputs, slacks, sigmas = point_parts(w, horizon, n_obs)
    n_rows = n_collision + n_safety
    for row in range(n_rows):
        sources[row] = -1
        if row < n_collision:
            vehicle = qp.collision_rows[row]
            for previous in range(previous_counts[0]):
                if previous_rows[0, previous] == vehicle:
                    sources[row] = previous
        else:
            vehicle = qp.safety_rows[row - n_collision]
            for previous in range(previous_counts[1]):
                if previous_rows[1, previous] == vehicle:
                    sources[row] = previous_counts[0] + previous
    reorder_memory_slots(memory, sources, n_rows, scratch_z)
    memory.inputs[:, :] = inputs
    memory.slacks[:] = 0.0
    memory.sigmas[:, :] = 0.0
    for row in range(n_collision):
        memory.slacks[row] = slacks[qp.collision_rows[row]]
    for row in range(n_safety):
        vehicle = qp.safety_rows[row]
        memory.slacks[n_collision + row] = slacks[n_obs + vehicle]
        for k in range(horizon):
            memory.sigmas[k, n_collision + row] = sigmas[k, vehicle]


@numba.njit(cache=True, error_model="numpy")
def qp_candidate(w, horizon, n_obs, solution, n_collision, n_safety, qp, candidate):
    """The QP's ``solution`` (a ``solvers.Primal``) as a point w_QP: its states and inputs,
    the rows' slacks in their vehicles' places, the screened vehicles' slacks those of w. Returns False if
    the solution is not finite (every entry, as ``RiccatiInteriorPointSolver.solve`` checks)."""
    for block in (solution.states.ravel(), solution.inputs.ravel(), solution.slacks, solution.sigmas.ravel()):
        for value in block:
            if not np.isfinite(value):
                return False
    states, inputs, slacks, sigmas = point_parts(candidate, horizon, n_obs)
    _, _, current_slacks, current_sigmas = point_parts(w, horizon, n_obs)
    states[:, :] = solution.states
    inputs[:, :] = solution.inputs
    slacks[:] = current_slacks
    sigmas[:, :] = current_sigmas
    for row in range(n_collision):
        slacks[qp.collision_rows[row]] = solution.slacks[row]
    for row in range(n_safety):
        vehicle = qp.safety_rows[row]
        slacks[n_obs + vehicle] = solution.slacks[n_collision + row]
        for k in range(horizon):
            sigmas[k, vehicle] = solution.sigmas[k, n_collision + row]
    return True


@numba.njit(cache=True, error_model="numpy")
def anderson_point(iterates, images, oldest, count, horizon, n_obs, measured_state, constants, accelerated):
    """w_AA = G_i - dG gamma, gamma = argmin ||f_i - dF gamma||_2 over the ``count`` pairs (w, G(w)) stored
    in the rings ``iterates``, ``images`` (m + 1, >= len(w)) from slot ``oldest`` on, f = G(w) - w; projected
    into the boxes (module doc, step 4), into ``accelerated``. numpy's least squares (``lstsq``, rcond =
    eps max(rows, columns)) and matrix-vector product, as the numpy SQP computed them."""
    size = accelerated.shape[0]
    capacity = iterates.shape[0]
    residual_differences = np.empty((size, count - 1))
    image_differences = np.empty((size, count - 1))
    newest_residual = np.empty(size)
    newest = (oldest + count - 1) % capacity
    for column in range(count - 1):
        before, after = (oldest + column) % capacity, (oldest + column + 1) % capacity
        for i in range(size):
            residual_differences[i, column] = ((images[after, i] - iterates[after, i])
                                               - (images[before, i] - iterates[before, i]))
            image_differences[i, column] = images[after, i] - images[before, i]
    for i in range(size):
        newest_residual[i] = images[newest, i] - iterates[newest, i]
    rcond = _EPSILON * max(size, count - 1)
    gamma = np.linalg.lstsq(residual_differences, newest_residual, rcond)[0]
    correction = np.dot(image_differences, gamma)
    for i in range(size):
        accelerated[i] = images[newest, i] - correction[i]
    states, inputs, slacks, sigmas = point_parts(accelerated, horizon, n_obs)
    for c in range(4):
        states[0, c] = measured_state[c]
    for k in range(1, horizon + 1):
        for c in range(4):
            states[k, c] = min(max(states[k, c], constants.state_lower[c]), constants.state_upper[c])
    for k in range(horizon):
        for c in range(2):
            inputs[k, c] = min(max(inputs[k, c], constants.input_lower[c]), constants.input_upper[c])
    for i in range(slacks.shape[0]):
        slacks[i] = _positive_part(slacks[i])
    for k in range(horizon):
        for j in range(n_obs):
            sigmas[k, j] = _positive_part(sigmas[k, j])
