"""highway-env's ``IDMVehicle`` with lane changes off: lane-following steering and IDM acceleration.

For vehicle k on lane L (its closest lane):

- leader: ``Road.neighbour_vehicles`` -- among the other vehicles whose centre lies on lane L
  with a 1 m margin (|y - y_L| <= 3 m, -5 m <= x < L_road + 5 m), the one with the smallest
  x >= x_k (ties: the last in road order);
- acceleration (IDM, Treiber et al. 2000): with v0 the target speed clipped to [0, v_limit],
  a = a_max [1 - (max(v, 0) / v0)^delta - (s* / d)^2], s* = s0 + v T + v dv / (2 sqrt(a_max b)),
  d = x_leader - x_k, dv = (v_k - v_leader) projected on k's heading; clipped to +-6 m/s^2;
- steering (``ControlledVehicle.steering_control``): a lateral P controller gives a lateral speed,
  converted into a heading reference, a heading P controller gives a heading rate, converted into
  a steering angle through the bicycle's slip angle; clipped to +-pi/3.
"""

import numpy as np
from numba import njit

from srmpc.sim.constants import (
    IDM_ACC_MAX,
    IDM_COMFORT_ACC_MAX,
    IDM_COMFORT_ACC_MIN,
    IDM_DISTANCE_WANTED,
    IDM_TIME_WANTED,
    KP_HEADING,
    KP_LATERAL,
    LANE_END_MARGIN,
    MAX_STEERING_ANGLE,
    NEIGHBOUR_LANE_MARGIN,
    VEHICLE_LENGTH,
)
from srmpc.sim.state import HEADING, SPEED, X, Y
from srmpc.sim.vehicle import on_lane, wrap_to_pi

NOT_ZERO_EPS = 1e-2
"""highway-env's ``utils.not_zero`` floor [same unit as its argument]."""


@njit(cache=True, error_model="numpy", inline="always")
def not_zero(value: float) -> float:
    """value if |value| > 1e-2, else +-1e-2 (sign of value, + for 0)."""
    if abs(value) > NOT_ZERO_EPS:
        return value
    if value >= 0:
        return NOT_ZERO_EPS
    return -NOT_ZERO_EPS


@njit(cache=True, error_model="numpy", inline="always")
def steering_control(x: float, y: float, heading: float, speed: float, target_lane: int, lane_width: float) -> float:
    """Steering [rad] that follows the centre of ``target_lane`` (lane heading 0).

    On the lane centre with heading 0 every term is (+-)0, so the result is 0 (exact shortcut).
    """
    lateral = y - target_lane * lane_width
    if lateral == 0.0 and heading == 0.0:
        return 0.0
    lateral_speed_command = -KP_LATERAL * lateral
    heading_command = np.arcsin(min(max(lateral_speed_command / not_zero(speed), -1.0), 1.0))
    heading_reference = 0.0 + min(max(heading_command, -np.pi / 4), np.pi / 4)
    heading_rate_command = KP_HEADING * wrap_to_pi(heading_reference - heading)
    slip_angle = np.arcsin(min(max(VEHICLE_LENGTH / 2 / not_zero(speed) * heading_rate_command, -1.0), 1.0))
    steering = np.arctan(2 * np.tan(slip_angle))
    return min(max(steering, -MAX_STEERING_ANGLE), MAX_STEERING_ANGLE)


@njit(cache=True, error_model="numpy", inline="always")
def leader(
    vehicles: np.ndarray,
    order: np.ndarray,
    position: np.ndarray,
    k: int,
    lane: int,
    lane_width: float,
    road_length: float,
) -> int:
    """Storage index of k's leader on ``lane``, -1 if none (see the module docstring).

    ``order`` sorts the scene's vehicles by (x, road rank) and ``position`` is its inverse, so the
    scan starts at the first vehicle with x == x_k and usually stops after a few vehicles.
    """
    s = vehicles[k, X]
    p = position[k]
    while p > 0 and vehicles[order[p - 1], X] == s:
        p -= 1
    front = -1
    s_front = np.inf
    for q in range(p, order.shape[0]):
        j = order[q]
        if j == k:
            continue
        s_j = vehicles[j, X]
        if front >= 0 and s_j > s_front:
            break
        if s_j >= s and on_lane(s_j, vehicles[j, Y], lane, lane_width, road_length, NEIGHBOUR_LANE_MARGIN):
            front = j  # equal x: later in road order wins, as ``s_v <= s_front`` in highway-env
            s_front = s_j
    return front


