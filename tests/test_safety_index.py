"""phi and the SI cost on hand-computed cases (n = 1, sigma = 0.5, d_min = 1, k = 1, edge d_min = 0)."""

import numpy as np
import pytest

from srmpc.scenario.observation import observe
from srmpc.scenario.parameters import SafetyIndexParameters
from srmpc.scenario.safety_index import safety_index, safety_index_cost

SI = SafetyIndexParameters()


def phi(ego, others, si=SI):
    ego = np.asarray(ego, dtype=float)
    others = np.asarray(others, dtype=float).reshape(-1, 4)
    _, slots = observe(ego, others, 100.0)
    return safety_index(ego, others, slots, si.sigma_m, si.d_min_m, si.edge_d_min_m, si.n, si.k_s)


def test_lane_centre_without_traffic_is_safe_by_the_edges():
    # ego on the right lane centre, 2 m from the right edge: phi = 0.5 - 2 = -1.5
    assert phi([0, 8, 0, 25], []) == pytest.approx(-1.5)
    # on the middle lane both edges are 6 m away: -5.5
    assert phi([0, 4, 0, 25], []) == pytest.approx(-5.5)


def test_same_lane_leader_closing():
    # leader 15 m ahead (box gap 10 m), closing at 5 m/s: phi = 1.5 - 10 + 5 = -3.5
    assert phi([0, 4, 0, 25], [[15, 4, 0, 20]]) == pytest.approx(-3.5)
    # 10 m ahead (gap 5 m), closing at 10 m/s: phi = 1.5 - 5 + 10 = 6.5 (unsafe)
    assert phi([0, 4, 0, 25], [[10, 4, 0, 15]]) == pytest.approx(6.5)


def test_other_lane_longitudinal_rate_is_zeroed():
    # leader on the left lane, 10 m ahead, 10 m/s slower: gap_x = 5, gap_y = 2, d = sqrt(29)
    # the longitudinal closing speed does not count: phi = 1.5 - sqrt(29)
    assert phi([0, 4, 0, 25], [[10, 0, 0, 15]]) == pytest.approx(max(1.5 - np.sqrt(29.0), -5.5))


def test_lateral_drift_towards_vehicle_alongside():
    # vehicle alongside on the left lane (gap_y = 2 m); ego drifts left at 1 m/s (heading -asin(1/25))
    heading = -np.arcsin(1.0 / 25.0)
    ego = [0, 4, heading, 25]
    other = [0, 0, 0, 25 * np.cos(heading)]  # same vx: only the lateral rate remains
    # d = 2, d_dot = -1: phi = 1.5 - 2 + 1 = 0.5
    assert phi(ego, [other]) == pytest.approx(0.5)


def test_road_edge_drift():
    # 1 m from the right edge (y = 9), drifting right at 2 m/s: phi = 0.5 - 1 + 2 = 1.5
    heading = np.arcsin(2.0 / 20.0)
    assert phi([0, 9, heading, 20], []) == pytest.approx(1.5)


def test_overlap_gives_maximal_phi():
    assert phi([0, 4, 0, 25], [[3, 4.5, 0, 25]]) == pytest.approx(1.5)


@pytest.mark.parametrize(
    ("phi_before", "phi_after", "expected"),
    [
        (-1.0, -0.5, -0.1),  # safe -> safe: the floor
        (-1.0, -0.05, -0.05),
        (-1.0, 0.3, 0.3),  # safe -> unsafe: cost phi(s')
        (1.0, 0.85, -0.05),  # unsafe, decreasing by more than eta: 0.85 - 0.9
        (1.0, 0.95, 0.05),  # unsafe, decreasing by less than eta
        (1.0, 1.5, 0.6),  # unsafe and growing
    ],
)
def test_cost(phi_before, phi_after, expected):
    assert safety_index_cost(phi_before, phi_after, 0.1, -0.1) == pytest.approx(expected)
