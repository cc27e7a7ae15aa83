"""The RSS safety index: hand-computed RSS distances, monotonicity, and where its cost is zero or positive."""

import numpy as np
import pytest

from srmpc.config.compose import ConfigError, compose_config, recorded_yaml, to_objects
from srmpc.scenario.observation import observe
from srmpc.scenario.parameters import RssParameters, SafetyIndexKind, SafetyIndexParameters
from srmpc.scenario.safety_index import (
    rss_lateral_distance,
    rss_longitudinal_distance,
    rss_safe_distance,
    safety_index,
    safety_index_cost,
    scene_safety_index,
)

AGGRESSIVE = RssParameters()
"""IEEE 9304756's aggressive set (the default)."""
AD_RSS_LIB = RssParameters(response_time_ego_s=1.0, response_time_others_s=2.0,
                           longitudinal_acceleration_max_mps2=3.5, longitudinal_brake_min_mps2=4.0,
                           longitudinal_brake_max_mps2=8.0, lateral_acceleration_max_mps2=0.2,
                           lateral_brake_min_mps2=0.8, lateral_margin_m=0.1)
SI = SafetyIndexParameters(kind=SafetyIndexKind.rss)


def rss_phi(ego, others, rss=AGGRESSIVE, si=SI):
    ego = np.asarray(ego, dtype=float)
    others = np.asarray(others, dtype=float).reshape(-1, 4)
    _, slots = observe(ego, others, 100.0)
    return scene_safety_index(ego, others, slots, True, si.sigma_m, si.d_min_m, si.edge_d_min_m, si.n, si.k_s,
                              rss.as_tuple())


def test_longitudinal_distance_by_hand():
    # aggressive set, rear 25 m/s, front 20 m/s:
    # 25 * 0.53 + 0.5 * 4.1 * 0.53^2 + (25 + 0.53 * 4.1)^2 / (2 * 4.64) - 20^2 / (2 * 8.03)
    # = 13.25 + 0.575845 + 79.565941 - 24.906600 = 68.485186 m
    d = rss_longitudinal_distance(25.0, 20.0, 0.53, 4.10, 4.64, 8.03)
    assert d == pytest.approx(68.485186, abs=1e-5)
    # ad-rss-lib's defaults, both at 25 m/s: 25 + 1.75 + 28.5^2 / 8 - 25^2 / 16 = 89.21875 m
    assert rss_longitudinal_distance(25.0, 25.0, 1.0, 3.5, 4.0, 8.0) == pytest.approx(89.21875, abs=1e-12)
    # a fast front vehicle and a slow rear one: the bracket is negative, the distance 0
    assert rss_longitudinal_distance(5.0, 30.0, 0.53, 4.10, 4.64, 8.03) == 0.0


def test_lateral_distance_by_hand():
    # ad-rss-lib's lateral defaults (a 0.2, b 0.8, mu 0.1); left vehicle still (rho 1 s), right vehicle
    # drifting left at 0.5 m/s (rho 2 s):
    # left:  0 * 1 + 0.5 * 0.2 * 1 + (0 + 0.2)^2 / 1.6 = 0.125
    # right: -0.5 * 2 - 0.5 * 0.2 * 4 - (-0.5 - 0.4)^2 / 1.6 = -1.90625
    # d = 0.1 + (0.125 + 1.90625) = 2.13125 m
    assert rss_lateral_distance(0.0, -0.5, 1.0, 2.0, 0.2, 0.8, 0.1) == pytest.approx(2.13125, abs=1e-12)
    # both still: mu + the two worst-case drifts, 0.07 + 2 * (0.5 * 0.43 * 0.53^2 + (0.53 * 0.43)^2 / 1.92)
    expected = 0.07 + 2 * (0.5 * 0.43 * 0.53**2 + (0.53 * 0.43) ** 2 / 1.92)
    assert rss_lateral_distance(0.0, 0.0, 0.53, 0.53, 0.43, 0.96, 0.07) == pytest.approx(expected, abs=1e-12)


def test_pair_roles_follow_position():
    rss = AD_RSS_LIB.as_tuple()
    ego = np.array([0.0, 4.0, 0.0, 25.0])
    leader = np.array([30.0, 4.0, 0.0, 20.0])
    follower = np.array([-30.0, 4.0, 0.0, 20.0])
    # ego behind the leader: the ego is the rear vehicle with its own response time (1 s)
    assert rss_safe_distance(ego, leader, True, rss) == rss_longitudinal_distance(25.0, 20.0, 1.0, 3.5, 4.0, 8.0)
    # ego ahead of the follower: the follower is the rear vehicle, with the others' response time (2 s)
    assert rss_safe_distance(ego, follower, True, rss) == rss_longitudinal_distance(20.0, 25.0, 2.0, 3.5, 4.0, 8.0)
    # a vehicle on the right lane (larger y) drifting left: the ego is the left vehicle
    right = np.array([0.0, 8.0, -0.02, 25.0])
    vy = 25.0 * np.sin(-0.02)
    assert rss_safe_distance(ego, right, False, rss) == rss_lateral_distance(0.0, vy, 1.0, 2.0, 0.2, 0.8, 0.1)
    left = np.array([0.0, 0.0, 0.02, 25.0])
    assert rss_safe_distance(ego, left, False, rss) == rss_lateral_distance(25.0 * np.sin(0.02), 0.0, 2.0, 1.0,
                                                                             0.2, 0.8, 0.1)


