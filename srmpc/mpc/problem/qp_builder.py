"""The LTV-MPC QP in a fixed sparsity pattern, assembled once; only values change per step.

Decision vector, stage-interleaved (stage k = 0..N)::

    z = [x_0, u_0, | x_1, u_1, sigma_1, | ... | x_N, sigma_N, | s]

with x_k (4), u_k (2, k < N), sigma_k (V safety-region slacks, k >= 1) and, per other vehicle j,
one collision slack s_j that relaxes its collision constraint over the whole horizon (the paper:
slack "relaxing the whole constraint"); s_j is then the largest violation over the horizon: an
intrusion that cannot be avoided now may persist but is penalized, never made worse for free.

QP (paper eq. qp), kept in two equivalent forms that share the same value arrays::

    split form:    min 1/2 z^T P z + q^T z   s.t.  E z = e,  G z >= h,  z_lo <= z <= z_hi
    general form:  min 1/2 z^T P z + q^T z   s.t.  l <= A z <= u,  A = [E; G; I_box]

- E z = e: x_0 = x_hat and x_{k+1} - A_k x_k - B_k u_k = c_k (linearized dynamics, eq. OCP_b/c).
- G z >= h: per stage k >= 1 and vehicle j one row, the linearized collision constraint of the
  critical ego circle merged with its safety region: n^T J_p x_k + s_j + sigma_kj >= h_kj
  (see ``collision_constraints.py``).
- Box: y_k and v_k (k >= 1), u_k, s >= 0, 0 <= sigma_kj <= h'(n) - 1 (changes each step);
  x, psi and x_0 are free (+-inf).

P (upper triangle, constant): 2 Q on x_k (k >= 1), 2 R + 2 S (+ 2 S if k < N - 1) on u_k,
-2 S between u_{k-1} and u_k, 2 w_2 on the slacks.  q = -2 Q x^ref_k on x_k, -2 S u_hat on u_0,
w_1 on the slacks.

Every entry that can ever be nonzero is in the pattern, explicit zeros included: matrices are
built from index lists with placeholder values, never from sparse arithmetic that would drop
zeros, so solvers can be updated in place (OSQP ``update(Ax=...)``, PIQP ``update``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from srmpc.mpc.problem.collision_constraints import linearize_collision_constraints
from srmpc.mpc.problem.ocp import OcpConfig
from srmpc.mpc.problem.step_data import OcpStepData
from srmpc.mpc.problem.vehicle_model import INPUT_DIM, LATERAL_INDEX, SPEED_INDEX, STATE_DIM, KinematicBicycle


@dataclass(frozen=True)
class VariableLayout:
    """Positions of the blocks of z (see module doc)."""

    horizon: int
    n_slots: int
    state_start: np.ndarray  # (N + 1,)
    input_start: np.ndarray  # (N,)
    safety_slack_start: np.ndarray  # (N,), sigma of stage k + 1
    collision_slack_start: int
    n_variables: int

    @classmethod
    def build(cls, horizon: int, n_slots: int) -> VariableLayout:
        state_start = np.empty(horizon + 1, dtype=np.int64)
        input_start = np.empty(horizon, dtype=np.int64)
        safety_slack_start = np.empty(horizon, dtype=np.int64)
        index = 0
        for k in range(horizon + 1):
            state_start[k] = index
            index += STATE_DIM
            if k < horizon:
                input_start[k] = index
                index += INPUT_DIM
            if k >= 1:
                safety_slack_start[k - 1] = index
                index += n_slots
        return cls(horizon, n_slots, state_start, input_start, safety_slack_start, index,
                   index + n_slots)

    def state_indices(self) -> np.ndarray:
        """(N + 1, 4) indices of x_k."""
        return self.state_start[:, None] + np.arange(STATE_DIM)[None, :]

    def input_indices(self) -> np.ndarray:
        """(N, 2) indices of u_k."""
        return self.input_start[:, None] + np.arange(INPUT_DIM)[None, :]

    def collision_slack_indices(self) -> np.ndarray:
        """(V,) indices of s_j."""
        return self.collision_slack_start + np.arange(self.n_slots)

    def safety_slack_indices(self) -> np.ndarray:
        """(N, V) indices of sigma_{k+1, j}."""
        return self.safety_slack_start[:, None] + np.arange(self.n_slots)[None, :]


class _PatternBuilder:
    """Collects (row, col) entries; ``add`` returns their entry numbers in insertion order."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.count = 0

    def add(self, rows, cols) -> np.ndarray:
        rows, cols = np.broadcast_arrays(np.asarray(rows, dtype=np.int64),
                                         np.asarray(cols, dtype=np.int64))
        entries = self.count + np.arange(rows.size).reshape(rows.shape)
        self.rows.append(rows.ravel())
        self.cols.append(cols.ravel())
        self.count += rows.size
        return entries

    def finalize(self, shape: tuple[int, int]) -> tuple[sp.csc_matrix, np.ndarray]:
        """CSC matrix with zero data and, per entry number, its position in ``data``."""
        rows = np.concatenate(self.rows) if self.rows else np.empty(0, dtype=np.int64)
        cols = np.concatenate(self.cols) if self.cols else np.empty(0, dtype=np.int64)
        return csc_with_positions(rows, cols, shape)


