"""One LTV-MPC step: reference -> linearization -> QP values -> solve -> Plan, with fallbacks.

Linearization reference z^r = (x^r_{0..N}, u^r_{0..N-1}), first match wins:

1. given by the caller (SRMPC passes its policy's rollout);
2. the previous plan shifted by one step: u^r = (u_1, ..., u_{N-1}, u_{N-1}), x^r the rollout of
   u^r from the measured state (dynamically consistent with the exact model);
3. at the first step: constant-velocity lane following, x^r_k = (x + v k dt, y_lane, 0, v) with
   y_lane the closest lane centre, u^r = 0.

x^r_0 is always replaced by the measured state.

Fallback chain when the QP is not solved (never an exception out of the step):
``SOLVED`` -> ``SHIFTED_PREVIOUS`` (the last solved plan, shifted by the steps since it was
solved, while it lasts) -> ``EMERGENCY_BRAKE`` (full braking, steering holding the closest lane).
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field

import numpy as np

from srmpc.mpc.compiled_step import STEP_REJECTED, STEP_SOLVED, CompiledPlannerStep, status_name
from srmpc.mpc.problem import (
    INPUT_DIM,
    LANE_CENTRES_M,
    STATE_DIM,
    LtvMpcQp,
    OcpConfig,
    OcpStepData,
    TrafficPredictor,
    lane_keeping_tracking_reference,
    predict_constant_velocity,
)
from srmpc.mpc.solvers import DEFAULT_SOLVER, QpSolution, QpSolver, RiccatiInteriorPointSolver, make_solver

LANE_HOLD_LATERAL_GAIN_1_S = 0.6
"""Emergency lane hold: heading command per lateral error and speed, psi_cmd = -k e / v [1/s]."""
LANE_HOLD_MAX_HEADING_RAD = 0.3
"""Emergency lane hold: the heading command's bound, |psi_cmd| <= this [rad]."""
LANE_HOLD_HEADING_GAIN = 1.0
"""Emergency lane hold: steering per heading error [rad/rad]."""
INPUT_BOUND_TOLERANCE = 1e-4
"""How far a solver's first input may exceed its box before the plan is rejected [rad, m/s^2]."""


class StepOutcome(enum.Enum):
    """Which source produced the applied input."""

    SOLVED = "solved"
    SHIFTED_PREVIOUS = "shifted_previous"
    EMERGENCY_BRAKE = "emergency_brake"


class ReferenceSource(enum.Enum):
    """Where the linearization reference came from."""

    GIVEN = "given"
    SHIFTED_PREVIOUS = "shifted_previous"
    LANE_FOLLOWING = "lane_following"


@dataclass
class Plan:
    """A planned trajectory and how it was obtained.

    Attributes:
        states: (N + 1, 4) x_0..x_N (x_0 the measured state).
        inputs: (N, 2) u_0..u_{N-1}; u_0 is applied.
        outcome: which link of the fallback chain produced it.
        reference_source: origin of the linearization reference.
        solver_status: solver status text ("" if not solved by the QP).
        iterations: solver iterations, where reported.
        collision_slacks, safety_slacks: (V,) slack values (zeros for fallbacks).
        solve_time_s: time in the QP solver [s]; step_time_s: whole step [s].
    """

    states: np.ndarray
    inputs: np.ndarray
    outcome: StepOutcome
    reference_source: ReferenceSource
    solver_status: str = ""
    iterations: int | None = None
    collision_slacks: np.ndarray = field(default_factory=lambda: np.zeros(0))
    safety_slacks: np.ndarray = field(default_factory=lambda: np.zeros(0))
    solve_time_s: float = 0.0
    step_time_s: float = 0.0

    @property
    def first_input(self) -> np.ndarray:
        return self.inputs[0]


def closest_lane_centre(lateral_position_m: float,
                        lane_centres_m: tuple[float, ...] = LANE_CENTRES_M) -> float:
    centres = np.asarray(lane_centres_m)
    return float(centres[np.argmin(np.abs(centres - lateral_position_m))])


