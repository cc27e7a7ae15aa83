"""The QP solvers behind one interface (``QpSolver.solve(qp) -> QpSolution``), selectable by name.

Two kinds:

- through qpsolvers (``osqp``, ``clarabel``, ``piqp``, ``proxqp``): the problem is handed over
  afresh each step (qpsolvers rebuilds the solver); success is qpsolvers' ``found`` flag (its
  ``x`` is garbage otherwise, so it is discarded).
- native fast paths (``piqp_native``, ``osqp_native``): the solver is set up once with the fixed
  sparsity pattern; each step only overwrites values with the library's ``update`` and re-solves
  (warm-started for OSQP).  PIQP gets real +-inf for absent bounds.
- ``riccati_ipm``: our structure-exploiting interior-point method (``interior_point``),
  which reads the QP's stage-wise data and never touches the sparse matrices, warm-started from the
  shifted previous solution; ``riccati_ipm_cold`` is the same method started cold at every step (the
  planner's floats before the warm start: select it to reproduce results of revisions before it).

``make_solver(name, **settings)`` raises ``ValueError`` listing the available names for an
unknown name (at configuration time, before any episode).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.sparse as sp

from srmpc.mpc.problem import LtvMpcQp
from srmpc.mpc.solvers.interior_point import solve_in
from srmpc.mpc.solvers.ipm_iteration import STATUS_NAMES, STATUS_SOLVED
from srmpc.mpc.solvers.ipm_start import WARM_START_SETTINGS, allocate_memory
from srmpc.mpc.solvers.ipm_workspace import allocate_workspace, qp_tuple, scatter_solution

DEFAULT_SOLVER = "riccati_ipm"

# Tolerances: OSQP's default eps 1e-3 gives first-input errors up to ~1 (rad or m/s^2); 1e-5
# is the loosest setting that keeps it within 1e-3 of Clarabel on this QP.
OSQP_TOLERANCE = 1e-5
INTERIOR_POINT_TOLERANCE = 1e-7
NATIVE_PIQP_TOLERANCE = INTERIOR_POINT_TOLERANCE
"""Fast path; at 1e-6 closed-loop first inputs drifted up to 2.3e-3 from Clarabel at 1e-9."""


RICCATI_IPM_TOLERANCE = 1e-8
"""Residual/complementarity tolerance of ``riccati_ipm`` (see ``interior_point``)."""
RICCATI_IPM_MAX_ITERATIONS = 50

SolverConstants = namedtuple("SolverConstants", ["state_weight_hessian", "input_weight_hessian",
                                                 "rate_hessian", "slack_weights", "bounds"])
"""``riccati_ipm``'s per-OCP constants: 2Q (4,), 2R (2,), 2S (2,), (w_c1, w_c2, w_s1, w_s2), the bounds (8,)
(see ``interior_point.solve_ltv_mpc_qp``)."""


@dataclass
class QpSolution:
    """Outcome of one QP solve.

    Attributes:
        solved: True only for an exact success status.
        status: solver-specific status text.
        z: primal solution (None unless solved).
        iterations: solver iterations, where reported.
        solve_time_s: wall time of the solve call [s] (set by the planner).
    """

    solved: bool
    status: str
    z: np.ndarray | None
    iterations: int | None = None
    solve_time_s: float = 0.0


class QpSolver(Protocol):
    """A solver by name.  ``accepts_warm_start = False`` tells the planner not to build the
    primal warm start (the planner assumes True when the attribute is missing)."""

    name: str

    def solve(self, qp: LtvMpcQp, warm_start: np.ndarray | None = None) -> QpSolution:
        """Solve the QP's current values."""
        ...

    def reset(self) -> None:
        """Forget warm-start state (new episode)."""
        ...


def _symmetric(upper: sp.csc_matrix) -> sp.csc_matrix:
    """Full symmetric matrix from an upper triangle (for solvers that take the full P)."""
    full = upper + sp.triu(upper, k=1, format="csc").T
    return sp.csc_matrix(full)


