"""Sizes, weights and geometry of the LTV-MPC optimal control problem (paper eqs. OCP_tracking,
OCP_objective and collision-constraint).

Objective (x_k: state, u_k: input, u_hat: last applied input, s: slacks)::

    J = sum_{k=1..N} ||x_k - x_k^ref||_Q^2 + sum_{k=0..N-1} ||u_k||_R^2
        + ||u_0 - u_hat||_S^2 + sum_{k=1..N-1} ||u_k - u_{k-1}||_S^2
        + sum_j (w_col,1 s_j + w_col,2 s_j^2) + sum_{k, j} (w_safe,1 sigma_kj + w_safe,2 sigma_kj^2)

with x_0 the measured state (indices shifted by one against the paper, which starts at k = 1).

Collision geometry: the ego is covered by ``n_ego_circles`` circles of radius r placed evenly along
its axis; each other vehicle (length L, width W) is over-approximated by the smallest-area
ellipse through its corners, semi-axes (L/2, W/2) * sqrt(2), enlarged by r (paper: "a and b are
the sum of the semi-major respectively semi-minor axis and the radius of the circle").  The
safety region (Jain et al. 2019) is a larger ellipse for the circle centres, semi-axes
(a + margin_long, b + margin_lat), with a cheaper slack (see ``collision_constraints.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from srmpc.mpc.problem.vehicle_model import (
    CONTROL_PERIOD_S,
    MAX_SPEED_MPS,
    VEHICLE_LENGTH_M,
    VEHICLE_WIDTH_M,
    BicycleParameters,
)
from srmpc.scenario.road import LANE_CENTERS, LANE_WIDTH, LEFT_ROAD_EDGE, RIGHT_ROAD_EDGE

LANE_WIDTH_M = float(LANE_WIDTH)
"""Lane width [m] (``srmpc.scenario.road``)."""
LANE_CENTRES_M = tuple(float(centre) for centre in LANE_CENTERS)
"""Lateral positions of the three lane centres [m]; y grows to the driver's right."""
ROAD_LEFT_EDGE_M = float(LEFT_ROAD_EDGE)
"""Left road edge [m]."""
ROAD_RIGHT_EDGE_M = float(RIGHT_ROAD_EDGE)
"""Right road edge [m]."""
REFERENCE_LATERAL_POSITION_M = LANE_CENTRES_M[-1]
"""Right-lane centre, the tracking target [m]."""
REFERENCE_SPEED_MPS = 25.0
"""Reference speed v_ref [m/s]."""

MAX_HORIZON_STEPS = 400
"""Largest horizon N the planner accepts: 400 steps are 80 s at 5 Hz, the default episode's whole length,
16x the paper's 5 s. The QP's size and the Riccati solver's work and memory grow linearly in N (N = 400
ran a 30-step episode with SRMPC in 9 s and 0.5 GB); far beyond it, the prediction outlasts any episode
and a run spends minutes per step (N = 100,000 gave no step within 90 s)."""
MAX_VEHICLE_SLOTS = 40
"""Most other-vehicle slots V in the QP: the paper's scene has 40 vehicles besides the ego, and the
controllers pass at most the 6 observed ones, so further slots stay empty. Each slot adds
N x circles collision rows (V = 1,000,000 took 13 GB and no step within 110 s)."""
MAX_EGO_CIRCLES = 16
"""Most circles covering the ego: with 16 the circle radius sqrt((L/2n)^2 + (W/2)^2) is within 1.2% of
the half-width W/2 it tends to, so more circles no longer tighten the cover, and each adds rows."""


@dataclass(frozen=True)
class TrackingWeights:
    """Diagonal weights of the objective.

    Attributes:
        state: Q diagonal for (x [1/m^2], y [1/m^2], psi [1/rad^2], v [s^2/m^2]); x is not tracked.
        input: R diagonal for (delta [1/rad^2], a [s^4/m^2]).
        input_rate: S diagonal for consecutive input differences, same units as R.
        collision_slack_linear, collision_slack_quadratic: w_col,1 and w_col,2 on the
            per-vehicle collision slack s_j (dimensionless: ellipse-norm units).
        safety_slack_linear, safety_slack_quadratic: w_safe,1 and w_safe,2 on the per-stage,
            per-vehicle safety slack sigma_kj, cheaper than the collision ones so the safety
            region is entered only if necessary.
    """

    state: tuple[float, float, float, float] = (0.0, 0.5, 20.0, 0.5)
    input: tuple[float, float] = (50.0, 0.05)
    input_rate: tuple[float, float] = (500.0, 0.2)
    collision_slack_linear: float = 1.0e4
    collision_slack_quadratic: float = 1.0e5
    safety_slack_linear: float = 50.0
    safety_slack_quadratic: float = 500.0


