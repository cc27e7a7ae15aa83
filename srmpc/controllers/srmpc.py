"""SRMPC (paper Algorithm 1): the LTV-MPC linearized about a safe RL policy's rollout.

Every control step k, top to bottom in :meth:`SrmpcController.act`:

1. measure the scene: x_k = the ego's [x, y, heading, speed], the observed vehicles;
2. roll the deterministic policy pi (the TanhNormal mode) forward N steps in a copy of the current
   scene, the other vehicles moving as the simulator moves them (IDM): the ego's states
   x^r_{0..N} and inputs u^r_{0..N-1} are the linearization reference, x^r_0 = x_k;
3. solve the LTV-MPC QP about (x^r, u^r) (tracking the right-lane centre at v_ref, or with
   ``tracking=policy_rollout`` the rollout x^r itself), optionally re-linearizing ``relinearizations`` times
   about the exact-model trajectory of the last QP solution (SQP-style, the paper's future work);
4. if the rollout raised, produced a non-finite value, or its QP was not solved: linearize about
   the shifted previous solution instead (LTV-MPC's own reference) and solve that QP;
   with ``selection=best_of_two`` both QPs are always solved and the plan with the lower
   nonlinear cost (``srmpc.mpc.problem.nonlinear_cost``) is applied;
5. if no QP was solved: the planner's fallback chain (shifted previous plan, emergency brake).

The information boundary: the rollout runs on the full simulator state of the current scene
(every vehicle, their IDM parameters), as in the paper ("use pi to simulate environment state
forward"), or with ``rollout=local`` on that scene cut to the vehicles that can reach the ego's
perception range within the horizon plus their leader chains (``srmpc.sim.local_rollout``, the bound
in its docstring; the cut is made inside the compiled step), while the QP sees only the 6 observed
vehicles, as LTV-MPC does. The other vehicles'
predicted motion in the QP is constant velocity (the paper's) or, with
``prediction=policy_rollout``, the observed vehicles' trajectories from the same rollout
(their IDM response to the policy's plan).

Outcomes counted per episode (``episode_outcomes``): the keys of ``srmpc.controllers.outcomes``,
the same as LTV-MPC's.
"""

from __future__ import annotations

import enum
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from srmpc.controllers.outcomes import POLICY_FAILED, REFERENCE_OUTCOMES, episode_counts
from srmpc.mpc.compiled_step import STEP_REJECTED, STEP_ROLLOUT_FAILED, CompiledPlannerStep, status_name
from srmpc.mpc.planner import LtvMpcPlanner, Plan, ReferenceSource
from srmpc.mpc.problem import nonlinear_plan_cost
from srmpc.sim.constants import SimConstants
from srmpc.sim.local_rollout import local_rollout
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import Rollout, rollout
from srmpc.sim.state import SceneState
from srmpc.value_checks import Interval, check_fields


class ReferenceSelection(enum.Enum):
    """Which linearization references are solved each step."""

    policy_first = "policy_first"
    """Algorithm 1: the policy's rollout; the shifted previous solution only if that fails."""
    best_of_two = "best_of_two"
    """Both, every step; apply the plan with the lower nonlinear cost (AC4MPC)."""


class OtherVehiclePrediction(enum.Enum):
    """How the QP predicts the observed vehicles."""

    constant_velocity = "constant_velocity"
    """Constant speed and heading (the paper's and LTV-MPC's)."""
    policy_rollout = "policy_rollout"
    """Their simulated IDM trajectories in the policy's rollout (constant velocity if it failed)."""


class TrackingTarget(enum.Enum):
    """What the QP's objective tracks (x^ref)."""

    lane_centre = "lane_centre"
    """The right-lane centre at v_ref (the paper's objective, LTV-MPC's)."""
    policy_rollout = "policy_rollout"
    """The policy's own rollout x^r: the MPC keeps the policy's lane and speed choices and adds its
    constraints (the right-lane reference if the rollout failed)."""


class RolloutScope(enum.Enum):
    """Which vehicles the policy's rollout simulates."""

    full = "full"
    """Every vehicle of the scene (the paper's)."""
    local = "local"
    """The vehicles that can come within the perception range of the ego within the horizon, and their
    leaders ``LEADER_DEPTH`` links deep (``srmpc.sim.local_rollout``, bound in its docstring); the dropped
    vehicles are predicted at constant speed where a prediction of them is read."""


