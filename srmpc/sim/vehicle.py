"""highway-env's ``Vehicle``: kinematic bicycle step, action clipping, lanes, the ego's action map.

Everything replicates highway-env 1.12.1's float64 arithmetic operation by operation, so that the
twin and highway-env agree to rounding (see ``tests/test_sim_differential.py``).
"""

import numpy as np
from numba import njit

from srmpc.sim.constants import LANE_END_MARGIN, MAX_SPEED, MIN_SPEED, VEHICLE_LENGTH
from srmpc.sim.state import ACCELERATION, HEADING, SPEED, STEERING, X, Y


@njit(cache=True, error_model="numpy", inline="always")
def wrap_to_pi(angle: float) -> float:
    """((angle + pi) mod 2 pi) - pi, highway-env's ``utils.wrap_to_pi``.

    The modulo is exact and the identity on [0, 2 pi), so it is skipped there (bit-identical).
    """
    shifted = angle + np.pi
    if not (0.0 <= shifted < 2 * np.pi):
        shifted = shifted % (2 * np.pi)
    return shifted - np.pi


@njit(cache=True, error_model="numpy", inline="always")
def closest_lane_index(
    x: float, y: float, heading: float, lane_count: int, lane_width: float, road_length: float
) -> int:
    """``RoadNetwork.get_closest_lane_index(position, heading)`` on the straight road.

    Lane i runs along y = i * lane_width from x = 0 to road_length with heading 0. Its distance is
    |y - y_i| + max(x - L, 0) + max(-x, 0) + |wrap(heading)|; the first minimum wins (np.argmin).
    """
    angle = abs(wrap_to_pi(heading - 0.0))
    longitudinal_excess = max(x - road_length, 0.0)
    longitudinal_deficit = max(0.0 - x, 0.0)
    best_lane = 0
    best_distance = np.inf
    for lane in range(lane_count):
        distance = abs(y - lane * lane_width) + longitudinal_excess + longitudinal_deficit + 1.0 * angle
        if distance < best_distance:
            best_distance = distance
            best_lane = lane
    return best_lane


@njit(cache=True, error_model="numpy", inline="always")
def on_lane(x: float, y: float, lane: int, lane_width: float, road_length: float, margin: float) -> bool:
    """``AbstractLane.on_lane``: |y - y_lane| <= width/2 + margin and -5 <= x < L + 5 [m]."""
    return abs(y - lane * lane_width) <= lane_width / 2 + margin and (
        -LANE_END_MARGIN <= x < road_length + LANE_END_MARGIN
    )


@njit(cache=True, error_model="numpy", inline="always")
def ego_control(
    steering: float, acceleration: float, steering_max: float, acceleration_min: float, acceleration_max: float
) -> tuple[float, float]:
    """The physical (delta, a) the ego holds after ``SrmpcHighwayEnv.step``'s round trip.

    Clip to the box, normalize as ``srmpc.scenario.actions.to_highway_env``
    (a_n = 2 (a - a_min) / (a_max - a_min) - 1, delta_n = delta / delta_max), clip to [-1, 1] and
    map back with ``utils.lmap`` (y0 + (v - x0) (y1 - y0) / (x1 - x0)), operation by operation.
    """
    steering = min(max(steering, -steering_max), steering_max)
    acceleration = min(max(acceleration, acceleration_min), acceleration_max)
    normalized_acceleration = 2.0 * (acceleration - acceleration_min) / (acceleration_max - acceleration_min) - 1.0
    normalized_steering = steering / steering_max
    normalized_acceleration = min(max(normalized_acceleration, -1.0), 1.0)
    normalized_steering = min(max(normalized_steering, -1.0), 1.0)
    acceleration_span = acceleration_max - acceleration_min
    held_acceleration = acceleration_min + (normalized_acceleration - (-1.0)) * acceleration_span / 2.0
    held_steering = -steering_max + (normalized_steering - (-1.0)) * (steering_max - (-steering_max)) / 2.0
    return held_steering, held_acceleration