class LtvMpcPlanner:
    """LTV-MPC (paper Sec. "MPC for Automated Driving") with a selectable QP solver.

    Args:
        config: OCP sizes, weights, bounds and geometry.
        solver: a solver name (see ``solvers.available_solvers``) or a solver object.
        predictor: prediction of the other vehicles (constant velocity by default).
        lane_centres_m: lane centre y positions [m] for the lane-following reference and the
            emergency lane hold.
        solver_settings: keyword settings for a solver given by name.

    Attributes (besides the arguments): ``qp`` (the ``LtvMpcQp``), ``model`` (its bicycle), ``input_lower`` and
    ``input_upper`` (the input box (delta, a) [rad, m/s^2]).
    """

    def __init__(
        self,
        config: OcpConfig | None = None,
        solver: str | QpSolver = DEFAULT_SOLVER,
        predictor: TrafficPredictor = predict_constant_velocity,
        lane_centres_m: tuple[float, ...] = LANE_CENTRES_M,
        solver_settings: dict | None = None,
    ) -> None:
        self.config = config or OcpConfig()
        self.qp = LtvMpcQp(self.config)
        self.model = self.qp.model
        self.solver = make_solver(solver, **(solver_settings or {})) if isinstance(
            solver, str) else solver
        self.predictor = predictor
        self.lane_centres_m = tuple(lane_centres_m)
        horizon = self.config.horizon
        self.input_lower = np.array([self.config.steering_bounds_rad[0],
                                     self.config.acceleration_bounds_mps2[0]])
        self.input_upper = np.array([self.config.steering_bounds_rad[1],
                                     self.config.acceleration_bounds_mps2[1]])
        self._default_tracking = lane_keeping_tracking_reference(horizon)
        self._no_inputs = np.zeros((horizon, INPUT_DIM))
        self._compiled: CompiledPlannerStep | None = None
        self.reset()

    def compiled_step(self) -> CompiledPlannerStep | None:
        """The one-call compiled step (``compiled_step``) if this planner's default path can take it
        (the ``riccati_ipm`` solver, constant-velocity prediction), else None (the Python path)."""
        if self._compiled is None and isinstance(self.solver, RiccatiInteriorPointSolver) \
                and self.predictor is predict_constant_velocity:
            self._compiled = CompiledPlannerStep(self, INPUT_BOUND_TOLERANCE)
        return self._compiled

    def reset(self) -> None:
        """Forget the previous plan and warm starts (new episode)."""
        self.last_solved_plan: Plan | None = None
        self.steps_since_solved = 0
        self.solver.reset()

    # ------------------------------------------------------------------ references
    def lane_following_reference(self, ego_state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Constant-velocity lane following from the measured state (module doc, item 3)."""
        horizon, dt = self.config.horizon, self.config.control_period_s
        states = np.empty((horizon + 1, STATE_DIM))
        speed = float(ego_state[3])
        states[:, 0] = ego_state[0] + speed * dt * np.arange(horizon + 1)
        states[:, 1] = closest_lane_centre(float(ego_state[1]), self.lane_centres_m)
        states[:, 2] = 0.0
        states[:, 3] = speed
        states[0] = ego_state
        return states, np.zeros((horizon, INPUT_DIM))

    def shifted_inputs(self, plan: Plan, shift: int) -> np.ndarray:
        """(u_shift, ..., u_{N-1}, u_{N-1}, ...): the plan's inputs advanced by ``shift``."""
        inputs = plan.inputs
        index = np.minimum(np.arange(inputs.shape[0]) + shift, inputs.shape[0] - 1)
        return inputs[index].copy()

    def emergency_brake(self, ego_state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full braking while steering back to the closest lane centre.

        Steering law per stage: delta = clip(-k_psi (psi - psi_cmd)), psi_cmd = clip(-k_y e / max(v, 1), +-psi_max)
        with e = y - y_lane; acceleration = the lower acceleration bound, but not below what
        stops exactly at v = 0 within one step.
        """
        horizon, dt = self.config.horizon, self.config.control_period_s
        lane = closest_lane_centre(float(ego_state[1]), self.lane_centres_m)
        states = np.empty((horizon + 1, STATE_DIM))
        inputs = np.empty((horizon, INPUT_DIM))
        states[0] = ego_state
        for k in range(horizon):
            px, py, psi, speed = states[k]
            heading_command = -LANE_HOLD_LATERAL_GAIN_1_S * (py - lane) / max(speed, 1.0)
            heading_command = float(np.clip(heading_command, -LANE_HOLD_MAX_HEADING_RAD, LANE_HOLD_MAX_HEADING_RAD))
            steering = -LANE_HOLD_HEADING_GAIN * (psi - heading_command)
            braking = max(self.input_lower[1], -max(speed, 0.0) / dt)
            inputs[k] = np.clip([steering, braking], self.input_lower, self.input_upper)
            states[k + 1] = self.model.step(states[k], inputs[k])
        return states, inputs

    def default_reference(self, ego_state: np.ndarray) -> tuple[np.ndarray, np.ndarray, ReferenceSource]:
        """The reference LTV-MPC linearizes about: the shifted previous plan, else lane following.

        Returns (x^r (N + 1, 4), u^r (N, 2), source); x^r_0 is the measured state.
        """
        if self.last_solved_plan is not None and self.steps_since_solved < self.config.horizon:
            ref_inputs = self.shifted_inputs(self.last_solved_plan, 1 + self.steps_since_solved)
            return self.model.rollout(ego_state, ref_inputs), ref_inputs, ReferenceSource.SHIFTED_PREVIOUS
        ref_states, ref_inputs = self.lane_following_reference(ego_state)
        return ref_states, ref_inputs, ReferenceSource.LANE_FOLLOWING

    def predict(self, others: np.ndarray) -> np.ndarray:
        """The other vehicles' poses over the horizon, (N + 1, V_obs, 4), by the planner's predictor."""
        others = np.asarray(others, dtype=np.float64).reshape(-1, STATE_DIM)
        return np.asarray(self.predictor(others, self.config.horizon, self.config.control_period_s))

    # ------------------------------------------------------------------ step
    def plan(
        self,
        ego_state: np.ndarray,
        others: np.ndarray,
        last_input: np.ndarray,
        tracking_reference: np.ndarray | None = None,
        linearization_reference: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Plan:
        """Plan from the measured ego state: reference -> QP -> solve, then the fallback chain.

        Args:
            ego_state: (4,) [x, y, heading, speed].
            others: (V_obs, 4) observed vehicles [x, y, heading, speed], V_obs <= max_vehicles.
            last_input: (2,) previously applied (delta, a).
            tracking_reference: (N + 1, 4) x^ref; default right-lane centre at 25 m/s.
            linearization_reference: (states (N + 1, 4), inputs (N, 2)) to linearize about;
                default: shifted previous plan / lane following.
        """
        start = time.perf_counter()
        ego_state = np.asarray(ego_state, dtype=np.float64).reshape(STATE_DIM)
        compiled = self.compiled_step() if linearization_reference is None else None
        if compiled is not None:
            plan = self._plan_compiled(compiled, ego_state, others, last_input, tracking_reference)
            plan.step_time_s = time.perf_counter() - start
            return plan
        if linearization_reference is not None:
            ref_states, ref_inputs = linearization_reference
            source = ReferenceSource.GIVEN
        else:
            ref_states, ref_inputs, source = self.default_reference(ego_state)
        predicted = self.predict(others)
        plan, status = self.solve_about(ego_state, predicted, last_input, ref_states, ref_inputs, source,
                                        tracking_reference)
        if plan is not None:
            self.accept(plan)
        else:
            plan = self.fallback(ego_state, source, status)
        plan.step_time_s = time.perf_counter() - start
        return plan

    def _plan_compiled(self, compiled: CompiledPlannerStep, ego_state, others, last_input,
                       tracking_reference) -> Plan:
        """:meth:`plan` about the default reference as one compiled call, then the fallback chain."""
        source, shift, previous = ReferenceSource.LANE_FOLLOWING, 0, self._no_inputs
        if self.last_solved_plan is not None and self.steps_since_solved < self.config.horizon:
            source, shift = ReferenceSource.SHIFTED_PREVIOUS, 1 + self.steps_since_solved
            previous = self.last_solved_plan.inputs
        others = np.ascontiguousarray(others, dtype=np.float64).reshape(-1, STATE_DIM)
        outcome, status, iterations, _ = compiled.ltv_mpc(
            ego_state, others, np.asarray(last_input, dtype=np.float64).reshape(INPUT_DIM),
            self._checked_tracking(tracking_reference), previous, shift)
        plan = self.compiled_plan(compiled, outcome, status, iterations, source)
        if plan is None:
            return self.fallback(ego_state, source, "solved" if outcome == STEP_REJECTED else status_name(status))
        self.accept(plan)
        return plan

    def compiled_plan(self, compiled: CompiledPlannerStep, outcome: int, status: int, iterations: int,
                      source: ReferenceSource) -> Plan | None:
        """The plan of an accepted compiled step (copies of its solution), else None."""
        if outcome != STEP_SOLVED:
            return None
        states, inputs, slacks, sigmas = compiled.plan_arrays()
        plan = Plan(states, inputs, StepOutcome.SOLVED, source, status_name(status), iterations, slacks, sigmas)
        plan.solve_time_s = float(compiled.stage_us()[2]) * 1e-6
        return plan

    def _checked_tracking(self, tracking_reference: np.ndarray | None) -> np.ndarray:
        """x^ref as a (N + 1, 4) float array (the default lane keeping if None)."""
        if tracking_reference is None:
            return self._default_tracking
        tracking_reference = np.asarray(tracking_reference, dtype=np.float64)
        if tracking_reference.shape != (self.config.horizon + 1, STATE_DIM):
            raise ValueError(f"tracking_reference must have shape {(self.config.horizon + 1, STATE_DIM)}")
        return tracking_reference

    def solve_about(
        self,
        ego_state: np.ndarray,
        predicted_others: np.ndarray,
        last_input: np.ndarray,
        ref_states: np.ndarray,
        ref_inputs: np.ndarray,
        source: ReferenceSource,
        tracking_reference: np.ndarray | None = None,
    ) -> tuple[Plan | None, str]:
        """Linearize about (x^r, u^r), update the QP, solve: the plan, or None and the solver status.

        The arguments become the step's ``OcpStepData`` (x^r_0 replaced by the measured state), shapes checked.
        Does not touch the fallback state (call :meth:`accept` with the plan that is applied).
        ``plan.solve_time_s`` is the solver's time, ``plan.step_time_s`` this call's.
        """
        start = time.perf_counter()
        ego_state = np.asarray(ego_state, dtype=np.float64).reshape(STATE_DIM)
        ref_states = np.array(ref_states, dtype=np.float64)
        if ref_states.shape != (self.config.horizon + 1, STATE_DIM):
            raise ValueError(f"the linearization states must have shape {(self.config.horizon + 1, STATE_DIM)}, "
                             f"not {ref_states.shape}")
        ref_states[0] = ego_state
        step = OcpStepData(ego_state, ref_states, ref_inputs, self._checked_tracking(tracking_reference),
                           np.asarray(last_input, dtype=np.float64).reshape(INPUT_DIM), predicted_others)
        solution = self._solve(step)
        plan = self._plan_from_solution(solution, source)
        if plan is not None:
            plan.solve_time_s = solution.solve_time_s
            plan.step_time_s = time.perf_counter() - start
        return plan, solution.status

    def accept(self, plan: Plan) -> None:
        """Make ``plan`` (a solved one) the previous solution that later steps shift."""
        self.last_solved_plan = plan
        self.steps_since_solved = 0

    def _solve(self, step: OcpStepData) -> QpSolution:
        """``qp.update(step)``, then the solve, warm-started at (x^r, u^r) if the solver accepts it."""
        self.qp.update(step)
        warm_start = (self.qp.pack(step.linearization_states, step.linearization_inputs)
                      if getattr(self.solver, "accepts_warm_start", True) else None)
        solve_start = time.perf_counter()
        solution = self.solver.solve(self.qp, warm_start)
        solution.solve_time_s = time.perf_counter() - solve_start
        return solution

    def _plan_from_solution(self, solution: QpSolution, source: ReferenceSource) -> Plan | None:
        if not solution.solved or solution.z is None:
            return None
        states, inputs, collision_slacks, safety_slacks = self.qp.split_solution(solution.z)
        steering, acceleration = float(inputs[0, 0]), float(inputs[0, 1])
        lower, upper = self.input_lower, self.input_upper
        if not (np.all(np.isfinite(solution.z))
                and lower[0] - INPUT_BOUND_TOLERANCE <= steering <= upper[0] + INPUT_BOUND_TOLERANCE
                and lower[1] - INPUT_BOUND_TOLERANCE <= acceleration
                <= upper[1] + INPUT_BOUND_TOLERANCE):
            return None
        np.clip(inputs, lower, upper, out=inputs)
        return Plan(states, inputs, StepOutcome.SOLVED, source, solution.status,
                    solution.iterations, collision_slacks, safety_slacks)

    def fallback(self, ego_state: np.ndarray, source: ReferenceSource, status: str) -> Plan:
        """No QP was solved this step: the shifted last solved plan while it lasts, else emergency brake."""
        ego_state = np.asarray(ego_state, dtype=np.float64).reshape(STATE_DIM)
        self.steps_since_solved += 1
        n_slots = self.config.max_vehicles
        if self.last_solved_plan is not None and self.steps_since_solved < self.config.horizon:
            inputs = self.shifted_inputs(self.last_solved_plan, self.steps_since_solved)
            states = self.model.rollout(ego_state, inputs)
            return Plan(states, inputs, StepOutcome.SHIFTED_PREVIOUS, source, status,
                        collision_slacks=np.zeros(n_slots), safety_slacks=np.zeros(n_slots))
        states, inputs = self.emergency_brake(ego_state)
        return Plan(states, inputs, StepOutcome.EMERGENCY_BRAKE, source, status,
                    collision_slacks=np.zeros(n_slots), safety_slacks=np.zeros(n_slots))
