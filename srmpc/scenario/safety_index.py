"""Safety index phi (paper eq. (si)) and the SI cost c of a transition, as numba kernels.

See :class:`srmpc.scenario.parameters.SafetyIndexParameters` for the definition of d and d_dot,
the treatment of road edges and the chosen values.

Two indices share the paper's barrier phi_j = (sigma + d_safe)^n - d^n - k * d_dot per vehicle:

- ``paper`` (:func:`safety_index`): d_safe = d_min, a constant;
- ``rss`` (:func:`rss_safety_index`): d_safe is the Responsibility-Sensitive Safety distance
  (Shalev-Shwartz, Shammah, Shashua 2017, "On a Formal Model of Safe and Scalable Self-driving Cars",
  Definitions 1 and 5) of the pair: longitudinal (:func:`rss_longitudinal_distance`) for a vehicle
  ahead of or behind the ego in the ego's lane, lateral (:func:`rss_lateral_distance`) for a vehicle
  on another lane. Its parameters: :class:`srmpc.scenario.parameters.RssParameters`.

The road edges keep the paper's treatment in both (sigma + edge_d_min): RSS defines distances
between road users, and the edge term already makes leaving the road unsafe.
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
    return _gap_and_rate(dx, dy, dvx, dvy, same_lane)


@njit(cache=True, inline="always")
def _gap_and_rate(dx: float, dy: float, dvx: float, dvy: float, same_lane: bool) -> tuple[float, float]:
    """:func:`vehicle_gap_and_rate` from the relative position (dx, dy) [m] and velocity (dvx, dvy) [m/s]."""
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
    """phi(s): the maximum of the barrier over the observed vehicles and both road edges (the paper's index:
    :func:`scene_safety_index` with the safe distance sigma + d_min for every vehicle)."""
    return scene_safety_index(ego, others, slot_vehicle, False, sigma, d_min, edge_d_min, n, k, NO_RSS)


RSS_RESPONSE_TIME_EGO = 0
RSS_RESPONSE_TIME_OTHERS = 1
RSS_LON_ACCELERATION_MAX = 2
RSS_LON_BRAKE_MIN = 3
RSS_LON_BRAKE_MAX = 4
RSS_LAT_ACCELERATION_MAX = 5
RSS_LAT_BRAKE_MIN = 6
RSS_LAT_MARGIN = 7
RSS_PARAMETER_COUNT = 8
"""Positions in the RSS parameter array (the order of :class:`~srmpc.scenario.parameters.RssParameters`)."""
NO_RSS = (0.0,) * RSS_PARAMETER_COUNT
"""The RSS parameters passed where the paper's index is computed (unused there)."""


@njit(cache=True)
def rss_longitudinal_distance(
    rear_speed: float, front_speed: float, response_time: float, acceleration_max: float,
    brake_min: float, brake_max: float,
) -> float:
    """RSS's safe longitudinal distance [m] (Definition 1) between a rear and a front vehicle on one lane.

        d = [v_r rho + 1/2 a_acc rho^2 + (v_r + rho a_acc)^2 / (2 b_min) - v_f^2 / (2 b_max)]_+

    The rear vehicle (speed v_r [m/s]) accelerates at a_acc [m/s^2] for its response time rho [s],
    then brakes at no less than b_min; the front one (v_f) brakes at most at b_max. Speeds are the
    longitudinal components, clipped at 0 (RSS's vehicles do not reverse).
    """
    v_r = max(rear_speed, 0.0)
    v_f = max(front_speed, 0.0)
    v_after = v_r + response_time * acceleration_max
    distance = (v_r * response_time + 0.5 * acceleration_max * response_time * response_time
                + v_after * v_after / (2.0 * brake_min) - v_f * v_f / (2.0 * brake_max))
    return max(distance, 0.0)


@njit(cache=True)
def rss_lateral_distance(
    left_speed: float, right_speed: float, left_response_time: float, right_response_time: float,
    acceleration_max: float, brake_min: float, margin: float,
) -> float:
    """RSS's safe lateral distance [m] (Definition 5) between a left and a right vehicle.

        d = mu + [ (2 v_1 + rho_1 a) / 2 rho_1 + (v_1 + rho_1 a)^2 / (2 b)
                   - ((2 v_2 - rho_2 a) / 2 rho_2 - (v_2 - rho_2 a)^2 / (2 b)) ]_+

    v_1, v_2 [m/s]: lateral velocities of the left and the right vehicle, positive towards the right
    (+y, from vehicle 1 to vehicle 2); each accelerates towards the other at a [m/s^2] for its
    response time rho, then brakes laterally at b; mu [m] is the lateral fluctuation margin. The
    formula is RSS's as written (conservative when a vehicle still moves away after its response time).
    """
    v1_after = left_speed + left_response_time * acceleration_max
    v2_after = right_speed - right_response_time * acceleration_max
    left_move = (left_speed * left_response_time + 0.5 * acceleration_max * left_response_time * left_response_time
                 + v1_after * v1_after / (2.0 * brake_min))
    right_move = (right_speed * right_response_time
                  - 0.5 * acceleration_max * right_response_time * right_response_time
                  - v2_after * v2_after / (2.0 * brake_min))
    return margin + max(left_move - right_move, 0.0)


