"""HPIPM through CasADi's ``hpipm`` conic plugin, on the LTV-MPC QP in HPIPM's stage-wise form.

The problem is ``hpipm_stagewise.StagewiseQp`` (its doc states the layout: per stage nx = 4 / 6 + m / 4,
nu = 2 + m (2 + 2m at N - 1, 0 at N), ng = 0 / m / 2m / 0), handed to ``casadi.conic(..., "hpipm", ...)``
with the structure options ``N``, ``nx``, ``nu``, ``ng`` and the variables ordered
[x~_0, u~_0, x~_1, u~_1, ..., x~_N]. Its constraint matrix has, per stage, the dynamics rows
A_k x~_k + B_k u~_k - x~_{k+1} = -b_k (CasADi's gap rows: lba = uba = -b_k) followed by the ng_k rows
[C_k D_k]; its Hessian holds the stage blocks [Q_k S_k^T; S_k R_k] only.

What CasADi's interface does, read in its source (``casadi/interfaces/hpipm/hpipm_interface.cpp`` and
``hpipm_runtime.hpp`` at the repository's head; the 3.8.2 wheel has no tag there to compare) and checked with
the 3.8.2 wheel where marked (checked):

- **every variable is boxed**: it sets nbx = nx, nbu = nu and idxb = 0..n-1 on every stage, and replaces
  each infinite bound (and each infinite row bound) by -+``inf`` (option, default 1e8) (checked: a 5-variable
  QP whose solution a box at +-``inf`` cuts off, and ``tests/mpc/test_hpipm_reference.py``, where the QP far
  down the road is infeasible through the plugin). HPIPM's idxb and its constraint masks are not exposed,
  nor its soft constraints, so through CasADi HPIPM carries 2 (nx + nu + ng) inequalities per stage where
  our QP has only the bounds listed in ``hpipm_stagewise``.
  ``CASADI_INFINITY`` = 1e4 is above every value of our QPs (module constant); HPIPM converges with it.
- it allocates HPIPM's dimension, QP, solution, argument and workspace structures with ``malloc`` on every
  call, copies the sparse inputs into them, calls ``d_ocp_qp_ipm_solve`` and copies the solution out;
  the ``t_wall_solver`` / ``t_proc_solver`` statistics time all of that (CasADi's "solver" timer wraps
  the whole runtime call), so they are not HPIPM's own solve time (``hpipm_native`` measures that);
- the primal guess ``x0`` is passed to HPIPM (``d_ocp_qp_sol_set_u/x``), so HPIPM's ``warm_start = 1``
  (primal warm start) works (checked: it takes HPIPM from 23 to 10 median iterations in
  ``results/benchmarks/qp_solvers.json``); multipliers are not passed (the code that would is commented out);
- it halves H and g before handing them to HPIPM (its cost convention), which halves HPIPM's multipliers,
  its stationarity and complementarity residuals and its barrier parameter: ``res_g_max``, ``res_m_max``
  and ``mu0`` are passed halved, so that the settings mean what ``hpipm_native``'s do;
- the wheel's HPIPM and BLASFEO are built for BLASFEO's ``GENERIC`` target (CasADi's CMakeLists passes
  ``-DTARGET=GENERIC``; checked: the wheel's ``libblasfeo.so.0`` lists no required CPU features and holds only
  the C 4x4 kernels), not the AVX2 kernels acados builds use on x86-64 (docs/benchmarks.md).

Options used (``hpipm`` dict), the settings of ``hpipm_native`` (its constants say why): ``mode``
(``speed``: relative IPM formulation, predictor-corrector, no iterative refinement), the exit tolerances
res_g_max (stationarity), res_b_max (equalities), res_d_max (inequalities), res_m_max (complementarity),
``mu0``, ``iter_max`` and ``warm_start`` (1: start from ``x0``).

CasADi is an optional dependency (``pip install -e '.[nmpc]'``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from srmpc.mpc.solvers.hpipm_native import (
    HPIPM_MAX_ITERATIONS,
    HPIPM_MODE,
    HPIPM_MU0,
    HPIPM_STATIONARITY_TOLERANCE,
    HPIPM_TOLERANCE,
)
from srmpc.mpc.solvers.hpipm_stagewise import StagewiseQp

CASADI_INFINITY = 1e4
"""What CasADi puts in place of an infinite bound (option ``inf``), in the bounded quantity's units (m,
rad, m/s, m/s^2, ellipse norm): above any value of our QPs (the ego's x stays below 4e3 m: 80 s at the
40 m/s speed bound); at CasADi's default 1e8 HPIPM stopped at its 50-iteration limit on each of the three
QPs of ``tests/mpc/test_hpipm_reference.py``, which it solves in 13-23 iterations at 1e4 or 1e6."""


@dataclass
class HpipmSolution:
    """One HPIPM solve: z in ``LtvMpcQp``'s layout (None unless solved), status code (0 solved),
    iterations, the wall time of the CasADi call [s] and CasADi's ``t_wall_solver`` [s]."""

    z: np.ndarray | None
    status: int
    iterations: int
    call_s: float
    reported_solver_s: float

    @property
    def solved(self) -> bool:
        return self.status == 0 and self.z is not None


