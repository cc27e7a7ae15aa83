"""The paper's observation, eq. (observation): six surrounding vehicles plus the ego, 30 floats.

Slots, in this order, are the leader (dx > 0) and the follower (dx <= 0) on lane 0 (left),
lane 1 (middle) and lane 2 (right): the nearest vehicle on that lane ahead of, respectively
behind, the ego. Each slot holds [dx, dy, dvx, dvy] of that vehicle relative to the ego, with
velocities v * (cos heading, sin heading) as highway-env defines them. A vehicle's lane is the lane
whose centre is closest to it. Vehicles with |dx| > perception range are not observed.

An empty slot holds a phantom vehicle at the edge of perception on that lane's centre, moving
with the ego: [+range (leader) or -range (follower), lane centre - y_ego, 0, 0].

The ego part is [vx, vy, heading, y_right_edge - y, y_left_edge - y, y_right_lane_centre - y]
(signed lateral offsets; the right lane is the paper's target lane).

The policy sees ``raw / OBSERVATION_SCALE`` (float32). The scales put typical magnitudes near 1:

=============  ==========  ==================================================
feature        scale       why
=============  ==========  ==================================================
dx             100 m       perception range: |dx| <= 1
dy             12 m        road width: |dy| <= 1 on the road
dvx, dvy       20, 5 m/s   largest speed differences seen in traffic
vx, vy         40, 5 m/s   highway-env's maximum speed; lateral speeds are small
heading        0.5 rad     headings beyond 0.5 rad only occur just before a crash
edge/target dy 12 m        road width
=============  ==========  ==================================================

All functions are numba kernels over plain arrays so that the highway-env scenario and the
batched simulator compute the observation with the same code.
"""

import numpy as np
from numba import njit

from srmpc.scenario.road import (
    LANE_CENTERS,
    LANE_COUNT,
    LEFT_ROAD_EDGE,
    RIGHT_LANE,
    RIGHT_ROAD_EDGE,
)

SLOT_COUNT = 2 * LANE_COUNT
"""Observed vehicles: leader and follower on each lane."""
SLOT_FEATURES = 4
"""[dx, dy, dvx, dvy] per observed vehicle."""
EGO_FEATURES = 6
"""[vx, vy, heading, dy right edge, dy left edge, dy target lane]."""
OBSERVATION_SIZE = SLOT_COUNT * SLOT_FEATURES + EGO_FEATURES
"""30 floats."""
OBSERVATION_SCALE = np.array(
    [100.0, 12.0, 20.0, 5.0] * SLOT_COUNT + [40.0, 5.0, 0.5, 12.0, 12.0, 12.0], dtype=np.float64
)
"""Divisor of each raw feature to get the normalized observation."""

_LANE_CENTERS = np.asarray(LANE_CENTERS, dtype=np.float64)


@njit(cache=True)
def closest_lane(y: float) -> int:
    """Index of the lane whose centre is closest to lateral position ``y`` (first on ties)."""
    best_lane = 0
    best_distance = abs(y - _LANE_CENTERS[0])
    for lane in range(1, LANE_COUNT):
        distance = abs(y - _LANE_CENTERS[lane])
        if distance < best_distance:
            best_lane = lane
            best_distance = distance
    return best_lane


@njit(cache=True)
def find_observed_vehicles(
    ego: np.ndarray, others: np.ndarray, perception_range: float, slot_vehicle: np.ndarray
) -> None:
    """Fill ``slot_vehicle[6]`` with the index into ``others`` of each slot's vehicle, -1 if empty.

    ``ego`` is [x, y, heading, speed]; ``others`` is (V, 4) with the same columns. A slot's best |dx| so far
    is recomputed from the vehicle it holds (the same subtraction, so the same float; +inf while empty)
    instead of being kept in an array, which spares an allocation per call.
    """
    for slot in range(SLOT_COUNT):
        slot_vehicle[slot] = -1
    for j in range(others.shape[0]):
        dx = others[j, 0] - ego[0]
        if abs(dx) > perception_range:
            continue
        lane = closest_lane(others[j, 1])
        slot = 2 * lane if dx > 0.0 else 2 * lane + 1
        held = slot_vehicle[slot]
        best_dx = np.inf if held < 0 else abs(others[held, 0] - ego[0])
        if abs(dx) < best_dx:
            slot_vehicle[slot] = j


@njit(cache=True)
def raw_observation(
    ego: np.ndarray,
    others: np.ndarray,
    slot_vehicle: np.ndarray,
    perception_range: float,
    out: np.ndarray,
) -> None:
    """Write the 30 raw (unnormalized) observation features into ``out``."""
    ego_vx = ego[3] * np.cos(ego[2])
    ego_vy = ego[3] * np.sin(ego[2])
    for slot in range(SLOT_COUNT):
        base = SLOT_FEATURES * slot
        j = slot_vehicle[slot]
        if j >= 0:
            out[base + 0] = others[j, 0] - ego[0]
            out[base + 1] = others[j, 1] - ego[1]
            out[base + 2] = others[j, 3] * np.cos(others[j, 2]) - ego_vx
            out[base + 3] = others[j, 3] * np.sin(others[j, 2]) - ego_vy
        else:
            out[base + 0] = perception_range if slot % 2 == 0 else -perception_range
            out[base + 1] = _LANE_CENTERS[slot // 2] - ego[1]
            out[base + 2] = 0.0
            out[base + 3] = 0.0
    base = SLOT_FEATURES * SLOT_COUNT
    out[base + 0] = ego_vx
    out[base + 1] = ego_vy
    out[base + 2] = ego[2]
    out[base + 3] = RIGHT_ROAD_EDGE - ego[1]
    out[base + 4] = LEFT_ROAD_EDGE - ego[1]
    out[base + 5] = _LANE_CENTERS[RIGHT_LANE] - ego[1]


def observe(ego: np.ndarray, others: np.ndarray, perception_range: float) -> tuple[np.ndarray, np.ndarray]:
    """Convenience wrapper: (normalized float32 observation, slot_vehicle) of one scene."""
    slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
    raw = np.empty(OBSERVATION_SIZE, dtype=np.float64)
    find_observed_vehicles(ego, others, perception_range, slot_vehicle)
    raw_observation(ego, others, slot_vehicle, perception_range, raw)
    return (raw / OBSERVATION_SCALE).astype(np.float32), slot_vehicle
