"""HPIPM called through its own C API (ctypes), on the LTV-MPC QP in its stage-wise form.

CasADi's plugin boxes every variable and rebuilds HPIPM's structures on every call (``hpipm_reference``);
this module gives HPIPM the problem as its own interface takes it, from the ``libhpipm.so`` that CasADi's
wheel ships (the same library the plugin calls; another build may be passed as ``library``):

- dimensions per stage (``d_ocp_qp_dim_set_{nx,nu,nbx,nbu,ng}``) as in ``hpipm_stagewise``, with boxes
  only on the bounded components (``idxbx`` / ``idxbu``: x_0, y and v, the inputs, s, sigma) and the
  one-sided ones masked (``ubu_mask`` = 0 on s's upper side, ``ug_mask`` = 0 on every row's upper side):
  no artificial bounds;
- HPIPM's dimension, QP, solution, argument and workspace structures created once per number of observed
  vehicles m, each QP's values written into them with HPIPM's setters (``d_ocp_qp_set_A`` ...);
- mode ``SPEED`` (``d_ocp_qp_ipm_arg_set_default``), the exit tolerances ``tol_eq``, ``tol_ineq``,
  ``tol_comp`` and ``iter_max`` as ours, ``tol_stat`` and ``mu0`` as the constants below say (chosen on
  the benchmark's sweep of HPIPM's settings); ``warm_start = 1`` starts from the previous solution
  shifted by one stage (``d_ocp_qp_sol_set_u/x``), as our solver's warm start does;
- HPIPM minimizes sum_k 1/2 [u; x]^T [R S; S^T Q] [u; x] + r^T u + q^T x: the stage blocks of our
  1/2 z^T P z + q^T z, so its residuals are in our units and the tolerances mean the same.

Timing: ``solve_s`` is the ``d_ocp_qp_ipm_solve`` call alone (HPIPM's own solve, plus one ctypes call);
``setup_s`` is writing the values (one ctypes call per field and stage from Python, so it measures this
binding, not HPIPM) and reading the solution back.
"""

from __future__ import annotations

import ctypes
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from srmpc.mpc.solvers.hpipm_stagewise import StagewiseQp

HPIPM_TOLERANCE = 1e-8
"""HPIPM's exit tolerances on the equality and inequality residuals and on complementarity: our solver's
``solvers.RICCATI_IPM_TOLERANCE`` (absolute in both; HPIPM's complementarity test is on the largest
product t_i lam_i, ours on their mean, so HPIPM's is the stricter)."""
HPIPM_STATIONARITY_TOLERANCE = 1e-4
"""HPIPM's ``tol_stat`` (absolute, objective units per variable unit): ours. Ours is relative, 1e-8 x max(1, the
largest term of the Lagrangian's gradient), and with any observed vehicle the collision slack's cost gradient
w_col,1 = 1e4 is among the terms, so ours is then at least 1e-4 absolute; HPIPM gets that 1e-4 (its speed mode's
default, 1e-6, would ask more of it than we ask of ours). The benchmark's sweep of HPIPM's settings
(``results/benchmarks/qp_solvers.json``,
``hpipm_settings_sweep``, 233 planner QPs, mode speed): at tol_stat = 1e-8 HPIPM stopped at its iteration
limit on 9 QPs (mu0 = 10) and 6 (mu0 = 1); at 1e-6 on 1 and 0; 1e-4 saved at most one median iteration."""
HPIPM_MU0 = 1.0
"""HPIPM's initial barrier parameter ``mu0`` (objective units): the best of 1, 10 (speed mode's default)
and 100 in the same sweep (22 median iterations and no failure at tol_stat = 1e-6, against 24 and 27)."""
HPIPM_MODE = "speed"
"""HPIPM's speed-oriented mode that still checks its residuals (``speed_abs`` stops on the barrier parameter
alone and failed on 8 to 59 of the sweep's 233 QPs; ``balance`` took 27 or more median iterations)."""
HPIPM_MAX_ITERATIONS = 50
"""HPIPM's ``iter_max``: our solver's ``solvers.RICCATI_IPM_MAX_ITERATIONS``."""
HPIPM_MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}
"""HPIPM's ``enum hpipm_mode``."""
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)
_INT_P = ctypes.POINTER(ctypes.c_int)


