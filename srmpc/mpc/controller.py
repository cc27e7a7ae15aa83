"""Closed-loop LTV-MPC controller: plain arrays in, physical action (delta, a) out.

Usable by evaluation and by an environment adapter: ``reset()`` at episode start, then
``act(ego_state, others)`` each control period.  The controller remembers the input it applied
last (u_hat of the rate cost) unless the caller passes the one the plant actually applied.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from srmpc.mpc.ocp import (
    REFERENCE_LATERAL_POSITION_M,
    REFERENCE_SPEED_M_S,
    OcpConfig,
    lane_keeping_tracking_reference,
)
from srmpc.mpc.planner import LtvMpcPlanner, Plan, StepOutcome
from srmpc.mpc.prediction import TrafficPredictor, predict_constant_velocity
from srmpc.mpc.solvers import DEFAULT_SOLVER, QpSolver


@dataclass(frozen=True)
class StepReport:
    """What one controller step did.

    Attributes:
        outcome: SOLVED / SHIFTED_PREVIOUS / EMERGENCY_BRAKE.
        solver_status: solver status text.
        iterations: solver iterations (None if not reported).
        step_time_us: whole step (prediction, linearization, QP update, solve) [us].
        solve_time_us: QP solve only [us].
        max_collision_slack, max_safety_slack: largest slack values (ellipse-norm units).
        plan: the full plan (states, inputs).
    """

    outcome: StepOutcome
    solver_status: str
    iterations: int | None
    step_time_us: float
    solve_time_us: float
    max_collision_slack: float
    max_safety_slack: float
    plan: Plan


class LtvMpcController:
    """LTV-MPC tracking the right-lane centre at the reference speed.

    Args:
        config: OCP configuration (horizon, weights, bounds, geometry).
        solver: solver name or object (default: the native fast path).
        predictor: other-vehicle prediction (constant velocity; an IDM rollout can be passed).
        reference_lateral_position_m: y_ref [m] (right-lane centre 8 m).
        reference_speed_m_s: v_ref [m/s].
        solver_settings: keyword settings for a solver given by name.
    """

    def __init__(
        self,
        config: OcpConfig | None = None,
        solver: str | QpSolver = DEFAULT_SOLVER,
        predictor: TrafficPredictor = predict_constant_velocity,
        reference_lateral_position_m: float = REFERENCE_LATERAL_POSITION_M,
        reference_speed_m_s: float = REFERENCE_SPEED_M_S,
        solver_settings: dict | None = None,
    ) -> None:
        self.config = config or OcpConfig()
        self.planner = LtvMpcPlanner(self.config, solver, predictor,
                                     solver_settings=solver_settings)
        self.reference_lateral_position_m = reference_lateral_position_m
        self.reference_speed_m_s = reference_speed_m_s
        self._tracking_reference = lane_keeping_tracking_reference(
            self.config.horizon, reference_lateral_position_m, reference_speed_m_s,
            control_period_s=self.config.control_period_s)
        self.reset()

    def reset(self) -> None:
        """Start a new episode: forget the plan, zero the last input, clear the counts."""
        self.planner.reset()
        self.last_input = np.zeros(2)
        self.outcome_counts: Counter[str] = Counter()

    def act(
        self,
        ego_state: np.ndarray,
        others: np.ndarray,
        last_input: np.ndarray | None = None,
        tracking_reference: np.ndarray | None = None,
        linearization_reference: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, StepReport]:
        """One control step.

        Args:
            ego_state: (4,) [x, y, heading, speed].
            others: (V_obs, 4) observed vehicles (may be empty).
            last_input: the input the plant applied last; default the one returned last.
            tracking_reference: (N + 1, 4) x^ref; default lane keeping at y_ref, v_ref.
            linearization_reference: optional (states, inputs) to linearize about (SRMPC).

        Returns:
            (action (2,) = (delta [rad], a [m/s^2]), StepReport).
        """
        if last_input is not None:
            self.last_input = np.asarray(last_input, dtype=np.float64).reshape(2)
        if tracking_reference is None:
            tracking_reference = self._tracking_reference
        plan = self.planner.plan(ego_state, others, self.last_input, tracking_reference,
                                 linearization_reference)
        action = plan.first_input.copy()
        self.last_input = action
        self.outcome_counts[plan.outcome.value] += 1
        report = StepReport(
            outcome=plan.outcome,
            solver_status=plan.solver_status,
            iterations=plan.iterations,
            step_time_us=plan.step_time_s * 1e6,
            solve_time_us=plan.solve_time_s * 1e6,
            max_collision_slack=float(np.max(plan.collision_slacks, initial=0.0)),
            max_safety_slack=float(np.max(plan.safety_slacks, initial=0.0)),
            plan=plan,
        )
        return action, report
