"""The OCP's cost of a plan on the exact model: objective plus penalized constraint violation.

The QP is an approximation about one linearization reference, so the QP objectives of two plans
linearized about different references are not comparable. This evaluates a plan's inputs on the
nonlinear problem instead (SRMPC's ``best_of_two`` picks by it, as AC4MPC does for NMPC):

    x_0 = x_hat,  x_{k+1} = f(x_k, u_k)                    (exact 3-sub-step bicycle, no linearization)
    J   = sum_{k=1..N} ||x_k - x^ref_k||_Q^2 + sum_{k=0..N-1} ||u_k||_R^2
          + ||u_0 - u_hat||_S^2 + sum_{k=1..N-1} ||u_k - u_{k-1}||_S^2            (the QP's objective)
        + sum_j (w_col,1 s_j + w_col,2 s_j^2),      s_j = max_k max(0, 1 - g_kj)
        + sum_{k,j} (w_safe,1 sigma_kj + w_safe,2 sigma_kj^2),  sigma_kj = max(0, 1 - g'_kj)
        + sum_k (w_col,1 b_k + w_col,2 b_k^2),      b_k = violation of the y and v bounds [m, m/s]

g_kj is the exact ellipse norm of the ego's closest circle to vehicle j at stage k (< 1 inside the
collision ellipse), g'_kj the same for the larger safety region (``collision_constraints.collision_norms``).
The slacks are measured as ellipse-norm deficits, the QP's as linearized support distances: the
penalty weights are the QP's, the units differ, which is immaterial for ranking two plans.
"""

from __future__ import annotations

import numpy as np

from srmpc.mpc.problem.collision_constraints import collision_norms
from srmpc.mpc.problem.ocp import OcpConfig
from srmpc.mpc.problem.vehicle_model import KinematicBicycle


def _penalty(violation: np.ndarray, linear: float, quadratic: float) -> float:
    return float(np.sum(linear * violation + quadratic * violation**2))


def nonlinear_plan_cost(
    config: OcpConfig,
    model: KinematicBicycle,
    measured_state: np.ndarray,
    inputs: np.ndarray,
    tracking_reference: np.ndarray,
    last_input: np.ndarray,
    predicted_others: np.ndarray,
) -> float:
    """J of ``inputs`` (N, 2) applied from ``measured_state`` on the exact model (module doc).

    ``tracking_reference`` (N + 1, 4); ``last_input`` (2,); ``predicted_others`` (N + 1, V_obs, 4).
    """
    weights, geometry = config.weights, config.geometry
    states = model.rollout(measured_state, inputs)
    q, r, s = np.asarray(weights.state), np.asarray(weights.input), np.asarray(weights.input_rate)
    tracking_error = states[1:] - tracking_reference[1:]
    rates = np.diff(np.vstack([np.asarray(last_input, dtype=np.float64)[None, :], inputs]), axis=0)
    cost = float(np.sum(q * tracking_error**2) + np.sum(r * inputs**2) + np.sum(s * rates**2))

    lateral, speed = states[1:, 1], states[1:, 3]
    bound_violation = (np.maximum(config.lateral_bounds_m[0] - lateral, 0.0)
                       + np.maximum(lateral - config.lateral_bounds_m[1], 0.0)
                       + np.maximum(config.speed_bounds_mps[0] - speed, 0.0)
                       + np.maximum(speed - config.speed_bounds_mps[1], 0.0))
    cost += _penalty(bound_violation, weights.collision_slack_linear, weights.collision_slack_quadratic)

    predicted_others = np.asarray(predicted_others, dtype=np.float64)
    if predicted_others.shape[1] == 0:
        return cost
    offsets = geometry.circle_offsets_m
    collision = collision_norms(states[1:], predicted_others[1:], offsets, geometry.collision_semi_axes_m)
    safety = collision_norms(states[1:], predicted_others[1:], offsets, geometry.safety_semi_axes_m)
    collision_slack = np.maximum(1.0 - collision.min(axis=2), 0.0).max(axis=0)  # (V,)
    safety_slack = np.maximum(1.0 - safety.min(axis=2), 0.0)  # (N, V)
    cost += _penalty(collision_slack, weights.collision_slack_linear, weights.collision_slack_quadratic)
    cost += _penalty(safety_slack, weights.safety_slack_linear, weights.safety_slack_quadratic)
    return cost
