"""LTV-MPC planner (paper Sec. "MPC for Automated Driving") and the NMPC that solves its OCP exactly.

Three rooms and the planner, each importing only what is listed before it (``tests/test_layers.py`` checks it);
a room is entered through its ``__init__``, which exports what the others use:

- ``problem``: what is solved -- the OCP (``ocp``), the ego model (``vehicle_model``), the other vehicles'
  prediction, the linearized collision rows and the QP in a fixed sparsity pattern (``qp_builder.LtvMpcQp``);
- ``solvers``: how a QP is solved -- our Riccati interior point and the library solvers behind one interface
  (``make_solver``, ``SOLVER_FACTORIES``), HPIPM as a benchmark peer;
- the planner, at this package's root: ``planner`` (problem data as one ``OcpStepData`` per step -> QP values ->
  solve -> ``Plan``, with the fallback chain) and its default step as one compiled call (``compiled_step``);
- ``nmpc``: the same OCP on the exact model, solved by SQP to convergence (CasADi/IPOPT as its reference).

The closed-loop controllers that stand on the planner (LTV-MPC, SRMPC) and on the NMPC are in ``srmpc.controllers``.
"""

from srmpc.mpc.planner import LtvMpcPlanner, Plan, StepOutcome
from srmpc.mpc.problem import CollisionGeometry, OcpConfig, OcpStepData, TrackingWeights
from srmpc.mpc.solvers import DEFAULT_SOLVER, available_solvers, make_solver

__all__ = [
    "DEFAULT_SOLVER",
    "CollisionGeometry",
    "LtvMpcPlanner",
    "OcpConfig",
    "OcpStepData",
    "Plan",
    "StepOutcome",
    "TrackingWeights",
    "available_solvers",
    "make_solver",
]
