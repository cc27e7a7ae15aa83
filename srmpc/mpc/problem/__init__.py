"""The LTV-MPC problem and its QP: what the planner solves at each step.

Pipeline: the OCP's sizes, weights and geometry (``ocp``), the ego's discrete kinematic bicycle and its exact
Jacobians (``vehicle_model``) and the other vehicles' predicted poses (``prediction``) -> one step's data as one
value (``step_data.OcpStepData``: x_hat, x^r, u^r, x^ref, u_hat, the predicted others) -> the linearized collision
rows (``collision_constraints``) -> the QP's values in a fixed sparsity pattern, overwritten each step by
``qp_builder.LtvMpcQp.update(step)`` (sparse forms for library solvers, stage-wise arrays for ours).
``nonlinear_cost`` evaluates a plan on the exact (not linearized) problem. Nothing here imports the other rooms.
"""

from srmpc.mpc.problem.collision_constraints import closest_circle, collision_norms, linearize_collision_constraints
from srmpc.mpc.problem.nonlinear_cost import nonlinear_plan_cost
from srmpc.mpc.problem.ocp import (
    LANE_CENTRES_M,
    MAX_EGO_CIRCLES,
    MAX_HORIZON_STEPS,
    MAX_VEHICLE_SLOTS,
    CollisionGeometry,
    OcpConfig,
    TrackingWeights,
    lane_keeping_tracking_reference,
)
from srmpc.mpc.problem.prediction import TrafficPredictor, constant_velocity_rollout, predict_constant_velocity
from srmpc.mpc.problem.qp_builder import LtvMpcQp
from srmpc.mpc.problem.step_data import OcpStepData
from srmpc.mpc.problem.vehicle_model import (
    INPUT_DIM,
    LATERAL_INDEX,
    SPEED_INDEX,
    STATE_DIM,
    BicycleParameters,
    KinematicBicycle,
    linearize_horizon,
    rollout_horizon,
)

__all__ = [
    "INPUT_DIM",
    "LANE_CENTRES_M",
    "LATERAL_INDEX",
    "MAX_EGO_CIRCLES",
    "MAX_HORIZON_STEPS",
    "MAX_VEHICLE_SLOTS",
    "SPEED_INDEX",
    "STATE_DIM",
    "BicycleParameters",
    "CollisionGeometry",
    "KinematicBicycle",
    "LtvMpcQp",
    "OcpConfig",
    "OcpStepData",
    "TrackingWeights",
    "TrafficPredictor",
    "closest_circle",
    "collision_norms",
    "constant_velocity_rollout",
    "lane_keeping_tracking_reference",
    "linearize_collision_constraints",
    "linearize_horizon",
    "nonlinear_plan_cost",
    "predict_constant_velocity",
    "rollout_horizon",
]
