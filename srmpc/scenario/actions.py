"""The scenario's action: (steering delta [rad], acceleration a [m/s^2]), the paper's order.

highway-env's ``ContinuousAction`` takes [acceleration, steering] in [-1, 1]^2 and maps each
linearly onto its range; :func:`to_highway_env` is the exact inverse of that map (after clipping
to the ranges), so a physical action reaches the vehicle unchanged up to rounding (< 1e-15).
"""

import numpy as np
from numba import njit


@njit(cache=True)
def clip_action(
    steering: float, acceleration: float, steering_max: float, acceleration_min: float, acceleration_max: float
) -> tuple[float, float]:
    """Clip a physical action to the scenario's box."""
    return (
        min(max(steering, -steering_max), steering_max),
        min(max(acceleration, acceleration_min), acceleration_max),
    )


def to_highway_env(
    action: np.ndarray, steering_max: float, acceleration_min: float, acceleration_max: float
) -> np.ndarray:
    """Physical (delta, a) -> highway-env's normalized [acceleration, steering] in [-1, 1]."""
    steering, acceleration = clip_action(
        float(action[0]), float(action[1]), steering_max, acceleration_min, acceleration_max
    )
    normalized_acceleration = 2.0 * (acceleration - acceleration_min) / (acceleration_max - acceleration_min) - 1.0
    normalized_steering = steering / steering_max
    return np.array([normalized_acceleration, normalized_steering], dtype=np.float64)