def casadi_hpipm_library() -> Path:
    """The ``libhpipm.so`` inside the installed CasADi wheel."""
    import casadi

    return Path(os.path.dirname(casadi.__file__)) / "libhpipm.so"


def _ptr(array: np.ndarray):
    if array.dtype == np.int32:
        return array.ctypes.data_as(_INT_P)
    return array.ctypes.data_as(_DOUBLE_P)


class _Library:
    """The C functions used, with their argument types."""

    def __init__(self, path: Path) -> None:
        lib = ctypes.CDLL(str(path))
        size = ctypes.c_size_t
        for name in ("d_ocp_qp_dim_strsize", "d_ocp_qp_strsize", "d_ocp_qp_sol_strsize", "d_ocp_qp_ipm_arg_strsize",
                     "d_ocp_qp_ipm_ws_strsize"):
            getattr(lib, name).restype = size
        for name in ("d_ocp_qp_dim_memsize", "d_ocp_qp_memsize", "d_ocp_qp_sol_memsize", "d_ocp_qp_ipm_arg_memsize",
                     "d_ocp_qp_ipm_ws_memsize"):
            getattr(lib, name).restype = size
        lib.d_ocp_qp_dim_memsize.argtypes = [ctypes.c_int]
        self.lib = lib

    def __getattr__(self, name):
        return getattr(self.lib, name)