class QpsolversSolver:
    """Any sparse qpsolvers backend; a fresh problem each call (reference path)."""

    def __init__(self, backend: str, **settings) -> None:
        import qpsolvers

        if backend not in qpsolvers.available_solvers:
            raise ValueError(f"qpsolvers backend {backend!r} is not installed; installed: "
                             f"{sorted(qpsolvers.available_solvers)}")
        self.name = backend
        self.backend = backend
        self.settings = settings
        self._cost_full: sp.csc_matrix | None = None

    def reset(self) -> None:
        pass

    def solve(self, qp: LtvMpcQp, warm_start: np.ndarray | None = None) -> QpSolution:
        import qpsolvers

        if self._cost_full is None or self._cost_full.shape != qp.cost_matrix.shape:
            self._cost_full = _symmetric(qp.cost_matrix)
        problem = qpsolvers.Problem(
            self._cost_full, qp.cost_vector.copy(),
            G=-qp.inequality_matrix, h=-qp.inequality_lower,
            A=qp.equality_matrix.copy(), b=qp.equality_rhs.copy(),
            lb=qp.variable_lower, ub=qp.variable_upper)
        try:
            solution = qpsolvers.solve_problem(problem, solver=self.backend, **self.settings)
        except Exception as error:  # noqa: BLE001 -- any backend failure is a failed solve
            return QpSolution(False, f"exception: {error!r}", None)
        if not solution.found or solution.x is None or not np.all(np.isfinite(solution.x)):
            return QpSolution(False, "not found", None)
        return QpSolution(True, "found", np.asarray(solution.x, dtype=np.float64))


class PiqpNativeSolver:
    """PIQP sparse solver: set up once, then ``update`` values and re-solve."""

    name = "piqp_native"
    accepts_warm_start = False

    def __init__(self, **settings) -> None:
        import piqp

        self._piqp = piqp
        self.settings = {"eps_abs": NATIVE_PIQP_TOLERANCE, "eps_rel": NATIVE_PIQP_TOLERANCE,
                         "preconditioner_reuse_on_update": True,
                         "kkt_solver": piqp.KKTSolver.sparse_ldlt_eq_cond, **settings}
        self._solver = None
        self._upper_inf: np.ndarray | None = None

    def reset(self) -> None:
        self._solver = None

    def _setup(self, qp: LtvMpcQp) -> None:
        piqp = self._piqp
        solver = piqp.SparseSolver()
        for key, value in self.settings.items():
            setattr(solver.settings, key, value)
        self._upper_inf = np.full(qp.n_inequalities, np.inf)
        solver.setup(qp.cost_matrix, qp.cost_vector, qp.equality_matrix, qp.equality_rhs,
                     qp.inequality_matrix, qp.inequality_lower, self._upper_inf,
                     qp.variable_lower, qp.variable_upper)
        self._solver = solver
        self._shape = (qp.n_variables, qp.n_equalities, qp.n_inequalities)

    def solve(self, qp: LtvMpcQp, warm_start: np.ndarray | None = None) -> QpSolution:
        piqp = self._piqp
        try:
            if self._solver is None or self._shape != (qp.n_variables, qp.n_equalities,
                                                        qp.n_inequalities):
                self._setup(qp)
            else:
                self._solver.update(c=qp.cost_vector, A=qp.equality_matrix, b=qp.equality_rhs,
                                    G=qp.inequality_matrix, h_l=qp.inequality_lower,
                                    x_u=qp.variable_upper)
            status = self._solver.solve()
        except Exception as error:  # noqa: BLE001 -- a crashed solve is a failed solve
            self._solver = None
            return QpSolution(False, f"exception: {error!r}", None)
        result = self._solver.result
        solved = status == piqp.PIQP_SOLVED
        z = np.array(result.x, dtype=np.float64) if solved else None
        if z is not None and not np.all(np.isfinite(z)):
            solved, z = False, None
        return QpSolution(solved, str(status), z, int(result.info.iter))