def csc_with_positions(
    rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]
) -> tuple[sp.csc_matrix, np.ndarray]:
    """Build a CSC pattern from (row, col) pairs; return it and each pair's data position.

    Placeholder values 1..nnz keep every entry (explicit zeros are never dropped); duplicates
    are rejected.
    """
    n_entries = rows.size
    order = np.lexsort((rows, cols))
    sorted_rows, sorted_cols = rows[order], cols[order]
    if n_entries > 1:
        same = (np.diff(sorted_rows) == 0) & (np.diff(sorted_cols) == 0)
        if np.any(same):
            raise ValueError("duplicate entries in sparsity pattern")
    indptr = np.zeros(shape[1] + 1, dtype=np.int32)
    np.add.at(indptr, sorted_cols + 1, 1)
    indptr = np.cumsum(indptr).astype(np.int32)
    matrix = sp.csc_matrix(
        (np.zeros(n_entries), sorted_rows.astype(np.int32), indptr), shape=shape
    )
    positions = np.empty(n_entries, dtype=np.int64)
    positions[order] = np.arange(n_entries)
    return matrix, positions


def _equality_pattern(layout: VariableLayout) -> tuple[sp.csc_matrix, np.ndarray, np.ndarray]:
    """E z = e (module doc): x_0 = x_hat; x_{k+1} - A_k x_k - B_k u_k = c_k.

    Returns E with its constant entries (the identity blocks) set, and the data positions of the entries of
    -A_k (N, 4, 4) and -B_k (N, 4, 2).
    """
    horizon = layout.horizon
    state_idx = layout.state_indices()
    input_idx = layout.input_indices()
    eq = _PatternBuilder()
    initial_entries = eq.add(np.arange(STATE_DIM), state_idx[0])
    rows_k = STATE_DIM + STATE_DIM * np.arange(horizon)[:, None] + np.arange(STATE_DIM)
    next_entries = eq.add(rows_k, state_idx[1:])
    a_entries = eq.add(rows_k[:, :, None], state_idx[:-1, None, :])
    b_entries = eq.add(rows_k[:, :, None], input_idx[:, None, :])
    matrix, eq_pos = eq.finalize((STATE_DIM * (horizon + 1), layout.n_variables))
    matrix.data[eq_pos[initial_entries]] = 1.0
    matrix.data[eq_pos[next_entries]] = 1.0
    return matrix, eq_pos[a_entries], eq_pos[b_entries]