class _Workspace:
    """HPIPM's structures for one (N, m), created once (module doc)."""

    def __init__(self, lib: _Library, stages: StagewiseQp, mode: str, tolerance: float, max_iterations: int,
                 warm_start: bool, mu0: float | None, stationarity_tolerance: float | None) -> None:
        self.lib, self.stages = lib, stages
        n = stages.horizon
        self._keep = []

        def struct_and_memory(strsize, memsize):
            struct = ctypes.create_string_buffer(int(strsize))
            memory = ctypes.create_string_buffer(int(memsize))
            self._keep.extend([struct, memory])
            return struct, memory

        self.dim, memory = struct_and_memory(lib.d_ocp_qp_dim_strsize(), lib.d_ocp_qp_dim_memsize(n))
        lib.d_ocp_qp_dim_create(ctypes.c_int(n), self.dim, memory)
        for k in range(n + 1):
            for field, value in (("nx", stages.nx[k]), ("nu", stages.nu[k]), ("nbx", len(stages.idxbx[k])),
                                 ("nbu", len(stages.idxbu[k])), ("ng", stages.ng[k]), ("ns", 0)):
                getattr(lib, f"d_ocp_qp_dim_set_{field}")(ctypes.c_int(k), ctypes.c_int(int(value)), self.dim)
        self.qp, memory = struct_and_memory(lib.d_ocp_qp_strsize(), lib.d_ocp_qp_memsize(self.dim))
        lib.d_ocp_qp_create(self.dim, self.qp, memory)
        self.sol, memory = struct_and_memory(lib.d_ocp_qp_sol_strsize(), lib.d_ocp_qp_sol_memsize(self.dim))
        lib.d_ocp_qp_sol_create(self.dim, self.sol, memory)
        self.arg, memory = struct_and_memory(lib.d_ocp_qp_ipm_arg_strsize(), lib.d_ocp_qp_ipm_arg_memsize(self.dim))
        lib.d_ocp_qp_ipm_arg_create(self.dim, self.arg, memory)
        lib.d_ocp_qp_ipm_arg_set_default(ctypes.c_int(HPIPM_MODES[mode]), self.arg)
        for field in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp"):
            getattr(lib, f"d_ocp_qp_ipm_arg_set_{field}")(ctypes.byref(ctypes.c_double(tolerance)), self.arg)
        if stationarity_tolerance is not None:
            lib.d_ocp_qp_ipm_arg_set_tol_stat(ctypes.byref(ctypes.c_double(stationarity_tolerance)), self.arg)
        if mu0 is not None:
            lib.d_ocp_qp_ipm_arg_set_mu0(ctypes.byref(ctypes.c_double(mu0)), self.arg)
        lib.d_ocp_qp_ipm_arg_set_iter_max(ctypes.byref(ctypes.c_int(max_iterations)), self.arg)
        lib.d_ocp_qp_ipm_arg_set_warm_start(ctypes.byref(ctypes.c_int(int(warm_start))), self.arg)
        self.ws, memory = struct_and_memory(lib.d_ocp_qp_ipm_ws_strsize(),
                                            lib.d_ocp_qp_ipm_ws_memsize(self.dim, self.arg))
        lib.d_ocp_qp_ipm_ws_create(self.dim, self.arg, self.ws, memory)
        self._setters = self._bind_setters()
        self.states = [np.zeros(stages.nx[k]) for k in range(n + 1)]
        self.controls = [np.zeros(stages.nu[k]) for k in range(n + 1)]
        self._state_ptrs = [_ptr(a) for a in self.states]
        self._control_ptrs = [_ptr(a) for a in self.controls]
        masks = []  # constant: the index sets and masks of the one-sided bounds
        for k in range(n + 1):
            for field, array in (("idxbx", stages.idxbx[k]), ("idxbu", stages.idxbu[k]),
                                 ("ubx_mask", stages.ubx_finite[k]), ("ubu_mask", stages.ubu_finite[k]),
                                 ("ug_mask", stages.ug_finite[k])):
                if array.size:
                    masks.append((getattr(lib, f"d_ocp_qp_set_{field}"), k, _ptr(array)))
        self._constant = masks

    def _bind_setters(self) -> list:
        """(setter, stage, pointer) for every value array of the stages (pointers are stable)."""
        s, lib, calls = self.stages, self.lib, []
        n = s.horizon
        self._finite_copies = []
        for k in range(n + 1):
            fields = [("Q", s.Q[k]), ("S", s.S[k]), ("R", s.R[k]), ("q", s.q[k]), ("r", s.r[k]), ("C", s.C[k]),
                      ("D", s.D[k]), ("lg", s.lg[k]), ("lbx", s.lbx[k]), ("lbu", s.lbu[k])]
            for field, source, finite in (("ubx", s.ubx[k], s.ubx_finite[k]), ("ubu", s.ubu[k], s.ubu_finite[k]),
                                          ("ug", s.ug[k], s.ug_finite[k])):
                buffer = np.zeros(source.size)  # masked sides get a finite placeholder (0), never +inf
                self._finite_copies.append((buffer, source, finite > 0.0))
                fields.append((field, buffer))
            if k < n:
                fields += [("A", s.A[k]), ("B", s.B[k]), ("b", s.b[k])]
            for field, array in fields:
                if array.size:
                    calls.append((getattr(lib, f"d_ocp_qp_set_{field}"), k, _ptr(array)))
        return calls

    def write(self) -> None:
        """Copy the stage arrays into HPIPM's QP (upper bounds that do not exist are masked)."""
        for buffer, source, finite in self._finite_copies:
            buffer[finite] = source[finite]
        for setter, k, pointer in self._setters:
            setter(k, pointer, self.qp)
        for setter, k, pointer in self._constant:
            setter(k, pointer, self.qp)

    def set_guess(self, states: list[np.ndarray], controls: list[np.ndarray]) -> None:
        for k in range(self.stages.horizon + 1):
            self.states[k][:] = states[k]
            self.controls[k][:] = controls[k]
            self.lib.d_ocp_qp_sol_set_x(k, self._state_ptrs[k], self.sol)
            if self.controls[k].size:
                self.lib.d_ocp_qp_sol_set_u(k, self._control_ptrs[k], self.sol)

    def read(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        for k in range(self.stages.horizon + 1):
            self.lib.d_ocp_qp_sol_get_x(k, self.sol, self._state_ptrs[k])
            if self.controls[k].size:
                self.lib.d_ocp_qp_sol_get_u(k, self.sol, self._control_ptrs[k])
        return self.states, self.controls


@dataclass
class HpipmNativeSolution:
    """One solve: z (``LtvMpcQp`` layout, None unless solved), HPIPM's status (0 success), iterations,
    the ``d_ocp_qp_ipm_solve`` call [s] and the value writing + solution reading around it [s]."""

    z: np.ndarray | None
    status: int
    iterations: int
    solve_s: float
    setup_s: float

    @property
    def solved(self) -> bool:
        return self.status == 0 and self.z is not None


class HpipmNativeSolver:
    """HPIPM's C API on an ``LtvMpcQp``'s current values (module doc); ``warm_start`` as in
    ``hpipm_reference.HpipmCasadiSolver``. ``mu0`` (HPIPM's initial barrier parameter) and
    ``stationarity_tolerance`` (its ``tol_stat``): None leaves the mode's default and ``tolerance``."""

    def __init__(self, tolerance: float = HPIPM_TOLERANCE, max_iterations: int = HPIPM_MAX_ITERATIONS,
                 warm_start: bool = False, mode: str = HPIPM_MODE, library: Path | None = None,
                 mu0: float | None = HPIPM_MU0,
                 stationarity_tolerance: float | None = HPIPM_STATIONARITY_TOLERANCE) -> None:
        if mode not in HPIPM_MODES:
            raise ValueError(f"mode={mode!r}: expected one of {sorted(HPIPM_MODES)}")
        self.library_path = Path(library) if library is not None else casadi_hpipm_library()
        if not self.library_path.is_file():
            raise ValueError(f"library={str(self.library_path)!r}: no such file")
        self._lib = _Library(self.library_path)
        self.settings = (mode, float(tolerance), int(max_iterations), bool(warm_start), mu0, stationarity_tolerance)
        self.warm_start = bool(warm_start)
        self._workspaces: dict[tuple[int, int], _Workspace] = {}
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        self._previous = None

    def workspace(self, qp) -> _Workspace:
        key = (qp.config.horizon, qp.n_observed)
        if key not in self._workspaces:
            self._workspaces[key] = _Workspace(self._lib, StagewiseQp(*key), *self.settings)
        return self._workspaces[key]

    def solve(self, qp) -> HpipmNativeSolution:
        workspace = self.workspace(qp)
        stages = workspace.stages
        stages.update(qp)
        start = time.perf_counter()
        workspace.write()
        if self.warm_start and self._previous is not None:
            workspace.set_guess(*stages.stagewise_from_z(qp, self._previous[qp.variable_shift]))
        setup_s = time.perf_counter() - start
        lib = self._lib
        start = time.perf_counter()
        lib.d_ocp_qp_ipm_solve(workspace.qp, workspace.sol, workspace.arg, workspace.ws)
        solve_s = time.perf_counter() - start
        status, iterations = ctypes.c_int(-1), ctypes.c_int(-1)
        lib.d_ocp_qp_ipm_get_status(workspace.ws, ctypes.byref(status))
        lib.d_ocp_qp_ipm_get_iter(workspace.ws, ctypes.byref(iterations))
        start = time.perf_counter()
        z = None
        if status.value == 0:
            z = stages.z_from_stagewise(qp, *workspace.read())
            if not np.all(np.isfinite(z)):
                z = None
        setup_s += time.perf_counter() - start
        self._previous = z
        return HpipmNativeSolution(z, int(status.value), int(iterations.value), solve_s, setup_s)
