"""The LTV-MPC planner as a scenario controller: reads the ego and the observed vehicles' states."""

from __future__ import annotations

from collections import Counter

import numpy as np

from srmpc.controllers.outcomes import OUTCOME_KEYS, REFERENCE_OUTCOMES
from srmpc.mpc.controller import LtvMpcController
from srmpc.mpc.ocp import CollisionGeometry, OcpConfig, TrackingWeights
from srmpc.mpc.planner import StepOutcome
from srmpc.scenario import road
from srmpc.scenario.parameters import ScenarioParameters


def ocp_config(
    scenario: ScenarioParameters,
    horizon_steps: int,
    max_vehicles: int,
    weights: TrackingWeights,
    geometry: CollisionGeometry,
) -> OcpConfig:
    """The OCP for ``scenario``: its action box as input bounds, its road edges as lateral bounds."""
    return OcpConfig(
        horizon=horizon_steps,
        max_vehicles=max_vehicles,
        steering_bounds_rad=(-scenario.steering_max_rad, scenario.steering_max_rad),
        acceleration_bounds_m_s2=(scenario.acceleration_min_mps2, scenario.acceleration_max_mps2),
        lateral_bounds_m=(
            road.LEFT_ROAD_EDGE + road.VEHICLE_WIDTH / 2.0,
            road.RIGHT_ROAD_EDGE - road.VEHICLE_WIDTH / 2.0,
        ),
        weights=weights,
        geometry=geometry,
    )


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