MAX_RELINEARIZATIONS = 10
"""Upper bound on ``relinearizations`` (each costs one more QP solve per step)."""


@dataclass
class SrmpcSettings:
    """The SRMPC variant (paper: ``policy_first``, ``constant_velocity``, 0 re-linearizations)."""

    selection: ReferenceSelection = ReferenceSelection.policy_first
    """policy_first (Algorithm 1) or best_of_two."""
    prediction: OtherVehiclePrediction = OtherVehiclePrediction.constant_velocity
    """constant_velocity (the paper's) or policy_rollout (the rollout's IDM trajectories)."""
    relinearizations: int = 0
    """Extra QP solves about the exact-model trajectory of the last solution (0 = the paper)."""
    tracking: TrackingTarget = TrackingTarget.lane_centre
    """lane_centre (the paper's x^ref) or policy_rollout (x^ref = the policy's rollout)."""
    rollout: RolloutScope = RolloutScope.full
    """full (the paper's: every vehicle simulated) or local (the scene cut to the horizon)."""

    def __post_init__(self) -> None:
        check_fields(self, relinearizations=Interval(0, MAX_RELINEARIZATIONS))


SQP_RELINEARIZATIONS = 2
"""The re-linearizations of the variant named ``sqp``; another count is ``sqp_<count>``."""


def variant_of(settings: SrmpcSettings) -> str:
    """The variant name the settings make: ``paper`` when each is the paper's (Algorithm 1), else the name of each
    that differs, in field order, joined by ``+``: ``best_of_two`` (selection), ``rollout_prediction``
    (prediction), ``sqp`` (relinearizations), ``track_rollout`` (tracking), ``local_rollout`` (rollout). A
    display name: a run's identity is its experiment (srmpc.config.schema.Config.experiment)."""
    names = []
    if settings.selection is not ReferenceSelection.policy_first:
        names.append(settings.selection.value)
    if settings.prediction is not OtherVehiclePrediction.constant_velocity:
        names.append("rollout_prediction")
    if settings.relinearizations:
        k = settings.relinearizations
        names.append("sqp" if k == SQP_RELINEARIZATIONS else f"sqp_{k}")
    if settings.tracking is not TrackingTarget.lane_centre:
        names.append("track_rollout")
    if settings.rollout is not RolloutScope.full:
        names.append("local_rollout")
    return "+".join(names) or "paper"


@dataclass(frozen=True)
class SrmpcStepTiming:
    """Wall time of one SRMPC step [us], split as the latency benchmark reports it."""

    rollout_us: float
    """Scene copy (or cut, ``rollout=local``) and policy rollout."""
    qp_update_us: float
    """Prediction, linearization, QP value update, plan selection (everything but the solves)."""
    solve_us: float
    """QP solver calls."""
    step_us: float
    """The whole step."""


SceneSource = Callable[[], tuple[SceneState, SimConstants]]
"""Returns the current scene's full simulator state (B = 1) and constants; the rollout copies it."""


