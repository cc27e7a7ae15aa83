"""LTV-MPC planner (paper Sec. "MPC for Automated Driving").

Pipeline: problem data (``ocp``, ``vehicle_model``, ``prediction``) -> QP values in a fixed
pattern (``qp_builder``, ``collision``) -> solve (``solvers``) -> ``Plan`` (``planner``).
The closed-loop controllers that stand on the planner (LTV-MPC, SRMPC) are in ``srmpc.controllers``.
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