@dataclass(frozen=True)
class CollisionGeometry:
    """Ego circle cover, other-vehicle ellipses and the safety region.

    Attributes:
        ego_length_m, ego_width_m: ego footprint [m].
        other_length_m, other_width_m: footprint of the other vehicles [m].
        n_ego_circles: number of circles covering the ego (>= 2).
        safety_margin_longitudinal_m: safety-region semi-major axis minus the collision one [m].
        safety_margin_lateral_m: safety-region semi-minor axis minus the collision one [m].
    """

    ego_length_m: float = VEHICLE_LENGTH_M
    ego_width_m: float = VEHICLE_WIDTH_M
    other_length_m: float = VEHICLE_LENGTH_M
    other_width_m: float = VEHICLE_WIDTH_M
    n_ego_circles: int = 2
    safety_margin_longitudinal_m: float = 8.0
    safety_margin_lateral_m: float = 0.3

    def __post_init__(self) -> None:
        if not 2 <= self.n_ego_circles <= MAX_EGO_CIRCLES:
            raise ValueError(f"the ego must be covered by 2 to {MAX_EGO_CIRCLES} circles, not {self.n_ego_circles}")

    @property
    def circle_offsets_m(self) -> np.ndarray:
        """Longitudinal offsets d_c [m] of the circle centres from the ego centre.

        n circles split the length into n equal segments, centres at the segment midpoints.
        """
        n = self.n_ego_circles
        segment = self.ego_length_m / n
        return (np.arange(n) + 0.5) * segment - self.ego_length_m / 2.0

    @property
    def circle_radius_m(self) -> float:
        """r = sqrt((L / 2n)^2 + (W / 2)^2) [m]: each circle covers its segment's rectangle."""
        return math.hypot(self.ego_length_m / (2 * self.n_ego_circles), self.ego_width_m / 2.0)

    @property
    def collision_semi_axes_m(self) -> tuple[float, float]:
        """(a, b) [m]: corner-touching ellipse of the other vehicle enlarged by the radius."""
        r = self.circle_radius_m
        return (self.other_length_m / 2.0 * math.sqrt(2.0) + r,
                self.other_width_m / 2.0 * math.sqrt(2.0) + r)

    @property
    def safety_semi_axes_m(self) -> tuple[float, float]:
        """(a', b') = (a + margin_long, b + margin_lat) [m] of the safety region."""
        a, b = self.collision_semi_axes_m
        return (a + self.safety_margin_longitudinal_m, b + self.safety_margin_lateral_m)


@dataclass(frozen=True)
class OcpConfig:
    """Everything that fixes the QP's size and values apart from the per-step data.

    Attributes:
        horizon: N, number of control intervals (N = 25 at 0.2 s gives 5 s).
        max_vehicles: V, number of other-vehicle slots (fewer observed: empty slots).
        steering_bounds_rad, acceleration_bounds_mps2: input boxes.
        lateral_bounds_m: bounds on the ego centre's y [m] (road edges minus half the width).
        speed_bounds_mps: bounds on v [m/s].
        weights: objective weights.
        geometry: collision geometry.
        bicycle: discrete model parameters (control period, sub-steps, length).
    """

    horizon: int = 25
    max_vehicles: int = 6
    steering_bounds_rad: tuple[float, float] = (-0.1, 0.1)
    acceleration_bounds_mps2: tuple[float, float] = (-5.0, 5.0)
    lateral_bounds_m: tuple[float, float] = (ROAD_LEFT_EDGE_M + VEHICLE_WIDTH_M / 2.0,
                                             ROAD_RIGHT_EDGE_M - VEHICLE_WIDTH_M / 2.0)
    speed_bounds_mps: tuple[float, float] = (0.0, MAX_SPEED_MPS)
    weights: TrackingWeights = field(default_factory=TrackingWeights)
    geometry: CollisionGeometry = field(default_factory=CollisionGeometry)
    bicycle: BicycleParameters = field(default_factory=BicycleParameters)

    @property
    def control_period_s(self) -> float:
        return self.bicycle.control_period_s


def lane_keeping_tracking_reference(
    horizon: int,
    lateral_position_m: float = REFERENCE_LATERAL_POSITION_M,
    speed_mps: float = REFERENCE_SPEED_MPS,
    ego_longitudinal_position_m: float = 0.0,
    control_period_s: float = CONTROL_PERIOD_S,
) -> np.ndarray:
    """x^ref_k, k = 0..N (shape (N + 1, 4)): (x0 + v_ref k dt, y_ref, 0, v_ref).

    x is not weighted by the default Q; it is filled for plotting only.
    """
    k = np.arange(horizon + 1)
    reference = np.empty((horizon + 1, 4))
    reference[:, 0] = ego_longitudinal_position_m + speed_mps * control_period_s * k
    reference[:, 1] = lateral_position_m
    reference[:, 2] = 0.0
    reference[:, 3] = speed_mps
    return reference


__all__ = [
    "CONTROL_PERIOD_S",
    "LANE_CENTRES_M",
    "LANE_WIDTH_M",
    "CollisionGeometry",
    "OcpConfig",
    "TrackingWeights",
    "lane_keeping_tracking_reference",
]