@pytest.mark.parametrize("rss", [AGGRESSIVE, AD_RSS_LIB], ids=["aggressive", "ad_rss_lib"])
def test_monotone_in_the_followers_speed(rss):
    p = rss
    speeds = np.linspace(0.0, 40.0, 81)
    for front in (0.0, 15.0, 25.0, 35.0):
        d = [rss_longitudinal_distance(v, front, p.response_time_ego_s, p.longitudinal_acceleration_max_mps2,
                                       p.longitudinal_brake_min_mps2, p.longitudinal_brake_max_mps2) for v in speeds]
        assert np.all(np.diff(d) >= 0.0)
        assert d[-1] > d[0] or front > 40.0
    # and phi with a leader 40 m ahead at 22 m/s grows with the ego's speed
    phis = [rss_phi([0.0, 4.0, 0.0, v], [[40.0, 4.0, 0.0, 22.0]], rss) for v in speeds]
    assert np.all(np.diff(phis) >= 0.0) and phis[-1] > phis[0]


def test_barrier_sign_is_rss_safety_without_the_rate_term():
    """With k = 0 (no rate term), phi_j > 0 exactly when the box gap is below sigma + the RSS distance."""
    si = SafetyIndexParameters(kind=SafetyIndexKind.rss, k_s=0.0, sigma_m=0.0)
    rng = np.random.default_rng(0)
    for _ in range(500):
        ego = np.array([0.0, 4.0, 0.0, rng.uniform(15, 30)])
        other = np.array([rng.uniform(5.0, 100.0), 4.0, 0.0, rng.uniform(15, 30)])
        gap = other[0] - 5.0
        d_rss = rss_safe_distance(ego, other, True, AGGRESSIVE.as_tuple())
        phi = rss_phi(ego, [other], si=si)
        if abs(gap - d_rss) > 1e-9:
            assert (phi > 0.0) == (gap < d_rss)


def test_cost_is_at_the_floor_where_the_pair_is_rss_safe_and_positive_where_the_condition_fails():
    si = SI
    # leader 80 m ahead at the ego's speed: RSS-safe (about 45 m needed at 22 m/s), before and after a step
    before = rss_phi([0.0, 4.0, 0.0, 22.0], [[80.0, 4.0, 0.0, 22.0]])
    after = rss_phi([4.4, 4.0, 0.0, 22.0], [[84.4, 4.0, 0.0, 22.0]])
    assert before < 0.0 and after < 0.0
    assert safety_index_cost(before, after, si.eta, si.cost_floor) <= 0.0
    # leader 30 m ahead, 5 m/s slower, the ego keeps its speed: unsafe and getting worse, c > 0
    before = rss_phi([0.0, 4.0, 0.0, 25.0], [[30.0, 4.0, 0.0, 20.0]])
    after = rss_phi([5.0, 4.0, 0.0, 25.0], [[34.0, 4.0, 0.0, 20.0]])
    assert before > 0.0 and after > before - si.eta
    assert safety_index_cost(before, after, si.eta, si.cost_floor) > 0.0
    # the paper's index calls the same leader safe (gap 25 m against 1.5 m + 5 m/s x 1 s)
    paper = SafetyIndexParameters()
    ego, others = np.array([0.0, 4.0, 0.0, 25.0]), np.array([[30.0, 4.0, 0.0, 20.0]])
    _, slots = observe(ego, others, 100.0)
    assert safety_index(ego, others, slots, paper.sigma_m, paper.d_min_m, paper.edge_d_min_m, paper.n,
                        paper.k_s) < 0.0


def test_paper_kind_is_the_papers_index_bit_for_bit():
    """With kind paper, phi is the paper's: the edge barriers and sigma + d_min for every observed vehicle,
    composed here from the barrier kernel alone (the same operations, so the same bits)."""
    from srmpc.scenario.observation import closest_lane
    from srmpc.scenario.road import LEFT_ROAD_EDGE, RIGHT_ROAD_EDGE
    from srmpc.scenario.safety_index import barrier, vehicle_gap_and_rate

    rng = np.random.default_rng(1)
    si = SafetyIndexParameters()
    for _ in range(200):
        ego = np.array([0.0, rng.choice([0.0, 4.0, 8.0]) + rng.normal(0, 0.3), rng.normal(0, 0.02),
                        rng.uniform(15, 30)])
        others = np.column_stack([rng.uniform(-90, 90, 8), rng.choice([0.0, 4.0, 8.0], 8), np.zeros(8),
                                  rng.uniform(18, 26, 8)])
        _, slots = observe(ego, others, 100.0)
        vy = ego[3] * np.sin(ego[2])
        expected = max(barrier(max(RIGHT_ROAD_EDGE - ego[1], 0.0), -vy, si.sigma_m + si.edge_d_min_m, si.n, si.k_s),
                       barrier(max(ego[1] - LEFT_ROAD_EDGE, 0.0), vy, si.sigma_m + si.edge_d_min_m, si.n, si.k_s))
        for j in slots[slots >= 0]:
            same_lane = closest_lane(others[j, 1]) == closest_lane(ego[1])
            gap, rate = vehicle_gap_and_rate(ego, others[j], same_lane)
            expected = max(expected, barrier(gap, rate, si.sigma_m + si.d_min_m, si.n, si.k_s))
        assert safety_index(ego, others, slots, si.sigma_m, si.d_min_m, si.edge_d_min_m, si.n, si.k_s) == expected
        assert scene_safety_index(ego, others, slots, False, si.sigma_m, si.d_min_m, si.edge_d_min_m, si.n,
                                  si.k_s, AGGRESSIVE.as_tuple()) == expected


