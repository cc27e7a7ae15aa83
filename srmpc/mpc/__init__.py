"""LTV-MPC planner (paper Sec. "MPC for Automated Driving").

Pipeline: problem data (``ocp``, ``vehicle_model``, ``prediction``) -> QP values in a fixed
pattern (``qp_builder``, ``collision``) -> solve (``solvers``) -> ``Plan`` (``planner``).
The closed-loop controllers that stand on the planner (LTV-MPC, SRMPC) are in ``srmpc.controllers``.
``nmpc`` solves the same OCP on the exact model to convergence (SQP on the same QP builder and solver);
``casadi_reference`` writes it independently in CasADi for IPOPT (optional dependency ``casadi``).
``hpipm_stagewise`` writes the QP in HPIPM's stage-wise form, which HPIPM solves through CasADi's plugin
(``hpipm_reference``) or its own C API (``hpipm_native``), the peers of ``benchmarks/qp_solvers.py``.
"""

from srmpc.mpc.ocp import CollisionGeometry, OcpConfig, TrackingWeights
from srmpc.mpc.planner import LtvMpcPlanner, Plan, StepOutcome
from srmpc.mpc.solvers import DEFAULT_SOLVER, available_solvers, make_solver

__all__ = [
    "DEFAULT_SOLVER",
    "CollisionGeometry",
    "LtvMpcPlanner",
    "OcpConfig",
    "Plan",
    "StepOutcome",
    "TrackingWeights",
    "available_solvers",
    "make_solver",
]
