"""Safety index phi (paper eq. (si)) and the SI cost c of a transition, as numba kernels.

See :class:`srmpc.scenario.parameters.SafetyIndexParameters` for the definition of d and d_dot,
the treatment of road edges and the chosen values.
"""

import numpy as np
from numba import njit

from srmpc.scenario.observation import SLOT_COUNT, closest_lane
from srmpc.scenario.road import LEFT_ROAD_EDGE, RIGHT_ROAD_EDGE, VEHICLE_LENGTH, VEHICLE_WIDTH


@njit(cache=True)
def barrier(distance: float, distance_rate: float, safe_distance: float, n: float, k: float) -> float:
    """phi = safe_distance^n - distance^n - k * distance_rate, with safe_distance = sigma + d_min."""
    return safe_distance**n - distance**n - k * distance_rate


@njit(cache=True)
def vehicle_gap_and_rate(
    ego: np.ndarray, other: np.ndarray, same_lane: bool
) -> tuple[float, float]:
    """Bounding-box gap d [m] between ego and ``other`` ([x, y, heading, speed]) and its rate [m/s].

    The gap is the Euclidean norm of the longitudinal and lateral gaps between the axis-aligned
    boxes (LENGTH x WIDTH) of the two vehicles. When ``same_lane`` is False the longitudinal part
    of the rate is zeroed (paper, section "Safety Index for Highway Driving").
    """
    dx = other[0] - ego[0]
    dy = other[1] - ego[1]
    dvx = other[3] * np.cos(other[2]) - ego[3] * np.cos(ego[2])
    dvy = other[3] * np.sin(other[2]) - ego[3] * np.sin(ego[2])
    gap_x = max(abs(dx) - VEHICLE_LENGTH, 0.0)
    gap_y = max(abs(dy) - VEHICLE_WIDTH, 0.0)
    rate_x = np.sign(dx) * dvx if (gap_x > 0.0 and same_lane) else 0.0
    rate_y = np.sign(dy) * dvy if gap_y > 0.0 else 0.0
    gap = np.sqrt(gap_x * gap_x + gap_y * gap_y)
    if gap <= 0.0:
        return 0.0, 0.0
    return gap, (gap_x * rate_x + gap_y * rate_y) / gap


@njit(cache=True)
def safety_index(
    ego: np.ndarray,
    others: np.ndarray,
    slot_vehicle: np.ndarray,
    sigma: float,
    d_min: float,
    edge_d_min: float,
    n: float,
    k: float,
) -> float:
    """phi(s): the maximum of the barrier over the observed vehicles and both road edges."""
    ego_lane = closest_lane(ego[1])
    ego_vy = ego[3] * np.sin(ego[2])
    right_distance = max(RIGHT_ROAD_EDGE - ego[1], 0.0)
    left_distance = max(ego[1] - LEFT_ROAD_EDGE, 0.0)
    phi = max(
        barrier(right_distance, -ego_vy, sigma + edge_d_min, n, k),
        barrier(left_distance, ego_vy, sigma + edge_d_min, n, k),
    )
    for slot in range(SLOT_COUNT):
        j = slot_vehicle[slot]
        if j < 0:
            continue
        same_lane = closest_lane(others[j, 1]) == ego_lane
        gap, rate = vehicle_gap_and_rate(ego, others[j], same_lane)
        phi = max(phi, barrier(gap, rate, sigma + d_min, n, k))
    return phi


@njit(cache=True)
def safety_index_cost(phi_before: float, phi_after: float, eta: float, floor: float) -> float:
    """c = max(phi(s') - max(phi(s) - eta, 0), floor): positive when the safe-control condition fails."""
    return max(phi_after - max(phi_before - eta, 0.0), floor)