@njit(cache=True)
def rss_safe_distance(ego: np.ndarray, other: np.ndarray, same_lane: bool, rss: tuple) -> float:
    """RSS distance [m] of the pair (ego, ``other``), both [x, y, heading, speed]; ``rss``: 8 floats as
    :meth:`srmpc.scenario.parameters.RssParameters.as_tuple` orders them.

    Same lane: longitudinal, the vehicle behind being the rear one (the ego's or the others' response
    time accordingly). Other lane: lateral, the vehicle with the smaller y being the left one.
    """
    ego_vx, ego_vy = ego[3] * np.cos(ego[2]), ego[3] * np.sin(ego[2])
    other_vx, other_vy = other[3] * np.cos(other[2]), other[3] * np.sin(other[2])
    return _rss_safe_distance(ego[0], ego[1], ego_vx, ego_vy, other[0], other[1], other_vx, other_vy, same_lane, rss)


@njit(cache=True, inline="always")
def _rss_safe_distance(
    ego_x: float, ego_y: float, ego_vx: float, ego_vy: float,
    other_x: float, other_y: float, other_vx: float, other_vy: float, same_lane: bool, rss: tuple,
) -> float:
    """:func:`rss_safe_distance` from both positions [m] and velocities (v cos psi, v sin psi) [m/s]."""
    rho_ego, rho_others = rss[RSS_RESPONSE_TIME_EGO], rss[RSS_RESPONSE_TIME_OTHERS]
    if same_lane:
        a_acc, b_min, b_max = rss[RSS_LON_ACCELERATION_MAX], rss[RSS_LON_BRAKE_MIN], rss[RSS_LON_BRAKE_MAX]
        if other_x > ego_x:
            return rss_longitudinal_distance(ego_vx, other_vx, rho_ego, a_acc, b_min, b_max)
        return rss_longitudinal_distance(other_vx, ego_vx, rho_others, a_acc, b_min, b_max)
    a_lat, b_lat, mu = rss[RSS_LAT_ACCELERATION_MAX], rss[RSS_LAT_BRAKE_MIN], rss[RSS_LAT_MARGIN]
    if other_y > ego_y:
        return rss_lateral_distance(ego_vy, other_vy, rho_ego, rho_others, a_lat, b_lat, mu)
    return rss_lateral_distance(other_vy, ego_vy, rho_others, rho_ego, a_lat, b_lat, mu)


@njit(cache=True)
def rss_safety_index(
    ego: np.ndarray,
    others: np.ndarray,
    slot_vehicle: np.ndarray,
    sigma: float,
    edge_d_min: float,
    n: float,
    k: float,
    rss: tuple,
) -> float:
    """phi(s) with the RSS distance: the maximum of the barrier (sigma + d_RSS)^n - d^n - k d_dot over
    the observed vehicles, and of the paper's edge barriers (:func:`scene_safety_index` with ``use_rss``)."""
    return scene_safety_index(ego, others, slot_vehicle, True, sigma, 0.0, edge_d_min, n, k, rss)


@njit(cache=True)
def scene_safety_index(
    ego: np.ndarray,
    others: np.ndarray,
    slot_vehicle: np.ndarray,
    use_rss: bool,
    sigma: float,
    d_min: float,
    edge_d_min: float,
    n: float,
    k: float,
    rss: tuple,
) -> float:
    """phi(s) of the selected index: the maximum of the barrier over both road edges (safe distance
    sigma + edge_d_min) and the observed vehicles (sigma + the pair's RSS distance if ``use_rss``, else
    sigma + d_min).

    The same operations as :func:`barrier`, :func:`vehicle_gap_and_rate` and :func:`rss_safe_distance` on the
    same values, each vehicle's velocity v (cos psi, sin psi) computed once and the edges' (sigma +
    edge_d_min)^n once (those functions recompute them per call), so the result is the same float."""
    ego_lane = closest_lane(ego[1])
    ego_vx = ego[3] * np.cos(ego[2])
    ego_vy = ego[3] * np.sin(ego[2])
    right_distance = max(RIGHT_ROAD_EDGE - ego[1], 0.0)
    left_distance = max(ego[1] - LEFT_ROAD_EDGE, 0.0)
    edge_safe_power = (sigma + edge_d_min) ** n
    phi = max(
        edge_safe_power - right_distance**n - k * -ego_vy,
        edge_safe_power - left_distance**n - k * ego_vy,
    )
    for slot in range(SLOT_COUNT):
        j = slot_vehicle[slot]
        if j < 0:
            continue
        same_lane = closest_lane(others[j, 1]) == ego_lane
        other_vx = others[j, 3] * np.cos(others[j, 2])
        other_vy = others[j, 3] * np.sin(others[j, 2])
        gap, rate = _gap_and_rate(others[j, 0] - ego[0], others[j, 1] - ego[1], other_vx - ego_vx, other_vy - ego_vy,
                                  same_lane)
        if use_rss:
            safe_distance = _rss_safe_distance(ego[0], ego[1], ego_vx, ego_vy, others[j, 0], others[j, 1], other_vx,
                                               other_vy, same_lane, rss)
        else:
            safe_distance = d_min
        phi = max(phi, barrier(gap, rate, sigma + safe_distance, n, k))
    return phi


@njit(cache=True)
def safety_index_cost(phi_before: float, phi_after: float, eta: float, floor: float) -> float:
    """c = max(phi(s') - max(phi(s) - eta, 0), floor): positive when the safe-control condition fails."""
    return max(phi_after - max(phi_before - eta, 0.0), floor)
