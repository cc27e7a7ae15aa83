"""The twin's state: B scenes of N = vehicles_count + 1 vehicles, float64, structure of arrays.

Storage order within a scene: the IDM vehicles in spawn order (indices 0..N-2), then the ego
(index N-1), so that ``vehicles[b, :N-1]`` is exactly ``SceneMeasurement.others`` of
``SrmpcHighwayEnv`` and the observation kernels apply unchanged. highway-env's *road order*
(the order of ``road.vehicles``, which decides collision-pair order and tie-breaks in the leader
search) has the ego at position ``ego_rank`` instead; the road rank of storage index k < N-1 is
k if k < ego_rank else k + 1.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, fields

import numpy as np

X, Y, HEADING, SPEED = 0, 1, 2, 3
"""Columns of ``vehicles``: position x [m], y [m], heading [rad], speed [m/s]."""
STEERING, ACCELERATION = 0, 1
"""Columns of ``control``: steering angle [rad], acceleration [m/s^2]."""

StateArrays = namedtuple(
    "StateArrays",
    [
        "vehicles",
        "control",
        "crashed",
        "impact",
        "has_impact",
        "lane",
        "target_lane",
        "target_speed",
        "delta",
        "ego_rank",
        "steps",
        "phi",
        "rng",
        "order",
    ],
)
"""The arrays of a :class:`SceneState`, as the tuple the numba kernels take."""


@dataclass
class SceneState:
    """State of B scenes. Every array's first axis is the scene."""

    vehicles: np.ndarray
    """(B, N, 4) float64 [x [m], y [m], heading [rad], speed [m/s]] (highway-env ``position``,
    ``heading``, ``speed``)."""
    control: np.ndarray
    """(B, N, 2) float64 [steering [rad], acceleration [m/s^2]]: the action each vehicle holds
    (highway-env ``vehicle.action``; the ego keeps its action across sub-steps and clipping
    overwrites it in place, as there)."""
    crashed: np.ndarray
    """(B, N) bool, highway-env ``crashed``."""
    impact: np.ndarray
    """(B, N, 2) float64 [m]: a pending collision transition, applied at the next integration."""
    has_impact: np.ndarray
    """(B, N) bool: whether ``impact`` is pending (highway-env ``impact is not None``)."""
    lane: np.ndarray
    """(B, N) int64: closest lane (``lane_index[2]``), updated after every integration step."""
    target_lane: np.ndarray
    """(B, N) int64: the lane an IDM vehicle follows (``target_lane_index[2]``)."""
    target_speed: np.ndarray
    """(B, N) float64 [m/s]: IDM target speed (clipped to the speed limit when used)."""
    delta: np.ndarray
    """(B, N) float64 [-]: IDM velocity exponent, randomized per vehicle."""
    ego_rank: np.ndarray
    """(B,) int64: the ego's position in highway-env's road order."""
    steps: np.ndarray
    """(B,) int64: control steps since the scene's reset."""
    phi: np.ndarray
    """(B,) float64: safety index phi of the current state (the SI cost needs phi(s))."""
    rng: np.ndarray
    """(B,) uint64: state of each scene's random stream (used by resets only)."""
    order: np.ndarray
    """(B, N) int64: storage indices sorted by (x, road rank). A cache: any permutation is valid,
    a nearly sorted one makes the per-step insertion sort O(N)."""

    @classmethod
    def empty(cls, scenes: int, vehicles: int) -> SceneState:
        """Zeroed state of ``scenes`` scenes with ``vehicles`` vehicles each (ego included)."""
        shape = (scenes, vehicles)
        return cls(
            vehicles=np.zeros((*shape, 4)),
            control=np.zeros((*shape, 2)),
            crashed=np.zeros(shape, dtype=np.bool_),
            impact=np.zeros((*shape, 2)),
            has_impact=np.zeros(shape, dtype=np.bool_),
            lane=np.zeros(shape, dtype=np.int64),
            target_lane=np.zeros(shape, dtype=np.int64),
            target_speed=np.zeros(shape),
            delta=np.full(shape, 4.0),
            ego_rank=np.zeros(scenes, dtype=np.int64),
            steps=np.zeros(scenes, dtype=np.int64),
            phi=np.zeros(scenes),
            rng=np.zeros(scenes, dtype=np.uint64),
            order=np.tile(np.arange(vehicles, dtype=np.int64), (scenes, 1)),
        )

    @property
    def scenes(self) -> int:
        """B."""
        return self.vehicles.shape[0]

    @property
    def vehicle_count(self) -> int:
        """N, the ego included."""
        return self.vehicles.shape[1]

    @property
    def ego(self) -> np.ndarray:
        """(B, 4) view of the ego's [x, y, heading, speed]."""
        return self.vehicles[:, -1]

    @property
    def others(self) -> np.ndarray:
        """(B, N-1, 4) view of the IDM vehicles in spawn order."""
        return self.vehicles[:, :-1]

    def arrays(self) -> StateArrays:
        """The arrays as the kernels' tuple (views, not copies)."""
        return StateArrays(self.vehicles, self.control, self.crashed, self.impact, self.has_impact, self.lane,
                           self.target_lane, self.target_speed, self.delta, self.ego_rank, self.steps, self.phi,
                           self.rng, self.order)

    def copy(self) -> SceneState:
        """A deep copy (a snapshot)."""
        return SceneState(*(getattr(self, f.name).copy() for f in fields(self)))

    def take(self, scenes: np.ndarray | list[int] | slice) -> SceneState:
        """A copy of the given scenes only."""
        index = np.arange(self.scenes)[scenes] if isinstance(scenes, slice) else np.asarray(scenes)
        return SceneState(*(getattr(self, f.name)[index].copy() for f in fields(self)))

    def repeat(self, times: int) -> SceneState:
        """Each scene repeated ``times`` times, consecutively (one scene -> a batch of copies)."""
        return SceneState(*(np.repeat(getattr(self, f.name), times, axis=0) for f in fields(self)))

    def assign(self, source: SceneState, scenes: np.ndarray | list[int] | slice | None = None) -> None:
        """Overwrite the given scenes (all if None) with ``source``'s scenes, in place (a restore)."""
        if source.vehicle_count != self.vehicle_count:
            raise ValueError(f"source has {source.vehicle_count} vehicles per scene, this state {self.vehicle_count}")
        for f in fields(self):
            target = getattr(self, f.name)
            if scenes is None:
                target[...] = getattr(source, f.name)
            else:
                target[scenes] = getattr(source, f.name)

    @staticmethod
    def concatenate(states: list[SceneState]) -> SceneState:
        """The scenes of several states in one."""
        return SceneState(*(np.concatenate([getattr(s, f.name) for s in states]) for f in fields(SceneState)))
