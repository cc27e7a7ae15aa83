"""NMPC in closed loop: the exact OCP solved to convergence (``srmpc.mpc.nmpc``) from a chosen initial guess.

Per step, from the measured ego state and the observed vehicles' constant-velocity predictions:

1. the initial guess (``NmpcInitialGuess``):
   - ``constant_velocity``: constant velocity in the closest lane from the measured state at every step
     (``LtvMpcPlanner.lane_following_reference``, the paper's LTV-MPC start), no memory of the last plan;
   - ``shifted``: the last applied NMPC plan's inputs advanced by the steps since, rolled out on the
     exact model from the measured state; constant velocity in the closest lane when there is none
     (LTV-MPC's reference rule, ``LtvMpcPlanner.default_reference``);
   - ``rollout``: the policy's rollout in a copy of the scene (SRMPC's reference); ``shifted``
     when the rollout raised or is non-finite;
   - ``best_of_two``: solve from both, apply the converged plan with the lower objective (AC4MPC's rule);
2. the NMPC solve; a plan counts as solved only if the SQP converged (``NmpcResult.converged``);
3. otherwise the LTV-MPC's fallback chain: the last applied plan shifted while it lasts, else the
   emergency brake (``LtvMpcPlanner.fallback``).

Outcome keys as the LTV-MPC's (``outcomes``): ``solved_from_policy`` / ``solved_from_shifted`` /
``solved_from_lane_following`` by the guess of the applied plan.
"""

from __future__ import annotations

import enum
import time
from collections import Counter
from collections.abc import Callable

import numpy as np

from srmpc.controllers.outcomes import POLICY_FAILED, REFERENCE_OUTCOMES, episode_counts
from srmpc.controllers.srmpc import SceneSource
from srmpc.mpc.nmpc import NmpcResult, NmpcSolver
from srmpc.mpc.planner import LtvMpcPlanner, Plan, ReferenceSource, StepOutcome
from srmpc.mpc.problem import OcpStepData
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import rollout


class NmpcInitialGuess(enum.Enum):
    """Where the SQP starts (module doc)."""

    constant_velocity = "constant_velocity"
    shifted = "shifted"
    rollout = "rollout"
    best_of_two = "best_of_two"


POLICY_GUESSES = (NmpcInitialGuess.rollout, NmpcInitialGuess.best_of_two)
"""The guesses that roll out the policy."""


class NmpcController:
    """The NMPC as a scenario controller (``srmpc.controllers.Controller``).

    Args:
        solver: the NMPC for the planner's OCP.
        planner: the LTV-MPC planner of the same OCP, for its prediction, references and fallback chain.
        tracking_reference: x^ref (N + 1, 4).
        initial_guess: see ``NmpcInitialGuess``.
        policy, scene_source: the policy rolled out and the current scene (``rollout``, ``best_of_two``).
    """

    def __init__(self, solver: NmpcSolver, planner: LtvMpcPlanner, tracking_reference: np.ndarray,
                 initial_guess: NmpcInitialGuess = NmpcInitialGuess.shifted,
                 policy: MlpPolicy | Callable[[np.ndarray], np.ndarray] | None = None,
                 scene_source: SceneSource | None = None) -> None:
        if initial_guess in POLICY_GUESSES and (policy is None or scene_source is None):
            raise ValueError(f"initial_guess={initial_guess.value} needs a policy and a scene source")
        self.solver, self.planner = solver, planner
        self.tracking_reference = np.asarray(tracking_reference, dtype=np.float64)
        self.initial_guess, self.policy, self.scene_source = initial_guess, policy, scene_source
        self.horizon = planner.config.horizon
        self.last_result: NmpcResult | None = None
        self.reset()

    def reset(self) -> None:
        self.planner.reset()
        self.last_input = np.zeros(2)
        self.outcomes: Counter[str] = Counter()

    def episode_outcomes(self) -> dict[str, int]:
        return episode_counts(self.outcomes)

    def _rollout_guess(self) -> tuple[np.ndarray, np.ndarray] | None:
        try:
            state, constants = self.scene_source()
            result = rollout(state, constants, self.policy, self.horizon)
        except Exception:  # noqa: BLE001 - as SRMPC: any error in the rollout falls back
            return None
        if not (np.isfinite(result.ego).all() and np.isfinite(result.actions).all()):
            return None
        return result.ego[0], result.actions[0]

    def act(self, observation: np.ndarray, scene) -> np.ndarray:
        """One step (module doc); returns u = (delta [rad], a [m/s^2])."""
        start = time.perf_counter()
        ego = np.asarray(scene.ego, dtype=np.float64)
        predicted = self.planner.predict(scene.others[scene.slot_vehicle[scene.slot_vehicle >= 0]])
        guesses: list[tuple[np.ndarray, np.ndarray, ReferenceSource]] = []
        if self.initial_guess in POLICY_GUESSES:
            guess = self._rollout_guess()
            if guess is None:
                self.outcomes[POLICY_FAILED] += 1
            else:
                guesses.append((*guess, ReferenceSource.GIVEN))
        if self.initial_guess is NmpcInitialGuess.constant_velocity:
            guesses.append((*self.planner.lane_following_reference(ego), ReferenceSource.LANE_FOLLOWING))
        elif not guesses or self.initial_guess is NmpcInitialGuess.best_of_two:
            guesses.append(self.planner.default_reference(ego))
        candidates = []
        for states, inputs, source in guesses:
            result = self.solver.solve(OcpStepData(ego, states, inputs, self.tracking_reference, self.last_input,
                                                   predicted))
            if result.converged:
                candidates.append((result, source))
        if candidates:
            result, source = min(candidates, key=lambda candidate: candidate[0].objective)
            self.last_result = result
            plan = Plan(result.states, result.inputs, StepOutcome.SOLVED, source, result.status, result.iterations,
                        result.collision_slacks, result.safety_slacks, result.solve_time_s,
                        time.perf_counter() - start)
            self.planner.accept(plan)
            self.outcomes[REFERENCE_OUTCOMES[source]] += 1
        else:
            plan = self.planner.fallback(ego, guesses[-1][2], "nmpc not converged")
        self.outcomes[plan.outcome.value] += 1
        self.last_input = plan.first_input.copy()
        return self.last_input.copy()