@njit(cache=True, error_model="numpy", inline="always")
def integrate(
    vehicles: np.ndarray,
    control: np.ndarray,
    crashed: np.ndarray,
    lane: np.ndarray,
    k: int,
    dt: float,
    lane_count: int,
    lane_width: float,
    road_length: float,
) -> None:
    """``Vehicle.step(dt)`` of vehicle k of one scene (arrays indexed [k, ...]).

    clip_actions: a crashed vehicle gets delta = 0, a = -v; beyond +-40 m/s the acceleration is
    limited to pull the speed back. Then, with beta = arctan(tan(delta) / 2):
    p += v [cos(psi + beta), sin(psi + beta)] dt (then a pending impact is added, marking the vehicle
    crashed, see :func:`apply_impacts`, which must follow); psi += v sin(beta) / (l / 2) dt;
    v += a dt; the lane becomes the closest lane.
    """
    speed = vehicles[k, SPEED]
    if crashed[k]:
        control[k, STEERING] = 0.0
        control[k, ACCELERATION] = -1.0 * speed
    if speed > MAX_SPEED:
        control[k, ACCELERATION] = min(control[k, ACCELERATION], 1.0 * (MAX_SPEED - speed))
    elif speed < MIN_SPEED:
        control[k, ACCELERATION] = max(control[k, ACCELERATION], 1.0 * (MIN_SPEED - speed))
    heading = vehicles[k, HEADING]
    steering = control[k, STEERING]
    straight = steering == 0.0 and heading == 0.0
    x_before = vehicles[k, X]
    x = x_before
    y = vehicles[k, Y]
    # (x and y are accumulated in locals and stored once: the same operations in the same order,
    # but a conditional read-modify-write of the array made the loop ~10x slower)
    if straight:
        # exact special case (tan 0 = atan 0 = sin 0 = 0, cos 0 = 1): a vehicle driving straight
        beta = 0.0
        x += speed * 1.0 * dt
        y += speed * 0.0 * dt
    else:
        beta = np.arctan(1 / 2 * np.tan(steering))
        x += speed * np.cos(heading + beta) * dt
        y += speed * np.sin(heading + beta) * dt
    vehicles[k, X] = x
    vehicles[k, Y] = y
    sin_beta = 0.0 if beta == 0.0 else np.sin(beta)
    heading = heading + speed * sin_beta / (VEHICLE_LENGTH / 2) * dt
    vehicles[k, HEADING] = heading
    vehicles[k, SPEED] = speed + control[k, ACCELERATION] * dt
    if straight and 0.0 <= x_before and x <= road_length:
        return  # y and heading (= 0) unchanged, no longitudinal term: the closest lane is unchanged
    lane[k] = closest_lane_index(x, y, heading, lane_count, lane_width, road_length)


@njit(cache=True, error_model="numpy", inline="always")
def apply_impacts(
    vehicles: np.ndarray,
    crashed: np.ndarray,
    impact: np.ndarray,
    has_impact: np.ndarray,
    lane: np.ndarray,
    lane_count: int,
    lane_width: float,
    road_length: float,
) -> None:
    """The second half of ``Vehicle.step`` for vehicles with a pending impact: p += impact, crashed.

    :func:`integrate` leaves it out (a rare branch there slowed the whole loop ~10x); applied right
    after it, the result is the same: (x + v cos(psi + beta) dt) + impact, then the closest lane.
    """
    for k in range(vehicles.shape[0]):
        if has_impact[k]:
            vehicles[k, X] += impact[k, 0]
            vehicles[k, Y] += impact[k, 1]
            crashed[k] = True
            has_impact[k] = False
            lane[k] = closest_lane_index(
                vehicles[k, X], vehicles[k, Y], vehicles[k, HEADING], lane_count, lane_width, road_length
            )