@njit(cache=True, error_model="numpy", inline="always")
def _direction(heading: float) -> tuple[float, float]:
    """(cos, sin) of the heading; exactly (1, 0) at heading 0 without calling them."""
    if heading == 0.0:
        return 1.0, 0.0
    return np.cos(heading), np.sin(heading)


@njit(cache=True, error_model="numpy", inline="always")
def all_leaders(
    vehicles: np.ndarray,
    order: np.ndarray,
    position: np.ndarray,
    lane: np.ndarray,
    target_lane: np.ndarray,
    lane_count: int,
    lane_width: float,
    road_length: float,
    lane_leader: np.ndarray,
    target_leader: np.ndarray,
    last_on_lane: np.ndarray,
) -> None:
    """:func:`leader` of every vehicle on its lane and on its target lane, in one sweep.

    Sweeping ``order`` from the front, the last vehicle seen on each lane is the leader of the
    next vehicle behind it on that lane. This equals :func:`leader` whenever no two x are exactly
    equal (ties are resolved by road order there); on a tie the scan :func:`leader` is used. The tie
    test runs inside the sweep (consecutive x in ``order`` compared with ``==``, as a separate pass
    would) and the fallback overwrites every entry, so a sweep cut short by a tie leaves nothing behind.
    :func:`~srmpc.sim.vehicle.on_lane`'s two conditions are evaluated separately (the longitudinal one
    once per vehicle, the lateral one per lane), on the same floats. ``last_on_lane`` is a work buffer
    of at least ``lane_count`` int64.
    """
    n = order.shape[0]
    last_on_lane[:lane_count] = -1
    lateral_limit = lane_width / 2 + NEIGHBOUR_LANE_MARGIN
    x_ahead = np.nan  # x of the vehicle one place ahead in ``order`` (none: compares unequal)
    for p in range(n - 1, -1, -1):
        k = order[p]
        x = vehicles[k, X]
        if x == x_ahead:
            for m in range(n):
                lane_leader[m] = leader(vehicles, order, position, m, lane[m], lane_width, road_length)
                target_leader[m] = leader(vehicles, order, position, m, target_lane[m], lane_width, road_length)
            return
        x_ahead = x
        lane_leader[k] = last_on_lane[lane[k]]
        target_leader[k] = last_on_lane[target_lane[k]]
        if -LANE_END_MARGIN <= x < road_length + LANE_END_MARGIN:  # on_lane's longitudinal condition
            y = vehicles[k, Y]
            for candidate_lane in range(lane_count):
                if abs(y - candidate_lane * lane_width) <= lateral_limit:  # on_lane's lateral condition
                    last_on_lane[candidate_lane] = k


@njit(cache=True, error_model="numpy", inline="always")
def desired_gap(vehicles: np.ndarray, k: int, front: int) -> float:
    """s* = s0 + v T + v dv / (2 sqrt(a b)) [m], dv = (v_k - v_front) . (cos psi_k, sin psi_k)."""
    speed = vehicles[k, SPEED]
    cos_k, sin_k = _direction(vehicles[k, HEADING])
    cos_front, sin_front = _direction(vehicles[front, HEADING])
    front_speed = vehicles[front, SPEED]
    dv = (speed * cos_k - front_speed * cos_front) * cos_k + (speed * sin_k - front_speed * sin_front) * sin_k
    ab = -IDM_COMFORT_ACC_MAX * IDM_COMFORT_ACC_MIN
    return IDM_DISTANCE_WANTED + speed * IDM_TIME_WANTED + speed * dv / (2 * np.sqrt(ab))


@njit(cache=True, error_model="numpy", inline="always")
def idm_acceleration(
    vehicles: np.ndarray, k: int, front: int, target_speed: float, delta: float, speed_limit: float
) -> float:
    """IDM acceleration [m/s^2] of vehicle k behind ``front`` (-1: free road), before clipping."""
    target = min(max(target_speed, 0.0), speed_limit)
    acceleration = IDM_COMFORT_ACC_MAX * (1 - (max(vehicles[k, SPEED], 0.0) / abs(not_zero(target))) ** delta)
    if front >= 0:
        distance = vehicles[front, X] - vehicles[k, X]
        ratio = desired_gap(vehicles, k, front) / not_zero(distance)
        acceleration -= IDM_COMFORT_ACC_MAX * (ratio * ratio)
    return acceleration


@njit(cache=True, error_model="numpy", inline="always")
def clip_idm_acceleration(acceleration: float) -> float:
    """np.clip(a, -ACC_MAX, ACC_MAX)."""
    return min(max(acceleration, -IDM_ACC_MAX), IDM_ACC_MAX)