class _CasadiProblem:
    """The conic function and the fixed sparsity maps for one number of observed vehicles m."""

    def __init__(self, horizon: int, m: int, options: dict) -> None:
        self.stages = StagewiseQp(horizon, m)
        s = self.stages
        nx, nu, ng = s.nx, s.nu, s.ng
        starts = np.concatenate([[0], np.cumsum(nx + nu)])
        self.x_start, self.u_start = starts[:-1], starts[:-1] + nx
        self.n = int(starts[-1])
        row = 0
        self.dyn_rows, self.gen_rows = [], []
        for k in range(horizon + 1):
            if k < horizon:
                self.dyn_rows.append(row)
                row += nx[k + 1]
            self.gen_rows.append(row)
            row += ng[k]
        self.n_rows = row
        hess_pattern = np.zeros((self.n, self.n), dtype=bool)
        cons_pattern = np.zeros((self.n_rows, self.n), dtype=bool)
        for k in range(horizon + 1):
            block = slice(self.x_start[k], self.u_start[k] + nu[k])
            hess_pattern[block, block] = True
            gen = slice(self.gen_rows[k], self.gen_rows[k] + ng[k])
            cons_pattern[gen, block] = True
            if k < horizon:
                dyn = slice(self.dyn_rows[k], self.dyn_rows[k] + nx[k + 1])
                cons_pattern[dyn, block] = True
                cons_pattern[dyn, self.x_start[k + 1]:self.x_start[k + 1] + nx[k + 1]] = np.eye(nx[k + 1], dtype=bool)
        self.hess_rows, self.hess_cols = np.nonzero(hess_pattern.T)[::-1]  # column-major order
        self.cons_rows, self.cons_cols = np.nonzero(cons_pattern.T)[::-1]
        self.hess_sparsity = ca.Sparsity.triplet(self.n, self.n, self.hess_rows.tolist(), self.hess_cols.tolist())
        self.cons_sparsity = ca.Sparsity.triplet(self.n_rows, self.n, self.cons_rows.tolist(),
                                                 self.cons_cols.tolist())
        self.solver = ca.conic(f"hpipm_ltv_mpc_m{m}", "hpipm",
                               {"h": self.hess_sparsity, "a": self.cons_sparsity},
                               {"N": horizon, "nx": nx.tolist(), "nu": nu.tolist(), "ng": ng.tolist(), **options})
        self._hessian = np.zeros((self.n, self.n))
        self._constraint = np.zeros((self.n_rows, self.n))
        for k in range(horizon):
            rows = slice(self.dyn_rows[k], self.dyn_rows[k] + nx[k + 1])
            self._constraint[rows, self.x_start[k + 1]:self.x_start[k + 1] + nx[k + 1]] = -np.eye(nx[k + 1])

    def arguments(self) -> dict:
        """CasADi's h, g, a, lba, uba, lbx, ubx from the stage arrays (module doc's layout)."""
        s = self.stages
        hess, cons = self._hessian, self._constraint
        g = np.zeros(self.n)
        lbx, ubx = np.full(self.n, -np.inf), np.full(self.n, np.inf)
        lba, uba = np.empty(self.n_rows), np.empty(self.n_rows)
        for k in range(s.horizon + 1):
            xs, us, nxk, nuk, ngk = self.x_start[k], self.u_start[k], s.nx[k], s.nu[k], s.ng[k]
            xb, ub = slice(xs, xs + nxk), slice(us, us + nuk)
            hess[xb, xb], hess[ub, ub], hess[ub, xb], hess[xb, ub] = s.Q[k], s.R[k], s.S[k], s.S[k].T
            g[xb], g[ub] = s.q[k], s.r[k]
            lbx[xs + s.idxbx[k]], ubx[xs + s.idxbx[k]] = s.lbx[k], s.ubx[k]
            lbx[us + s.idxbu[k]], ubx[us + s.idxbu[k]] = s.lbu[k], s.ubu[k]
            gen = slice(self.gen_rows[k], self.gen_rows[k] + ngk)
            cons[gen, xb], cons[gen, ub] = s.C[k], s.D[k]
            lba[gen], uba[gen] = s.lg[k], s.ug[k]
            if k < s.horizon:
                dyn = slice(self.dyn_rows[k], self.dyn_rows[k] + s.nx[k + 1])
                cons[dyn, xb], cons[dyn, ub] = s.A[k], s.B[k]
                lba[dyn] = uba[dyn] = -s.b[k]
        return {"h": ca.DM(self.hess_sparsity, hess[self.hess_rows, self.hess_cols]), "g": g,
                "a": ca.DM(self.cons_sparsity, cons[self.cons_rows, self.cons_cols]),
                "lba": lba, "uba": uba, "lbx": lbx, "ubx": ubx}

    def pack(self, states: list[np.ndarray], controls: list[np.ndarray]) -> np.ndarray:
        w = np.empty(self.n)
        for k in range(self.stages.horizon + 1):
            w[self.x_start[k]:self.u_start[k]] = states[k]
            w[self.u_start[k]:self.u_start[k] + self.stages.nu[k]] = controls[k]
        return w

    def unpack(self, w: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        s = self.stages
        states = [w[self.x_start[k]:self.u_start[k]] for k in range(s.horizon + 1)]
        controls = [w[self.u_start[k]:self.u_start[k] + s.nu[k]] for k in range(s.horizon + 1)]
        return states, controls


class HpipmCasadiSolver:
    """HPIPM on an ``LtvMpcQp``'s current values through CasADi's plugin (module doc).

    ``warm_start=True``: HPIPM starts from the previous solution shifted by one stage (``qp.variable_shift``),
    as our solver does; cold: from HPIPM's own initialization.
    """

    def __init__(self, tolerance: float = HPIPM_TOLERANCE, max_iterations: int = HPIPM_MAX_ITERATIONS,
                 warm_start: bool = False, infinity: float = CASADI_INFINITY, mode: str = HPIPM_MODE,
                 stationarity_tolerance: float = HPIPM_STATIONARITY_TOLERANCE, mu0: float = HPIPM_MU0) -> None:
        self.warm_start = bool(warm_start)
        self.options = {"inf": float(infinity), "error_on_fail": False,
                        "hpipm": {"mode": mode, "iter_max": int(max_iterations),
                                  "res_g_max": 0.5 * stationarity_tolerance, "res_b_max": tolerance,
                                  "res_d_max": tolerance, "res_m_max": 0.5 * tolerance, "mu0": 0.5 * mu0,
                                  "warm_start": int(self.warm_start)}}
        self._problems: dict[tuple[int, int], _CasadiProblem] = {}
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        self._previous = None

    def problem(self, qp) -> _CasadiProblem:
        key = (qp.config.horizon, qp.n_observed)
        if key not in self._problems:
            self._problems[key] = _CasadiProblem(*key, self.options)
        return self._problems[key]

    def solve(self, qp) -> HpipmSolution:
        problem = self.problem(qp)
        problem.stages.update(qp)
        arguments = problem.arguments()
        if self.warm_start and self._previous is not None:
            arguments["x0"] = problem.pack(*problem.stages.stagewise_from_z(qp, self._previous[qp.variable_shift]))
        start = time.perf_counter()
        out = problem.solver(**arguments)
        call_s = time.perf_counter() - start
        stats = problem.solver.stats()
        status = int(stats["return_status"])
        z = None
        if status == 0:
            z = problem.stages.z_from_stagewise(qp, *problem.unpack(np.asarray(out["x"]).ravel()))
            if not np.all(np.isfinite(z)):
                z, status = None, -1
        self._previous = z
        return HpipmSolution(z, status, int(stats["iter_count"]), call_s, float(stats["t_wall_solver"]))
