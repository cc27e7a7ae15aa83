"""A simple lane-keeping baseline: IDM on the leader in the ego's lane, P-D steering to its centre.

It reads only the scenario's raw observation, never changes lane, and serves as the reference
controller that exercises the whole path config -> scenario -> episode metrics -> tracking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from srmpc.scenario import road
from srmpc.scenario.observation import OBSERVATION_SCALE, SLOT_COUNT, SLOT_FEATURES


@dataclass
class LaneKeepingGains:
    """Gains of the baseline. Defaults give a well-damped lateral response at 20-30 m/s."""

    target_speed_mps: float = 25.0
    """Cruise speed [m/s]."""
    time_headway_s: float = 1.5
    """IDM desired time gap [s]."""
    jam_distance_m: float = 10.0
    """IDM desired centre-to-centre distance at standstill [m]."""
    comfort_acceleration_mps2: float = 3.0
    """IDM maximum acceleration [m/s^2]."""
    comfort_deceleration_mps2: float = 5.0
    """IDM comfortable deceleration [m/s^2]."""
    lateral_gain: float = 0.04
    """Steering per metre of lateral error [rad/m]."""
    heading_gain: float = 0.6
    """Steering per radian of heading error [rad/rad]."""


class LaneKeepingController:
    """Follows the centre of the lane it is in, with IDM speed control on that lane's leader."""

    def __init__(
        self, steering_max: float, acceleration_min: float, acceleration_max: float,
        gains: LaneKeepingGains | None = None,
    ) -> None:
        self.steering_max = steering_max
        self.acceleration_min = acceleration_min
        self.acceleration_max = acceleration_max
        self.gains = gains or LaneKeepingGains()

    def reset(self) -> None:
        """No internal state."""

    def episode_outcomes(self) -> dict[str, int]:
        """A fixed law: no outcomes to count."""
        return {}

    def act(self, observation: np.ndarray, scene=None) -> np.ndarray:
        """(delta [rad], a [m/s^2]) from one normalized observation (the scene is not needed)."""
        raw = np.asarray(observation, dtype=np.float64) * OBSERVATION_SCALE
        gains = self.gains
        ego = raw[SLOT_COUNT * SLOT_FEATURES:]
        vx, heading = ego[0], ego[2]
        y = road.LANE_CENTERS[road.RIGHT_LANE] - ego[5]
        lane = int(np.argmin(np.abs(road.LANE_CENTERS - y)))
        lateral_error = road.LANE_CENTERS[lane] - y
        steering = gains.lateral_gain * lateral_error - gains.heading_gain * heading

        leader = raw[SLOT_FEATURES * 2 * lane: SLOT_FEATURES * (2 * lane + 1)]
        free_road = 1.0 - (max(vx, 0.0) / gains.target_speed_mps) ** 4
        acceleration = gains.comfort_acceleration_mps2 * free_road
        gap = leader[0]
        closing_speed = -leader[2]
        desired_gap = gains.jam_distance_m + max(
            0.0,
            vx * gains.time_headway_s
            + vx * closing_speed / (2.0 * np.sqrt(gains.comfort_acceleration_mps2 * gains.comfort_deceleration_mps2)),
        )
        acceleration -= gains.comfort_acceleration_mps2 * (desired_gap / max(gap, 1e-3)) ** 2
        return np.array(
            [
                np.clip(steering, -self.steering_max, self.steering_max),
                np.clip(acceleration, self.acceleration_min, self.acceleration_max),
            ]
        )