def _inequality_pattern(layout: VariableLayout) -> tuple[sp.csc_matrix, np.ndarray]:
    """G z >= h (module doc): one row per stage k >= 1 and vehicle slot j, n^T J_p x_k + s_j + sigma_kj >= h_kj.

    Returns G with its slack entries (1) set, and the data positions of the row normals' entries (N, V, 3).
    """
    horizon, n_slots = layout.horizon, layout.n_slots
    state_idx = layout.state_indices()
    rows = np.arange(horizon)[:, None] * n_slots + np.arange(n_slots)[None, :]  # (N, V)
    ineq = _PatternBuilder()
    coef_entries = ineq.add(rows[..., None], state_idx[1:, None, :3])  # (N, V, 3)
    col_slack_entries = ineq.add(rows, layout.collision_slack_indices()[None, :])
    safe_slack_entries = ineq.add(rows, layout.safety_slack_indices())
    matrix, ineq_pos = ineq.finalize((horizon * n_slots, layout.n_variables))
    matrix.data[ineq_pos[col_slack_entries]] = 1.0
    matrix.data[ineq_pos[safe_slack_entries]] = 1.0
    return matrix, ineq_pos[coef_entries]


def _box_bounds(config: OcpConfig, layout: VariableLayout) -> tuple[np.ndarray, np.ndarray]:
    """z_lo <= z <= z_hi (module doc): y_k and v_k (k >= 1), u_k, s >= 0, 0 <= sigma_kj <= h'(n) - 1 (0 until
    ``update`` sets it); +-inf elsewhere. Returns (z_lo, z_hi)."""
    n = layout.n_variables
    state_idx = layout.state_indices()
    input_idx = layout.input_indices()
    safe_slack_idx = layout.safety_slack_indices()
    variable_lower = np.full(n, -np.inf)
    variable_upper = np.full(n, np.inf)
    variable_lower[state_idx[1:, LATERAL_INDEX]] = config.lateral_bounds_m[0]
    variable_upper[state_idx[1:, LATERAL_INDEX]] = config.lateral_bounds_m[1]
    variable_lower[state_idx[1:, SPEED_INDEX]] = config.speed_bounds_mps[0]
    variable_upper[state_idx[1:, SPEED_INDEX]] = config.speed_bounds_mps[1]
    variable_lower[input_idx[:, 0]] = config.steering_bounds_rad[0]
    variable_upper[input_idx[:, 0]] = config.steering_bounds_rad[1]
    variable_lower[input_idx[:, 1]] = config.acceleration_bounds_mps2[0]
    variable_upper[input_idx[:, 1]] = config.acceleration_bounds_mps2[1]
    variable_lower[layout.collision_slack_indices()] = 0.0
    variable_lower[safe_slack_idx] = 0.0
    variable_upper[safe_slack_idx] = 0.0  # set per step to h'(n) - 1
    return variable_lower, variable_upper


def _cost(config: OcpConfig, layout: VariableLayout) -> tuple[sp.csc_matrix, np.ndarray]:
    """P (upper triangle, constant) and q without its per-step entries (module doc): 2 Q on x_k (k >= 1),
    2 R + 2 S (+ 2 S if k < N - 1) on u_k, -2 S between u_{k-1} and u_k, 2 w_2 and w_1 on the slacks."""
    weights = config.weights
    horizon = config.horizon
    n = layout.n_variables
    col_slack_idx = layout.collision_slack_indices()
    safe_slack_idx = layout.safety_slack_indices()
    state_weight = np.asarray(weights.state, dtype=np.float64)
    input_weight = np.asarray(weights.input, dtype=np.float64)
    rate_weight = np.asarray(weights.input_rate, dtype=np.float64)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    values: list[np.ndarray] = []

    def add(r, c, v):
        r, c, v = np.broadcast_arrays(np.asarray(r), np.asarray(c), np.asarray(v, float))
        rows.append(r.ravel())
        cols.append(c.ravel())
        values.append(v.ravel())

    states = layout.state_indices()[1:]
    add(states, states, np.broadcast_to(2.0 * state_weight, states.shape))
    inputs = layout.input_indices()
    # backward rate terms: every u_k has one (u_0 against u_hat); forward: all but the last
    forward = (np.arange(horizon) < horizon - 1).astype(float)[:, None]
    diag = 2.0 * input_weight[None, :] + 2.0 * rate_weight[None, :] * (1.0 + forward)
    add(inputs, inputs, diag)
    add(inputs[:-1], inputs[1:], np.broadcast_to(-2.0 * rate_weight, inputs[1:].shape))
    add(col_slack_idx, col_slack_idx, 2.0 * weights.collision_slack_quadratic)
    add(safe_slack_idx, safe_slack_idx, 2.0 * weights.safety_slack_quadratic)
    r, c = np.concatenate(rows), np.concatenate(cols)
    cost_matrix, positions = csc_with_positions(r, c, (n, n))
    cost_matrix.data[positions] = np.concatenate(values)
    cost_vector = np.zeros(n)
    cost_vector[col_slack_idx] = weights.collision_slack_linear
    cost_vector[safe_slack_idx] = weights.safety_slack_linear
    return cost_matrix, cost_vector


