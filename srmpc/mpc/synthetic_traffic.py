"""A small self-contained straight-highway scene for planner tests and latency benchmarks.

Stands in for the scenario until the gymnasium env / batched simulator are available to this
package: 3 lanes (centres 0, 4, 8 m), the ego integrated with the exact discrete model
(``KinematicBicycle``, 3 sub-steps of 1/15 s per 0.2 s step), other vehicles driving IDM along
their lane centre (heading 0, no lane changes), rectangle (SAT) collision checks.

IDM (highway-env's constants): a = a_max [1 - (v / v0)^delta - (s* / s)^2],
s* = s0 + v T + v (v - v_lead) / (2 sqrt(a_max b)), a_max = 6 m/s^2, b = 5 m/s^2,
s0 = 10 m (5 m + one length, measured centre to centre), T = 1.5 s, delta = 4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from srmpc.mpc.ocp import LANE_CENTRES_M, ROAD_LEFT_EDGE_M, ROAD_RIGHT_EDGE_M
from srmpc.mpc.vehicle_model import (
    VEHICLE_LENGTH_M,
    VEHICLE_WIDTH_M,
    BicycleParameters,
    KinematicBicycle,
)

IDM_MAX_ACCELERATION_M_S2 = 6.0
IDM_COMFORT_DECELERATION_M_S2 = 5.0
IDM_DISTANCE_WANTED_M = 5.0 + VEHICLE_LENGTH_M
IDM_TIME_WANTED_S = 1.5
IDM_DELTA = 4.0


def rectangle_corners(state: np.ndarray, length_m: float = VEHICLE_LENGTH_M,
                      width_m: float = VEHICLE_WIDTH_M) -> np.ndarray:
    """(4, 2) corners of a vehicle footprint centred at (x, y) rotated by its heading."""
    c, s = np.cos(state[2]), np.sin(state[2])
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length_m / 2, width_m / 2]
    rotation = np.array([[c, -s], [s, c]])
    return state[:2] + half @ rotation.T


def rectangles_overlap(corners_a: np.ndarray, corners_b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals."""
    for corners in (corners_a, corners_b):
        for i in range(4):
            edge = corners[(i + 1) % 4] - corners[i]
            axis = np.array([-edge[1], edge[0]])
            pa = corners_a @ axis
            pb = corners_b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


@dataclass
class SceneOutcome:
    crashed: bool
    offroad: bool


