"""LTV-MPC planner (paper Sec. "MPC for Automated Driving").

Pipeline: problem data (``ocp``, ``vehicle_model``, ``prediction``) -> QP values in a fixed
pattern (``qp_builder``, ``collision``) -> solve (``solvers``) -> ``Plan`` (``planner``) ->
closed-loop action (``controller``).
"""

from srmpc.mpc.controller import LtvMpcController, StepReport
from srmpc.mpc.ocp import CollisionGeometry, OcpConfig, TrackingWeights
from srmpc.mpc.planner import LtvMpcPlanner, Plan, StepOutcome
from srmpc.mpc.solvers import DEFAULT_SOLVER, available_solvers, make_solver

__all__ = [
    "DEFAULT_SOLVER",
    "CollisionGeometry",
    "LtvMpcController",
    "LtvMpcPlanner",
    "OcpConfig",
    "Plan",
    "StepOutcome",
    "StepReport",
    "TrackingWeights",
    "available_solvers",
    "make_solver",
]