class OsqpNativeSolver:
    """OSQP on the general form: set up once, then ``update(q, l, u, Ax)``, warm-started."""

    name = "osqp_native"

    def __init__(self, **settings) -> None:
        import osqp

        self._osqp = osqp
        self.settings = {"eps_abs": OSQP_TOLERANCE, "eps_rel": OSQP_TOLERANCE,
                         "warm_starting": True, "polishing": False, "verbose": False,
                         "max_iter": 20000, **settings}
        self._solver = None
        self._previous: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self) -> None:
        self._solver = None
        self._previous = None

    def solve(self, qp: LtvMpcQp, warm_start: np.ndarray | None = None) -> QpSolution:
        osqp = self._osqp
        try:
            if self._solver is None or self._n != qp.n_variables:
                solver = osqp.OSQP()
                solver.setup(qp.cost_matrix.copy(), qp.cost_vector.copy(),
                             qp.general_matrix.copy(), qp.general_lower.copy(),
                             qp.general_upper.copy(), **self.settings)
                self._solver = solver
                self._n = qp.n_variables
            else:
                self._solver.update(q=qp.cost_vector, l=qp.general_lower, u=qp.general_upper,
                                    Ax=qp.general_matrix.data)
            if self._previous is not None:
                x_previous, y_previous = self._previous
                self._solver.warm_start(x=x_previous[qp.variable_shift],
                                        y=y_previous[qp.general_row_shift])
            elif warm_start is not None:
                self._solver.warm_start(x=warm_start)
            result = self._solver.solve(raise_error=False)
        except Exception as error:  # noqa: BLE001 -- a crashed solve is a failed solve
            self._solver = None
            return QpSolution(False, f"exception: {error!r}", None)
        status = result.info.status_val
        solved = status == osqp.SolverStatus.OSQP_SOLVED
        z = np.array(result.x, dtype=np.float64) if solved else None
        self._previous = (z, np.array(result.y, dtype=np.float64)) if solved else None
        if z is not None and not np.all(np.isfinite(z)):
            solved, z = False, None
        return QpSolution(solved, str(result.info.status), z, int(result.info.iter))


class RiccatiInteriorPointSolver:
    """``interior_point`` on the QP's stage-wise data, in arrays allocated once.

    Starts from the shifted previous solution (primal and multipliers, ``ipm_start``)
    when the previous solve succeeded and ``warm_start`` is on; otherwise (and as the safeguard when a
    warm start fails) from the linearization inputs, clipped into their box, rolled out through the
    linearized dynamics. Any status other than solved is a failed solve (the planner's fallback chain
    takes over).

    ``warm_start_settings``: ``ipm_start.WARM_START_SETTINGS``' layout (mu_0 floor, centrality, slack floor,
    stage shift, warm iteration limit); the planner's by default. ``warm_start=False`` (the solver name
    ``riccati_ipm_cold``) starts every solve cold: the planner's floats
    of the revisions before the warm start, bit for bit (``tests/mpc/test_compiled_step.py`` checks that the
    compiled step and the Python path agree bit for bit in that mode). Warm, the first input stays within
    1e-3 of Clarabel's (same test) and the interior point takes 7 iterations at the median instead of 9
    (``results/benchmarks/srmpc_latency.json``).
    """

    name = "riccati_ipm"
    accepts_warm_start = False

    def __init__(self, tolerance: float = RICCATI_IPM_TOLERANCE,
                 max_iterations: int = RICCATI_IPM_MAX_ITERATIONS,
                 warm_start: bool = True, warm_start_settings: tuple | None = None) -> None:
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self.warm_start = bool(warm_start)
        # the planner's (``WARM_START_SETTINGS``), its warm iterations bounded by the solver's own limit
        self.warm_start_settings = (tuple(warm_start_settings) if warm_start_settings is not None
                                    else (*WARM_START_SETTINGS[:4], self.max_iterations))
        self.last_started_warm = False
        self._constants_for: LtvMpcQp | None = None

    def reset(self) -> None:
        """New episode: forget the previous solution (the next solve starts cold)."""
        if self._constants_for is not None:
            self.memory.valid[0] = False

    def _prepare(self, qp: LtvMpcQp) -> None:
        config = qp.config
        weights = config.weights
        horizon, n_slots = config.horizon, config.max_vehicles
        self.constants = SolverConstants(
            2.0 * np.asarray(weights.state, dtype=np.float64),
            2.0 * np.asarray(weights.input, dtype=np.float64),
            2.0 * np.asarray(weights.input_rate, dtype=np.float64),
            np.array([weights.collision_slack_linear, weights.collision_slack_quadratic,
                      weights.safety_slack_linear, weights.safety_slack_quadratic], dtype=np.float64),
            np.array([*config.lateral_bounds_m, *config.speed_bounds_mps,
                      config.steering_bounds_rad[0], config.acceleration_bounds_mps2[0],
                      config.steering_bounds_rad[1], config.acceleration_bounds_mps2[1]],
                     dtype=np.float64))
        self.workspace = allocate_workspace(horizon, n_slots)
        self.memory = allocate_memory(horizon, n_slots, self.workspace[1].t.shape[0])
        layout = qp.layout
        self._scatter = np.concatenate([layout.state_indices().ravel(),
                                        layout.input_indices().ravel(),
                                        layout.collision_slack_indices(),
                                        layout.safety_slack_indices().ravel()])
        self._constants_for = qp

    def bind(self, qp: LtvMpcQp) -> None:
        """Allocate the arrays for ``qp`` (once; the compiled planner step shares them)."""
        if self._constants_for is not qp:
            self._prepare(qp)

    def solve(self, qp: LtvMpcQp, warm_start: np.ndarray | None = None) -> QpSolution:
        self.bind(qp)
        c = self.constants
        try:
            problem = qp_tuple(qp.last_input, qp.state_matrices, qp.input_matrices, qp.affine_offsets,
                               qp.tracking_reference, qp.collision_coefficients, qp.collision_row_lower,
                               qp.safety_slack_upper, qp.n_observed, c.state_weight_hessian,
                               c.input_weight_hessian, c.rate_hessian, c.slack_weights, c.bounds)
            status, iterations, self.last_started_warm = solve_in(
                qp.measured_state, problem, qp.linearization_inputs, self.tolerance, self.max_iterations,
                self.workspace, self.memory, self.warm_start, self.warm_start_settings)
        except Exception as error:  # noqa: BLE001 -- a crashed solve is a failed solve
            self.memory.valid[0] = False
            return QpSolution(False, f"exception: {error!r}", None)
        if status != STATUS_SOLVED:
            return QpSolution(False, STATUS_NAMES[status], None, int(iterations))
        z = np.empty(qp.n_variables)
        if not scatter_solution(*self.workspace[0], self._scatter, z):
            self.memory.valid[0] = False
            return QpSolution(False, "non-finite solution", None, int(iterations))
        return QpSolution(True, STATUS_NAMES[status], z, int(iterations))


