"""The QP solvers: a ``problem.LtvMpcQp`` in, a ``QpSolution`` out.

Pipeline of our solver (``riccati_ipm``): the QP's stage-wise arrays as a tuple and a workspace allocated once
(``ipm_workspace``) -> a start, cold or warm from the shifted previous solution (``ipm_start``) -> Mehrotra
predictor-corrector iterations (``ipm_iteration``), each Newton step by a Riccati recursion and a Schur
complement on the collision slacks (``ipm_newton``, ``ipm_riccati``) -> the solution (``interior_point``: the
solves; ``ipm_compact``: the same solve on a QP's leading vehicle slots). ``adapters`` puts it and the library
solvers (qpsolvers' backends, native OSQP and PIQP) behind one interface, by name (``SOLVER_FACTORIES``,
``make_solver``). HPIPM, the peer of ``benchmarks/qp_solvers.py``, takes the QP in its stage-wise form
(``hpipm_stagewise``) through its C API (``hpipm_native``) or CasADi's plugin (``hpipm_reference``, optional
``casadi``): import those modules directly. This room imports only ``problem``.
"""

from srmpc.mpc.solvers.adapters import (
    DEFAULT_SOLVER,
    INTERIOR_POINT_TOLERANCE,
    NATIVE_PIQP_TOLERANCE,
    OSQP_TOLERANCE,
    RICCATI_IPM_MAX_ITERATIONS,
    RICCATI_IPM_TOLERANCE,
    SOLVER_FACTORIES,
    QpSolution,
    QpSolver,
    RiccatiInteriorPointSolver,
    SolverConstants,
    available_solvers,
    make_solver,
)
from srmpc.mpc.solvers.interior_point import solve_cold_in, solve_in, solve_ltv_mpc_qp
from srmpc.mpc.solvers.ipm_compact import CompactQp, allocate_compact, compact_multipliers, solve_compact
from srmpc.mpc.solvers.ipm_iteration import STATUS_NAMES, STATUS_SOLVED
from srmpc.mpc.solvers.ipm_start import WARM_START_SETTINGS, WarmStartMemory, allocate_memory, reorder_memory_slots
from srmpc.mpc.solvers.ipm_workspace import Primal, allocate_workspace, qp_tuple

__all__ = [
    "DEFAULT_SOLVER",
    "INTERIOR_POINT_TOLERANCE",
    "NATIVE_PIQP_TOLERANCE",
    "OSQP_TOLERANCE",
    "RICCATI_IPM_MAX_ITERATIONS",
    "RICCATI_IPM_TOLERANCE",
    "SOLVER_FACTORIES",
    "STATUS_NAMES",
    "STATUS_SOLVED",
    "WARM_START_SETTINGS",
    "CompactQp",
    "Primal",
    "QpSolution",
    "QpSolver",
    "RiccatiInteriorPointSolver",
    "SolverConstants",
    "WarmStartMemory",
    "allocate_compact",
    "allocate_memory",
    "allocate_workspace",
    "available_solvers",
    "compact_multipliers",
    "make_solver",
    "qp_tuple",
    "reorder_memory_slots",
    "solve_cold_in",
    "solve_compact",
    "solve_in",
    "solve_ltv_mpc_qp",
]