class SrmpcController:
    """SRMPC as a scenario controller (``srmpc.controllers.Controller``).

    Args:
        policy: the trained actor (deterministic: ``MlpPolicy`` with ``squash=True``), or any
            callable (1, 30) float32 observation -> (1, 2) physical action.
        planner: the LTV-MPC planner (the same OCP and solver as the ``ltv_mpc`` controller).
        scene_source: the current scene for the rollout (see :data:`SceneSource`).
        tracking_reference: (N + 1, 4) x^ref (right-lane centre at v_ref).
        settings: the variant.
    """

    def __init__(self, policy: MlpPolicy | Callable[[np.ndarray], np.ndarray], planner: LtvMpcPlanner,
                 scene_source: SceneSource, tracking_reference: np.ndarray,
                 settings: SrmpcSettings | None = None) -> None:
        self.policy = policy
        self.planner = planner
        self.scene_source = scene_source
        self.horizon = planner.config.horizon
        self.tracking_reference = np.asarray(tracking_reference, dtype=np.float64)
        if self.tracking_reference.shape != (self.horizon + 1, 4):
            raise ValueError(f"tracking_reference has shape {self.tracking_reference.shape}, "
                             f"the OCP needs {(self.horizon + 1, 4)}")
        self.settings = settings or SrmpcSettings()
        self.last_timing: SrmpcStepTiming | None = None
        self._solved_this_step: list[Plan] = []
        self.last_rollout: Rollout | None = None
        self.last_plan: Plan | None = None
        self.reset()

    def reset(self) -> None:
        """New episode: forget the previous solution, zero u_hat, clear the counts."""
        self.planner.reset()
        self.last_input = np.zeros(2)
        self.outcomes: Counter[str] = Counter()

    def episode_outcomes(self) -> dict[str, int]:
        return episode_counts(self.outcomes)

    def act(self, observation: np.ndarray, scene) -> np.ndarray:
        """One step of Algorithm 1 (module doc); returns u_k = (delta [rad], a [m/s^2])."""
        start = time.perf_counter()
        self._solved_this_step: list[Plan] = []
        # 1. measure
        ego = np.asarray(scene.ego, dtype=np.float64)
        observed = scene.slot_vehicle[scene.slot_vehicle >= 0]
        # 2.-3. the policy's rollout in a copy of the scene and the QP about it (one compiled call on
        # the default variant; the parts below otherwise)
        compiled, compiled_plan = self.compiled_step(), None
        if compiled is not None:
            policy_rollout, plan, status = self.compiled_rollout_and_qp(compiled, ego, scene)
            compiled_plan = plan
        else:
            policy_rollout, plan, status = self.policy_rollout(), None, "no policy reference"
        rollout_end = time.perf_counter()
        if policy_rollout is None:
            self.outcomes[POLICY_FAILED] += 1
        if policy_rollout is not None and self.settings.prediction is OtherVehiclePrediction.policy_rollout:
            predicted = policy_rollout.others[0][:, observed]
        elif plan is None or self.settings.selection is ReferenceSelection.best_of_two:
            predicted = self.planner.predict(scene.others[observed])
        tracking = self.tracking_reference
        if policy_rollout is not None and self.settings.tracking is TrackingTarget.policy_rollout:
            tracking = policy_rollout.ego[0]
        # 3. QP about the policy's reference (+ re-linearizations)
        candidates: list[Plan] = [plan] if plan is not None else []
        if policy_rollout is not None and compiled is None:
            plan, status = self.solve_about(ego, predicted, tracking, policy_rollout.ego[0],
                                            policy_rollout.actions[0], ReferenceSource.GIVEN)
            if plan is not None:
                candidates.append(plan)
        # 4. QP about the shifted previous solution, if needed (or always, best_of_two)
        source = ReferenceSource.GIVEN
        if not candidates or self.settings.selection is ReferenceSelection.best_of_two:
            ref_states, ref_inputs, source = self.planner.default_reference(ego)
            plan, status = self.solve_about(ego, predicted, tracking, ref_states, ref_inputs, source)
            if plan is not None:
                candidates.append(plan)
        # 5. apply the better plan, or the fallback chain
        if candidates:
            plan = min(candidates, key=lambda p: self.nonlinear_cost(ego, p, predicted, tracking)) \
                if len(candidates) > 1 else candidates[0]
            self.planner.accept(plan)
            self.outcomes[REFERENCE_OUTCOMES[plan.reference_source]] += 1
        else:
            plan = self.planner.fallback(ego, source, status)
        self.outcomes[plan.outcome.value] += 1
        self.last_input = plan.first_input.copy()
        self.last_rollout, self.last_plan = policy_rollout, plan
        end = time.perf_counter()
        solve_s = sum(p.solve_time_s for p in self._solved_this_step if p is not compiled_plan)
        rollout_s = rollout_end - start
        if compiled is not None:  # the compiled call's stages, by the cycle counter
            stage_us = compiled.stage_us()
            rollout_s, solve_s = stage_us[0] * 1e-6, solve_s + stage_us[2] * 1e-6
        self.last_timing = SrmpcStepTiming(
            rollout_us=rollout_s * 1e6, qp_update_us=(end - start - rollout_s - solve_s) * 1e6,
            solve_us=solve_s * 1e6, step_us=(end - start) * 1e6)
        return self.last_input.copy()

    # ------------------------------------------------------------------ the parts
    def compiled_step(self) -> CompiledPlannerStep | None:
        """The planner's compiled step if this variant is the default one (Algorithm 1 as the paper:
        policy_first, constant-velocity prediction, no re-linearization, lane-centre tracking; either rollout
        scope) and the policy a 2-hidden-layer ``MlpPolicy``; else None (the Python parts)."""
        settings = self.settings
        if not (isinstance(self.policy, MlpPolicy) and len(self.policy.weights) == 3
                and settings.selection is ReferenceSelection.policy_first
                and settings.prediction is OtherVehiclePrediction.constant_velocity
                and settings.relinearizations == 0 and settings.tracking is TrackingTarget.lane_centre):
            return None
        return self.planner.compiled_step()

    def compiled_rollout_and_qp(self, compiled: CompiledPlannerStep, ego: np.ndarray,
                                scene) -> tuple[Rollout | None, Plan | None, str]:
        """Steps 2-3 as one compiled call: (the rollout or None if it failed, the accepted plan or None,
        the solver status)."""
        try:
            state, constants = self.scene_source()
            outcome, status, iterations, _ = compiled.srmpc(
                state, constants, self.policy, ego, np.ascontiguousarray(scene.others, dtype=np.float64),
                np.ascontiguousarray(scene.slot_vehicle, dtype=np.int64), self.last_input, self.tracking_reference,
                local=self.settings.rollout is RolloutScope.local)
        except Exception:  # noqa: BLE001 - Algorithm 1: any error in the rollout falls back
            return None, None, "no policy reference"
        if outcome == STEP_ROLLOUT_FAILED:
            return None, None, "no policy reference"
        policy_rollout = Rollout(*(array.copy() for array in compiled.last_rollout()))
        plan = self.planner.compiled_plan(compiled, outcome, status, iterations, ReferenceSource.GIVEN)
        if plan is not None:
            self._solved_this_step.append(plan)
        return policy_rollout, plan, "solved" if outcome == STEP_REJECTED else status_name(status)

    def policy_rollout(self) -> Rollout | None:
        """The policy's N-step rollout from the current scene (``rollout=local``: its cut to the horizon, the
        dropped vehicles at constant speed in ``others``), or None if it raised or is non-finite."""
        record_others = self.settings.prediction is OtherVehiclePrediction.policy_rollout
        try:
            state, constants = self.scene_source()
            if self.settings.rollout is RolloutScope.local:
                result = local_rollout(state, constants, self.policy, self.horizon, record_others=record_others)
            else:
                result = rollout(state, constants, self.policy, self.horizon, record_others=record_others)
        except Exception:  # noqa: BLE001 - Algorithm 1: any error in the rollout falls back
            return None
        finite = np.isfinite(result.ego).all() and np.isfinite(result.actions).all()
        if record_others:
            finite = finite and np.isfinite(result.others).all()
        return result if finite else None

    def solve_about(self, ego: np.ndarray, predicted: np.ndarray, tracking: np.ndarray, ref_states: np.ndarray,
                    ref_inputs: np.ndarray, source: ReferenceSource) -> tuple[Plan | None, str]:
        """The QP about (x^r, u^r), then ``relinearizations`` QPs about the last solution's exact trajectory.

        Returns the last solved plan (None if the first QP failed) and the last solver status.
        """
        plan, status = self.planner.solve_about(ego, predicted, self.last_input, ref_states, ref_inputs, source,
                                                tracking)
        if plan is None:
            return None, status
        self._solved_this_step.append(plan)
        for _ in range(self.settings.relinearizations):
            exact_states = self.planner.model.rollout(ego, plan.inputs)
            better, status = self.planner.solve_about(ego, predicted, self.last_input, exact_states, plan.inputs,
                                                      source, tracking)
            if better is None:
                break
            self._solved_this_step.append(better)
            plan = better
        return plan, status

    def nonlinear_cost(self, ego: np.ndarray, plan: Plan, predicted: np.ndarray, tracking: np.ndarray) -> float:
        """The plan's objective plus constraint violation on the exact model (``nonlinear_cost``)."""
        return nonlinear_plan_cost(self.planner.config, self.planner.model, ego, plan.inputs, tracking,
                                   self.last_input, predicted)