@dataclass(frozen=True)
class _GeneralForm:
    """l <= A z <= u with A = [E; G; I_box] (module doc), one box row per variable with a finite bound.

    Attributes:
        matrix: A with the box rows' entries (1) set; E's and G's entries are copied per step.
        lower, upper: l and u with the box rows set from the variable bounds and G's rows' u = +inf.
        boxed_variables: the variables with a box row, in row order.
        from_equality, from_inequality: data positions in A of E's and G's entries (in their storage order).
        box_row_of_variable: (n,) each variable's box row, -1 if it has none.
    """

    matrix: sp.csc_matrix
    lower: np.ndarray
    upper: np.ndarray
    boxed_variables: np.ndarray
    from_equality: np.ndarray
    from_inequality: np.ndarray
    box_row_of_variable: np.ndarray


def _general_form(equality_matrix: sp.csc_matrix, inequality_matrix: sp.csc_matrix, variable_lower: np.ndarray,
                  variable_upper: np.ndarray) -> _GeneralForm:
    """A = [E; G; I_box] and its bounds (module doc) from the split form's patterns and boxes."""
    n_equalities, n = equality_matrix.shape
    n_inequalities = inequality_matrix.shape[0]
    boxed = np.flatnonzero(np.isfinite(variable_lower) | np.isfinite(variable_upper))
    eq_coo = equality_matrix.tocoo()
    ineq_coo = inequality_matrix.tocoo()
    # tocoo of a canonical CSC enumerates data in storage order
    rows = np.concatenate([eq_coo.row, ineq_coo.row + n_equalities,
                           n_equalities + n_inequalities + np.arange(boxed.size)])
    cols = np.concatenate([eq_coo.col, ineq_coo.col, boxed])
    n_rows = n_equalities + n_inequalities + boxed.size
    general_matrix, gen_pos = csc_with_positions(rows, cols, (n_rows, n))
    n_eq_nnz = equality_matrix.nnz
    n_ineq_nnz = inequality_matrix.nnz
    general_matrix.data[gen_pos[n_eq_nnz + n_ineq_nnz:]] = 1.0
    general_lower = np.empty(n_rows)
    general_upper = np.empty(n_rows)
    box_rows = slice(n_equalities + n_inequalities, n_rows)
    general_lower[box_rows] = variable_lower[boxed]
    general_upper[box_rows] = variable_upper[boxed]
    general_upper[n_equalities:n_equalities + n_inequalities] = np.inf
    box_row_of_variable = np.full(n, -1)
    box_row_of_variable[boxed] = n_equalities + n_inequalities + np.arange(boxed.size)
    return _GeneralForm(general_matrix, general_lower, general_upper, boxed, gen_pos[:n_eq_nnz],
                        gen_pos[n_eq_nnz:n_eq_nnz + n_ineq_nnz], box_row_of_variable)