def _riccati_ipm_cold(**settings) -> RiccatiInteriorPointSolver:
    return RiccatiInteriorPointSolver(**{**settings, "warm_start": False})


def _qpsolvers_osqp(**settings) -> QpsolversSolver:
    return QpsolversSolver("osqp", eps_abs=OSQP_TOLERANCE, eps_rel=OSQP_TOLERANCE,
                           polishing=False, max_iter=20000, **settings)


def _qpsolvers_clarabel(**settings) -> QpsolversSolver:
    return QpsolversSolver("clarabel", **{"tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9,
                                          "tol_feas": 1e-9, **settings})


def _qpsolvers_piqp(**settings) -> QpsolversSolver:
    return QpsolversSolver("piqp", **{"eps_abs": INTERIOR_POINT_TOLERANCE,
                                      "eps_rel": INTERIOR_POINT_TOLERANCE, **settings})


def _qpsolvers_proxqp(**settings) -> QpsolversSolver:
    return QpsolversSolver("proxqp", **{"eps_abs": INTERIOR_POINT_TOLERANCE, **settings})


SOLVER_FACTORIES = {
    "riccati_ipm": RiccatiInteriorPointSolver,
    "riccati_ipm_cold": _riccati_ipm_cold,
    "piqp_native": PiqpNativeSolver,
    "osqp_native": OsqpNativeSolver,
    "osqp": _qpsolvers_osqp,
    "clarabel": _qpsolvers_clarabel,
    "piqp": _qpsolvers_piqp,
    "proxqp": _qpsolvers_proxqp,
}
"""The solver-name table: our structured solver, native fast paths, then qpsolvers backends."""


def available_solvers() -> list[str]:
    return list(SOLVER_FACTORIES)


def make_solver(name: str, **settings) -> QpSolver:
    """Instantiate a solver by name; unknown names raise ValueError listing the valid ones."""
    try:
        factory = SOLVER_FACTORIES[name]
    except KeyError:
        raise ValueError(
            f"unknown QP solver {name!r}; available: {', '.join(available_solvers())}"
        ) from None
    return factory(**settings)
