"""The NMPC: the LTV-MPC's OCP on the exact model, solved by SQP to convergence (a reference for the planner).

Pipeline: the NLP's exact collision and safety constraints (``nonlinear_constraints``) and its cost and
infeasibility as compiled kernels on a flat point (``sqp_kernels``) -> per SQP iteration a QP subproblem, the
problem's ``LtvMpcQp`` linearized at the iterate and solved by the solvers' interior point on its rows' slots
(``solvers.solve_compact``) -> a merit line search or an Anderson step -> the plan (``sqp.NmpcSolver``), with the
KKT residual of the last QP's multipliers (``kkt_residual``). ``casadi_reference`` poses the same NLP for
CasADi + IPOPT (optional ``casadi``: import it directly). This room imports ``problem``, ``solvers`` and the
compiled step's cycle counter.
"""

from srmpc.mpc.nmpc.kkt_residual import KktResidual
from srmpc.mpc.nmpc.sqp import STATUSES, NlpPoint, NmpcResult, NmpcSettings, NmpcSolver
from srmpc.mpc.nmpc.sqp_kernels import SAFETY_SLACK_UPPER

__all__ = ["SAFETY_SLACK_UPPER", "STATUSES", "KktResidual", "NlpPoint", "NmpcResult", "NmpcSettings", "NmpcSolver"]