def _shift_maps(layout: VariableLayout, n_equalities: int, n_inequalities: int,
                general: _GeneralForm) -> tuple[np.ndarray, np.ndarray]:
    """One-stage shift maps (warm starts): the value of index i after the shift is taken from shift[i]; the last
    stage repeats itself. Returns the maps of z (n,) and of the general form's rows."""
    horizon, n_slots, n = layout.horizon, layout.n_slots, layout.n_variables
    state_idx = layout.state_indices()
    input_idx = layout.input_indices()
    safe_slack_idx = layout.safety_slack_indices()
    boxed = general.boxed_variables
    n_rows = n_equalities + n_inequalities + boxed.size
    stage_of = np.minimum(np.arange(horizon + 1) + 1, horizon)
    input_stage_of = np.minimum(np.arange(horizon) + 1, horizon - 1)
    sigma_stage_of = np.minimum(np.arange(horizon) + 1, horizon - 1)
    variable_shift = np.arange(n)
    variable_shift[state_idx] = state_idx[stage_of]
    variable_shift[input_idx] = input_idx[input_stage_of]
    variable_shift[safe_slack_idx] = safe_slack_idx[sigma_stage_of]
    eq_blocks = np.arange(n_equalities).reshape(horizon + 1, STATE_DIM)
    ineq_blocks = np.arange(n_inequalities).reshape(horizon, n_slots)
    row_shift = np.arange(n_rows)
    row_shift[eq_blocks] = eq_blocks[stage_of]
    row_shift[n_equalities + ineq_blocks] = n_equalities + ineq_blocks[sigma_stage_of]
    row_shift[n_equalities + n_inequalities:n_rows] = general.box_row_of_variable[variable_shift[boxed]]
    return variable_shift, row_shift