def test_rss_kind_is_composed_of_the_pair_kernels_bit_for_bit():
    """With kind rss, phi equals the edge barriers and, per observed vehicle, the barrier at sigma + its
    ``rss_safe_distance``, composed here from the public kernels (each recomputes the velocities that
    ``scene_safety_index`` computes once per vehicle): the same operations, so the same bits."""
    from srmpc.scenario.observation import closest_lane
    from srmpc.scenario.road import LEFT_ROAD_EDGE, RIGHT_ROAD_EDGE
    from srmpc.scenario.safety_index import barrier, vehicle_gap_and_rate

    rng = np.random.default_rng(2)
    for rss in (AGGRESSIVE, AD_RSS_LIB):
        for _ in range(100):
            ego = np.array([0.0, rng.choice([0.0, 4.0, 8.0]) + rng.normal(0, 0.5), rng.normal(0, 0.05),
                            rng.uniform(15, 30)])
            others = np.column_stack([rng.uniform(-60, 60, 8), rng.choice([0.0, 4.0, 8.0], 8) + rng.normal(0, 1, 8),
                                      rng.normal(0, 0.05, 8) * rng.integers(0, 2, 8), rng.uniform(18, 26, 8)])
            _, slots = observe(ego, others, 100.0)
            vy = ego[3] * np.sin(ego[2])
            edge = SI.sigma_m + SI.edge_d_min_m
            expected = max(barrier(max(RIGHT_ROAD_EDGE - ego[1], 0.0), -vy, edge, SI.n, SI.k_s),
                           barrier(max(ego[1] - LEFT_ROAD_EDGE, 0.0), vy, edge, SI.n, SI.k_s))
            for j in slots[slots >= 0]:
                same_lane = closest_lane(others[j, 1]) == closest_lane(ego[1])
                gap, rate = vehicle_gap_and_rate(ego, others[j], same_lane)
                safe = rss_safe_distance(ego, others[j], same_lane, rss.as_tuple())
                expected = max(expected, barrier(gap, rate, SI.sigma_m + safe, SI.n, SI.k_s))
            assert rss_phi(ego, others, rss) == expected


def test_config_selects_the_index_and_records_rss_only_when_selected():
    paper = compose_config([])
    assert "rss" not in recorded_yaml(paper) and "kind" not in recorded_yaml(paper)
    rss = compose_config(["scenario.safety_index.kind=rss", "scenario.safety_index.rss.response_time_ego_s=1.0"])
    config = to_objects(rss)
    assert config.scenario.safety_index.kind is SafetyIndexKind.rss
    assert config.scenario.safety_index.rss.response_time_ego_s == 1.0
    assert "kind: rss" in recorded_yaml(rss) and "response_time_ego_s: 1.0" in recorded_yaml(rss)
    with pytest.raises(ConfigError, match="kind"):
        compose_config(["scenario.safety_index.kind=nope"])
    with pytest.raises(ConfigError, match="longitudinal_brake_min_mps2"):
        compose_config(["scenario.safety_index.rss.longitudinal_brake_min_mps2=0"])
    with pytest.raises(ConfigError, match="response_time_others_s"):
        compose_config(["scenario.safety_index.rss.response_time_others_s=11"])


def test_twin_constants_carry_the_rss_parameters_in_their_order():
    from srmpc.scenario.parameters import ScenarioParameters
    from srmpc.sim.constants import sim_constants

    rss = RssParameters(response_time_ego_s=1.0, response_time_others_s=2.0, longitudinal_acceleration_max_mps2=3.0,
                        longitudinal_brake_min_mps2=4.0, longitudinal_brake_max_mps2=5.0,
                        lateral_acceleration_max_mps2=0.6, lateral_brake_min_mps2=0.7, lateral_margin_m=0.8)
    c = sim_constants(ScenarioParameters(safety_index=SafetyIndexParameters(kind=SafetyIndexKind.rss, rss=rss)))
    assert c.si_rss is True
    assert (c.rss_response_time_ego, c.rss_response_time_others, c.rss_longitudinal_acceleration_max,
            c.rss_longitudinal_brake_min, c.rss_longitudinal_brake_max, c.rss_lateral_acceleration_max,
            c.rss_lateral_brake_min, c.rss_lateral_margin) == rss.as_tuple()
    assert sim_constants(ScenarioParameters()).si_rss is False
