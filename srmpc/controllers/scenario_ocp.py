"""The scenario's OCP: the settings both planner-based controllers (LTV-MPC and SRMPC) solve.

The scenario fixes what the planner may do: its action box becomes the QP's input bounds, the road
edges, shrunk by half a vehicle width, its lateral position bounds [m], and its control period (the policy
frequency) and integration sub-steps the prediction model's time step (one input held for
``scenario.control_period_s``, integrated in ``scenario.substeps`` Euler steps, as the plant does). The
planner's own settings (horizon, observed vehicles, weights, collision geometry) come from ``conf/planner``.
"""

from __future__ import annotations

from srmpc.mpc.problem import BicycleParameters, CollisionGeometry, OcpConfig, TrackingWeights
from srmpc.scenario import road
from srmpc.scenario.parameters import ScenarioParameters


def ocp_config(
    scenario: ScenarioParameters,
    horizon_steps: int,
    max_vehicles: int,
    weights: TrackingWeights,
    geometry: CollisionGeometry,
) -> OcpConfig:
    """The OCP for ``scenario``: its action box as input bounds, its road edges as lateral bounds, its
    control period and sub-steps as the model's time step."""
    return OcpConfig(
        horizon=horizon_steps,
        max_vehicles=max_vehicles,
        steering_bounds_rad=(-scenario.steering_max_rad, scenario.steering_max_rad),
        acceleration_bounds_mps2=(scenario.acceleration_min_mps2, scenario.acceleration_max_mps2),
        lateral_bounds_m=(
            road.LEFT_ROAD_EDGE + road.VEHICLE_WIDTH / 2.0,
            road.RIGHT_ROAD_EDGE - road.VEHICLE_WIDTH / 2.0,
        ),
        weights=weights,
        geometry=geometry,
        bicycle=BicycleParameters(control_period_s=scenario.control_period_s, n_substeps=scenario.substeps),
    )