class LtvMpcQp:
    """Holds the QP's fixed pattern and overwrites its values each step (see module doc).

    Sparse forms (values written lazily, on first access after ``update``):
        cost_matrix (P, CSC upper triangle, constant), cost_vector (q),
        equality_matrix (E), equality_rhs (e), inequality_matrix (G), inequality_lower (h),
        variable_lower (constant), variable_upper,
        general_matrix (A), general_lower (l), general_upper (u).

    Stage-wise data (overwritten in place by ``update`` from an ``OcpStepData``, or directly by the compiled
    planner step and the NMPC, which then call ``stagewise_data_changed``; what structure-exploiting solvers
    read, see ``srmpc.mpc.solvers.interior_point``):
        measured_state x_hat (4,), last_input u_hat (2,), tracking_reference x^ref (N + 1, 4),
        linearization_inputs u^r (N, 2), state_matrices A_k (N, 4, 4),
        input_matrices B_k (N, 4, 2), affine_offsets c_k (N, 4), next_states f(x^r_k, u^r_k),
        collision_coefficients (N, V, 3) on (x, y, psi) of x_{k+1}, collision_row_lower h (N, V),
        safety_slack_upper (N, V), n_observed V_obs (slots >= V_obs are empty).
    """

    def __init__(self, config: OcpConfig, model: KinematicBicycle | None = None) -> None:
        self.config = config
        self.model = model or KinematicBicycle(config.bicycle)
        geometry = config.geometry
        self.circle_offsets_m = np.asarray(geometry.circle_offsets_m, dtype=np.float64)
        self.collision_semi_axes_m = np.asarray(geometry.collision_semi_axes_m)
        self.safety_semi_axes_m = np.asarray(geometry.safety_semi_axes_m)
        layout = VariableLayout.build(config.horizon, config.max_vehicles)
        self.layout = layout
        self._state_idx = layout.state_indices()
        self._input_idx = layout.input_indices()
        self._col_slack_idx = layout.collision_slack_indices()
        self._safe_slack_idx = layout.safety_slack_indices()

        self._equality_matrix, self._a_pos, self._b_pos = _equality_pattern(layout)
        self.n_equalities = self._equality_matrix.shape[0]
        self._equality_rhs = np.zeros(self.n_equalities)
        self._inequality_matrix, self._coef_pos = _inequality_pattern(layout)
        self.n_inequalities = self._inequality_matrix.shape[0]
        self._inequality_lower = np.zeros(self.n_inequalities)
        self.variable_lower, self._variable_upper = _box_bounds(config, layout)
        self.cost_matrix, self._cost_vector = _cost(config, layout)
        self._two_q = 2.0 * np.asarray(config.weights.state, dtype=np.float64)
        self._two_s = 2.0 * np.asarray(config.weights.input_rate, dtype=np.float64)

        general = _general_form(self._equality_matrix, self._inequality_matrix, self.variable_lower,
                                self._variable_upper)
        self.boxed_variables = general.boxed_variables
        self._general_matrix, self._general_lower, self._general_upper = general.matrix, general.lower, general.upper
        self._gen_from_eq, self._gen_from_ineq = general.from_equality, general.from_inequality
        self._safe_slack_box_rows = general.box_row_of_variable[self._safe_slack_idx]
        self.variable_shift, self.general_row_shift = _shift_maps(layout, self.n_equalities, self.n_inequalities,
                                                                  general)
        self._allocate_stagewise_data()
        self._sparse_values_stale = False

    def _allocate_stagewise_data(self) -> None:
        """The stage-wise data of the last update (class doc), zero until the first ``update``."""
        horizon, n_slots = self.config.horizon, self.config.max_vehicles
        self.next_states = np.zeros((horizon, STATE_DIM))
        self.state_matrices = np.zeros((horizon, STATE_DIM, STATE_DIM))
        self.input_matrices = np.zeros((horizon, STATE_DIM, INPUT_DIM))
        self.affine_offsets = np.zeros((horizon, STATE_DIM))
        self.collision_coefficients = np.zeros((horizon, n_slots, 3))
        self.collision_row_lower = np.zeros((horizon, n_slots))
        self.safety_slack_upper = np.zeros((horizon, n_slots))
        self.critical_circle = np.zeros((horizon, n_slots), dtype=np.int64)
        self._empty_prediction = np.zeros((horizon + 1, 1, 4))
        self.n_observed = 0
        self.measured_state = np.zeros(STATE_DIM)
        self.last_input = np.zeros(INPUT_DIM)
        self.tracking_reference = np.zeros((horizon + 1, STATE_DIM))
        self.linearization_inputs = np.zeros((horizon, INPUT_DIM))

    @property
    def n_variables(self) -> int:
        return self.layout.n_variables

    def update(self, step: OcpStepData) -> None:
        """Overwrite the QP's values for one MPC step from its data (``OcpStepData``: x_hat, x^r, u^r, x^ref,
        u_hat and the predicted others, V_obs <= V)."""
        if step.horizon != self.config.horizon:
            raise ValueError(f"the step's horizon {step.horizon} is not the QP's N={self.config.horizon}")
        lin_states, lin_inputs = step.linearization_states, step.linearization_inputs
        self.model.linearize(lin_states, lin_inputs, self.next_states, self.state_matrices,
                             self.input_matrices, self.affine_offsets)
        predicted_others = step.predicted_others
        if predicted_others.shape[1] > self.config.max_vehicles:
            raise ValueError(
                f"{predicted_others.shape[1]} vehicles exceed max_vehicles="
                f"{self.config.max_vehicles}")
        n_observed = predicted_others.shape[1]
        if n_observed == 0:
            predicted_others = self._empty_prediction
        linearize_collision_constraints(
            lin_states, predicted_others, n_observed,
            self.circle_offsets_m, self.collision_semi_axes_m, self.safety_semi_axes_m,
            self.collision_coefficients, self.collision_row_lower, self.safety_slack_upper,
            self.critical_circle)
        self.n_observed = n_observed
        self.measured_state[:] = step.measured_state
        self.last_input[:] = step.last_input
        self.tracking_reference[:] = step.tracking_reference
        self.linearization_inputs[:] = lin_inputs
        self._sparse_values_stale = True

    def stagewise_data_changed(self) -> None:
        """Mark the stage-wise data as written in place (as ``update`` does): the sparse forms resync their values
        on their next access."""
        self._sparse_values_stale = True

    def _sync_sparse_values(self) -> None:
        """Write the stage-wise data of the last ``update`` into the sparse forms' values."""
        if not self._sparse_values_stale:
            return
        self._sparse_values_stale = False
        eq_data = self._equality_matrix.data
        eq_data[self._a_pos] = -self.state_matrices
        eq_data[self._b_pos] = -self.input_matrices
        self._equality_rhs[:STATE_DIM] = self.measured_state
        self._equality_rhs[STATE_DIM:] = self.affine_offsets.ravel()
        ineq_data = self._inequality_matrix.data
        ineq_data[self._coef_pos] = self.collision_coefficients
        self._inequality_lower[:] = self.collision_row_lower.ravel()
        self._variable_upper[self._safe_slack_idx] = self.safety_slack_upper
        self._general_upper[self._safe_slack_box_rows] = self.safety_slack_upper

        self._cost_vector[self._state_idx[1:]] = -self._two_q * self.tracking_reference[1:]
        self._cost_vector[self._input_idx[0]] = -self._two_s * self.last_input

        self._general_matrix.data[self._gen_from_eq] = eq_data
        self._general_matrix.data[self._gen_from_ineq] = ineq_data
        self._general_lower[:self.n_equalities] = self._equality_rhs
        self._general_upper[:self.n_equalities] = self._equality_rhs
        self._general_lower[self.n_equalities:self.n_equalities + self.n_inequalities] = (
            self._inequality_lower)

    # Sparse forms: values are written on first access after an ``update`` (solvers that
    # work on the stage-wise data never pay for them).
    @property
    def equality_matrix(self) -> sp.csc_matrix:
        self._sync_sparse_values()
        return self._equality_matrix

    @property
    def equality_rhs(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._equality_rhs

    @property
    def inequality_matrix(self) -> sp.csc_matrix:
        self._sync_sparse_values()
        return self._inequality_matrix

    @property
    def inequality_lower(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._inequality_lower

    @property
    def variable_upper(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._variable_upper

    @property
    def general_matrix(self) -> sp.csc_matrix:
        self._sync_sparse_values()
        return self._general_matrix

    @property
    def general_lower(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._general_lower

    @property
    def general_upper(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._general_upper

    @property
    def cost_vector(self) -> np.ndarray:
        self._sync_sparse_values()
        return self._cost_vector

    def split_solution(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                     np.ndarray]:
        """(states (N + 1, 4), inputs (N, 2), collision slacks (V,), safety slacks (N, V))."""
        return (z[self._state_idx], z[self._input_idx], z[self._col_slack_idx],
                z[self._safe_slack_idx])

    def pack(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """z with the given states and inputs and zero slacks (e.g. a warm start)."""
        z = np.zeros(self.n_variables)
        z[self._state_idx] = states
        z[self._input_idx] = inputs
        return z

    def constraint_violation(self, z: np.ndarray) -> dict[str, float]:
        """Largest violation of each constraint group at z (0 when satisfied)."""
        eq = np.abs(self.equality_matrix @ z - self.equality_rhs)
        ineq = self.inequality_lower - self.inequality_matrix @ z
        lower = self.variable_lower - z
        upper = z - self.variable_upper
        return {
            "equality": float(eq.max(initial=0.0)),
            "inequality": float(np.maximum(ineq, 0.0).max(initial=0.0)),
            "box": float(np.maximum(np.maximum(lower, upper), 0.0).max(initial=0.0)),
        }

    def objective(self, z: np.ndarray) -> float:
        """1/2 z^T P z + q^T z with P's stored upper triangle."""
        upper = self.cost_matrix
        quad = z @ (upper @ z) + z @ (upper.T @ z) - z @ (upper.diagonal() * z)
        return 0.5 * float(quad) + float(self.cost_vector @ z)