class SyntheticHighway:
    """Ego + IDM traffic on a straight 3-lane road (see module doc).

    Args:
        n_others: number of other vehicles.
        mean_spacing_m: mean longitudinal spacing between successive spawns [m] (about 24 m is
            highway-env's density 1 with 3 lanes, about 15 m density 1.6).
        seed: random seed.
        ego_lane: ego's starting lane index (0 left .. 2 right); None draws it.
        ego_speed_m_s: ego's initial speed [m/s].
        others_speed_range_m_s: others' initial (and desired) speeds are uniform in it [m/s].
        others: optional explicit (M, 4) initial others [x, y, heading, speed] (overrides the
            random placement).
    """

    def __init__(self, n_others: int = 20, mean_spacing_m: float = 24.0, seed: int = 0,
                 ego_lane: int | None = None, ego_speed_m_s: float = 25.0,
                 others_speed_range_m_s: tuple[float, float] = (21.0, 24.0),
                 others: np.ndarray | None = None,
                 bicycle: BicycleParameters | None = None) -> None:
        self.model = KinematicBicycle(bicycle)
        params = self.model.parameters
        self._one_substep = KinematicBicycle(BicycleParameters(
            length_m=params.length_m, control_period_s=params.substep_s, n_substeps=1,
            max_speed_m_s=params.max_speed_m_s, min_speed_m_s=params.min_speed_m_s))
        self.rng = np.random.default_rng(seed)
        lanes = np.asarray(LANE_CENTRES_M)
        lane = int(self.rng.integers(3)) if ego_lane is None else ego_lane
        self.ego = np.array([0.0, lanes[lane], 0.0, ego_speed_m_s])
        if others is None:
            others = self._spawn(n_others, mean_spacing_m, others_speed_range_m_s, lane)
        self.others = np.asarray(others, dtype=np.float64).reshape(-1, 4).copy()
        self.desired_speeds = self.others[:, 3].copy()
        self.steps = 0

    def _spawn(self, n_others, mean_spacing_m, speed_range, ego_lane) -> np.ndarray:
        lanes = np.asarray(LANE_CENTRES_M)
        others = []
        # spawn behind and ahead of the ego alternately, keeping the ego's own slot clear
        front, back = 0.0, 0.0
        for i in range(n_others):
            gap = mean_spacing_m * self.rng.uniform(0.9, 1.1)
            if i % 3 == 2:
                back -= gap
                x = back
            else:
                front += gap
                x = front
            lane = int(self.rng.integers(3))
            if lane == ego_lane and abs(x) < 20.0:
                x += np.sign(x) * 20.0 if x != 0 else 20.0
            others.append([x, lanes[lane], 0.0, self.rng.uniform(*speed_range)])
        return np.array(others).reshape(-1, 4)

    def lane_index(self, lateral_m: np.ndarray | float) -> np.ndarray:
        lanes = np.asarray(LANE_CENTRES_M)
        return np.argmin(np.abs(np.asarray(lateral_m)[..., None] - lanes), axis=-1)

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """(ego (4,), observed others (<= 6, 4)): leader and follower of the ego on each lane."""
        observed = []
        lanes = self.lane_index(self.others[:, 1])
        dx = self.others[:, 0] - self.ego[0]
        for lane in range(len(LANE_CENTRES_M)):
            in_lane = lanes == lane
            ahead = np.flatnonzero(in_lane & (dx >= 0))
            behind = np.flatnonzero(in_lane & (dx < 0))
            if ahead.size:
                observed.append(self.others[ahead[np.argmin(dx[ahead])]])
            if behind.size:
                observed.append(self.others[behind[np.argmax(dx[behind])]])
        return self.ego.copy(), np.array(observed).reshape(-1, 4)

    def _idm_accelerations(self) -> np.ndarray:
        lanes = self.lane_index(self.others[:, 1])
        ego_lane = int(self.lane_index(self.ego[1]))
        positions = np.concatenate([self.others[:, 0], [self.ego[0]]])
        speeds = np.concatenate([self.others[:, 3], [self.ego[3]]])
        all_lanes = np.concatenate([lanes, [ego_lane]])
        accelerations = np.empty(self.others.shape[0])
        for i in range(self.others.shape[0]):
            v = self.others[i, 3]
            acceleration = IDM_MAX_ACCELERATION_M_S2 * (
                1.0 - (max(v, 0.0) / max(self.desired_speeds[i], 1e-3)) ** IDM_DELTA)
            gaps = positions - positions[i]
            candidates = np.flatnonzero((all_lanes == lanes[i]) & (gaps > 0))
            if candidates.size:
                lead = candidates[np.argmin(gaps[candidates])]
                gap = max(gaps[lead] - VEHICLE_LENGTH_M, 1e-2)
                desired_gap = (IDM_DISTANCE_WANTED_M - VEHICLE_LENGTH_M + v * IDM_TIME_WANTED_S
                               + v * (v - speeds[lead]) / (2.0 * np.sqrt(
                                   IDM_MAX_ACCELERATION_M_S2 * IDM_COMFORT_DECELERATION_M_S2)))
                acceleration -= IDM_MAX_ACCELERATION_M_S2 * (max(desired_gap, 0.0) / gap) ** 2
            accelerations[i] = max(acceleration, -IDM_MAX_ACCELERATION_M_S2 * 2.0)
        return accelerations

    def step(self, action: np.ndarray) -> SceneOutcome:
        """Advance one control period with the ego input (delta, a) held constant."""
        params = self.model.parameters
        h = params.substep_s
        for _ in range(params.n_substeps):
            accelerations = self._idm_accelerations()
            self.ego = self._one_substep.step(self.ego, action)
            self.others[:, 0] += self.others[:, 3] * h
            self.others[:, 3] = np.maximum(self.others[:, 3] + accelerations * h, 0.0)
        self.steps += 1
        return SceneOutcome(self.crashed(), self.offroad())

    def crashed(self) -> bool:
        near = np.flatnonzero(np.abs(self.others[:, 0] - self.ego[0]) < VEHICLE_LENGTH_M + 1.0)
        ego_corners = rectangle_corners(self.ego)
        return any(rectangles_overlap(ego_corners, rectangle_corners(self.others[i]))
                   for i in near)

    def offroad(self) -> bool:
        return not (ROAD_LEFT_EDGE_M <= self.ego[1] <= ROAD_RIGHT_EDGE_M)
