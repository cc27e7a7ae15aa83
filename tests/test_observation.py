"""The observation of hand-built scenes: slots, relative quantities, fill values, ego features."""

import numpy as np
import pytest

from srmpc.scenario.observation import OBSERVATION_SCALE, closest_lane, observe
from tests.conftest import build_scene


def slot(raw: np.ndarray, index: int) -> np.ndarray:
    return raw[4 * index: 4 * index + 4]


def test_vehicle_ahead_on_left_lane_fills_left_leader_slot(env):
    # ego on the middle lane at 20 m/s; a vehicle 10 m ahead on the left lane at 25 m/s
    build_scene(env, ego=(100.0, 4.0, 0.0, 20.0), others=[(110.0, 0.0, 0.0, 25.0)])
    raw = env.measurement.raw_observation
    np.testing.assert_allclose(slot(raw, 0), [10.0, -4.0, 5.0, 0.0])
    assert env.measurement.slot_vehicle.tolist() == [0, -1, -1, -1, -1, -1]
    # the policy sees the same numbers divided by the documented scales
    obs = env.observation_type.observe()
    np.testing.assert_allclose(obs[:4], [0.1, -4.0 / 12.0, 5.0 / 20.0, 0.0], rtol=1e-6)


def test_empty_slots_hold_phantom_vehicles_at_perception_range(env):
    build_scene(env, ego=(100.0, 4.0, 0.0, 20.0), others=[])
    raw = env.measurement.raw_observation
    for lane, centre in enumerate([0.0, 4.0, 8.0]):
        np.testing.assert_allclose(slot(raw, 2 * lane), [100.0, centre - 4.0, 0.0, 0.0])
        np.testing.assert_allclose(slot(raw, 2 * lane + 1), [-100.0, centre - 4.0, 0.0, 0.0])


def test_nearest_leader_and_follower_per_lane_and_range():
    ego = np.array([0.0, 8.0, 0.0, 25.0])
    others = np.array(
        [
            [30.0, 8.0, 0.0, 20.0],  # right lane, second leader
            [12.0, 8.1, 0.0, 22.0],  # right lane, nearest leader
            [-7.0, 7.9, 0.0, 27.0],  # right lane, follower
            [-150.0, 4.0, 0.0, 30.0],  # middle lane, beyond perception
            [0.0, 4.0, 0.0, 24.0],  # middle lane, alongside: dx = 0 counts as follower
        ]
    )
    _, slots = observe(ego, others, perception_range=100.0)
    assert slots.tolist() == [-1, -1, -1, 4, 1, 2]


def test_ego_features_and_velocity_components(env):
    heading = 0.05
    build_scene(env, ego=(50.0, 6.5, heading, 20.0), others=[])
    ego_part = env.measurement.raw_observation[24:]
    np.testing.assert_allclose(
        ego_part, [20.0 * np.cos(heading), 20.0 * np.sin(heading), heading, 10.0 - 6.5, -2.0 - 6.5, 8.0 - 6.5]
    )
    assert OBSERVATION_SCALE.shape == (30,)


@pytest.mark.parametrize(("y", "lane"), [(-1.9, 0), (1.99, 0), (2.01, 1), (5.9, 1), (6.01, 2), (11.0, 2)])
def test_closest_lane(y, lane):
    assert closest_lane(y) == lane


def test_observed_vehicles_are_the_nearest_per_slot_as_a_scan_finds_them():
    """``find_observed_vehicles`` against a plain scan that keeps each slot's best |dx| (strictly smaller
    wins, so the first of equal |dx| stays), on random scenes with repeated |dx|, vehicles out of range
    and a NaN position (never observed)."""
    from srmpc.scenario.observation import SLOT_COUNT, find_observed_vehicles

    rng = np.random.default_rng(0)
    slot_vehicle = np.empty(SLOT_COUNT, dtype=np.int64)
    for _ in range(300):
        ego = np.array([rng.uniform(0, 50), rng.uniform(-1, 9), 0.0, 25.0])
        others = np.column_stack([ego[0] + rng.choice([-120, -30, -10, -5, 5, 10, 30, 120], 12).astype(float),
                                  rng.choice([0.0, 4.0, 8.0], 12), np.zeros(12), np.full(12, 20.0)])
        others[rng.integers(12), 0] = np.nan
        best, expected = np.full(SLOT_COUNT, np.inf), np.full(SLOT_COUNT, -1)
        for j, (x, y, _, _) in enumerate(others):
            dx = x - ego[0]
            if abs(dx) > 100.0:
                continue
            slot_index = 2 * closest_lane(y) + (0 if dx > 0.0 else 1)
            if abs(dx) < best[slot_index]:
                best[slot_index], expected[slot_index] = abs(dx), j
        find_observed_vehicles(ego, others, 100.0, slot_vehicle)
        np.testing.assert_array_equal(slot_vehicle, expected)
