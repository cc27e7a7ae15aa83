"""LTV-MPC as a closed-loop controller: the planner linearized about its own shifted previous solution.

Every control step, in :meth:`LtvMpcController.step`:

1. measure the scene: x_k = the ego's [x, y, heading, speed] and the observed vehicles (the 6 observation
   slots, :meth:`LtvMpcController.act`);
2. plan (``srmpc.mpc.planner.LtvMpcPlanner``): linearize about the shifted previous solution (lane
   following at the first step), track x^ref (the right-lane centre at v_ref), penalize the rate against
   û = the input applied last, solve the QP; if it is not solved, the fallback chain (shifted previous
   plan, emergency brake);
3. apply the plan's first input (delta [rad], a [m/s^2]) and count the step's outcome.

SRMPC (``srmpc.controllers.srmpc``) stands on the same planner, with the policy's rollout as the
linearization reference.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from srmpc.controllers.outcomes import REFERENCE_OUTCOMES, episode_counts
from srmpc.mpc.planner import LtvMpcPlanner, Plan, StepOutcome
from srmpc.mpc.problem import OcpConfig, lane_keeping_tracking_reference


@dataclass(frozen=True)
class StepReport:
    """What one LTV-MPC step did.

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
    """LTV-MPC tracking x^ref (default: the right-lane centre at the reference speed), a scenario controller
    (``srmpc.controllers.Controller``).

    Args:
        planner: the LTV-MPC planner (OCP, solver, prediction); default ``LtvMpcPlanner(OcpConfig())``.
        tracking_reference: (N + 1, 4) x^ref; default lane keeping at the OCP's default y_ref and v_ref.
    """

    def __init__(self, planner: LtvMpcPlanner | None = None, tracking_reference: np.ndarray | None = None) -> None:
        self.planner = planner or LtvMpcPlanner(OcpConfig())
        self.config = self.planner.config
        if tracking_reference is None:
            tracking_reference = lane_keeping_tracking_reference(self.config.horizon,
                                                                 control_period_s=self.config.control_period_s)
        self.tracking_reference = np.asarray(tracking_reference, dtype=np.float64)
        if self.tracking_reference.shape != (self.config.horizon + 1, 4):
            raise ValueError(f"tracking_reference has shape {self.tracking_reference.shape}, "
                             f"the OCP needs {(self.config.horizon + 1, 4)}")
        self.last_report: StepReport | None = None
        self.reset()

    def reset(self) -> None:
        """Start a new episode: forget the plan, zero the last input, clear the counts."""
        self.planner.reset()
        self.last_input = np.zeros(2)
        self.outcome_counts: Counter[str] = Counter()

    def episode_outcomes(self) -> dict[str, int]:
        """Steps per outcome key (``srmpc.controllers.outcomes``): the fallback chain's links, and of the
        solved steps, how many per linearization reference."""
        return episode_counts(self.outcome_counts)

    def act(self, observation: np.ndarray, scene) -> np.ndarray:
        """The scenario controller's step: the ego and the observed vehicles (the 6 observation slots)."""
        observed = scene.slot_vehicle[scene.slot_vehicle >= 0]
        action, _ = self.step(scene.ego, scene.others[observed])
        return action

    def step(self, ego_state: np.ndarray, others: np.ndarray,
             last_input: np.ndarray | None = None) -> tuple[np.ndarray, StepReport]:
        """One control step on plain arrays.

        Args:
            ego_state: (4,) [x, y, heading, speed].
            others: (V_obs, 4) observed vehicles (may be empty).
            last_input: the input the plant applied last (û of the rate cost); default the one returned last.

        Returns:
            (action (2,) = (delta [rad], a [m/s^2]), StepReport).
        """
        if last_input is not None:
            self.last_input = np.asarray(last_input, dtype=np.float64).reshape(2)
        plan = self.planner.plan(ego_state, others, self.last_input, self.tracking_reference)
        action = plan.first_input.copy()
        self.last_input = action
        self.outcome_counts[plan.outcome.value] += 1
        if plan.outcome is StepOutcome.SOLVED:
            self.outcome_counts[REFERENCE_OUTCOMES[plan.reference_source]] += 1
        self.last_report = StepReport(
            outcome=plan.outcome,
            solver_status=plan.solver_status,
            iterations=plan.iterations,
            step_time_us=plan.step_time_s * 1e6,
            solve_time_us=plan.solve_time_s * 1e6,
            max_collision_slack=float(np.max(plan.collision_slacks, initial=0.0)),
            max_safety_slack=float(np.max(plan.safety_slacks, initial=0.0)),
            plan=plan,
        )
        return action, self.last_report
