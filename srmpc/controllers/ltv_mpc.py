"""The LTV-MPC planner as a scenario controller: reads the ego and the observed vehicles' states."""

from __future__ import annotations

from collections import Counter

import numpy as np

from srmpc.controllers.outcomes import OUTCOME_KEYS, REFERENCE_OUTCOMES
from srmpc.mpc.controller import LtvMpcController
from srmpc.mpc.planner import StepOutcome


class LtvMpcSceneController:
    """``LtvMpcController`` fed with the scenario's observed vehicles (the 6 observation slots)."""

    def __init__(self, mpc: LtvMpcController) -> None:
        self.mpc = mpc
        self.last_report = None
        self.reset()

    def reset(self) -> None:
        self.mpc.reset()
        self.solved_by_reference: Counter[str] = Counter()

    def episode_outcomes(self) -> dict[str, int]:
        """Steps per outcome key (``srmpc.controllers.outcomes``): the MPC's chain counts, and of its
        solved steps, how many per linearization reference."""
        counts = self.mpc.outcome_counts + self.solved_by_reference
        return {key: int(counts.get(key, 0)) for key in OUTCOME_KEYS}

    def act(self, observation: np.ndarray, scene) -> np.ndarray:
        observed = scene.slot_vehicle[scene.slot_vehicle >= 0]
        action, report = self.mpc.act(scene.ego, scene.others[observed])
        if report.outcome is StepOutcome.SOLVED:
            self.solved_by_reference[REFERENCE_OUTCOMES[report.plan.reference_source]] += 1
        self.last_report = report
        return action
