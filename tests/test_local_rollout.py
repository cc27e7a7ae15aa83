"""The rollout's scene cut to the horizon (``srmpc.sim.local_rollout``): what it keeps, and how far its
rollout of the ego strays from the full scene's on recorded twin scenes.

Measured when written (random 64x64 policy ``MlpPolicy.random(0)``, 25 steps, scenes 30 steps after
``reset(seed)`` for seeds 0..99 under a random-acceleration lane-keeping policy, 41 vehicles per scene),
largest |ego state difference| over all steps and the four state components [m, rad, m/s]:

=========  ============  ==================  =================  ==============
traffic    leader_depth  vehicles kept/41    scenes exact       largest dev.
=========  ============  ==================  =================  ==============
light      1             20.6                11 %               1.5e-2
light      2 (default)   23.5                16 %               4.5e-3
light      3             26.1                18 %               1.1e-3
light      -1 (chains)   30.6                100 %              0
dense      1             31.9                59 %               4.2e-4
dense      2 (default)   33.6                84 %               1.6e-5
dense      3             34.2                100 %              0
dense      -1 (chains)   34.3                100 %              0
=========  ============  ==================  =================  ==============

The tests below use 20 seeds per traffic level and the default depth, and allow EGO_TOLERANCE.
"""

from __future__ import annotations

import numpy as np
import pytest

from srmpc.config.compose import compose_config, to_objects
from srmpc.sim import engine
from srmpc.sim.constants import SimConstants
from srmpc.sim.local_rollout import (
    LEADER_DEPTH,
    WINDOW_MARGIN_M,
    constant_speed_others,
    ego_reach_ahead_m,
    local_rollout,
    local_scene,
)
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import rollout
from srmpc.sim.single_env import TwinScenarioEnv
from srmpc.sim.state import SceneState
from srmpc.sim.vehicle import on_lane

HORIZON = 25
"""SRMPC's rollout horizon [control steps]."""
EGO_TOLERANCE = 1e-2
"""Largest allowed |ego state difference| of the reduced rollout (default depth) [m, rad, m/s]: twice the
largest measured over 100 light scenes (module doc)."""
SEEDS = range(20)


def recorded_scenes(traffic: str) -> tuple[list[SceneState], SimConstants]:
    """Twin scenes 30 control steps after ``reset(seed)``, driven by lane keeping with random acceleration."""
    config = to_objects(compose_config([f"+experiment={traffic}_traffic", "tracking.enabled=false"]))
    env = TwinScenarioEnv(config.scenario)
    scenes = []
    for seed in SEEDS:
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(30):
            _, _, terminated, _, _ = env.step(np.array([0.0, rng.uniform(-1.0, 1.0)]))
            if terminated:
                break
        scenes.append(env.simulator.state.copy())
    return scenes, env.simulator.constants


@pytest.fixture(scope="module", params=["light", "dense"])
def scenes(request) -> tuple[str, list[SceneState], SimConstants]:
    return request.param, *recorded_scenes(request.param)


def window(state: SceneState, constants: SimConstants) -> np.ndarray:
    """Storage indices of the IDM vehicles inside the module doc's window, computed here from its formulas."""
    horizon_s = HORIZON * constants.substeps * constants.dt
    x_ego, v_ego = state.vehicles[0, -1, 0], state.vehicles[0, -1, 3]
    others = state.vehicles[0, :-1]
    dx = others[:, 0] - x_ego
    ahead = constants.perception_range + WINDOW_MARGIN_M + ego_reach_ahead_m(v_ego, constants.acceleration_max,
                                                                              horizon_s)
    bound = np.maximum(others[:, 3], np.clip(state.target_speed[0, :-1], 0.0, constants.speed_limit))
    closing = np.maximum(0.0, (bound - v_ego) * horizon_s - 0.5 * constants.acceleration_min * horizon_s**2)
    behind = constants.perception_range + WINDOW_MARGIN_M + closing
    return np.flatnonzero(np.where(dx >= 0, dx <= ahead, -dx <= behind))


def lane_leader(state: SceneState, constants: SimConstants, k: int, lane: int) -> int:
    """k's leader on ``lane`` by brute force (``idm.leader``'s definition; ties: the last in road order)."""
    vehicles = state.vehicles[0]
    rank = [j + 1 if j >= state.ego_rank[0] else j for j in range(len(vehicles) - 1)] + [state.ego_rank[0]]
    best, key = -1, None
    for j, (x, y, _, _) in enumerate(vehicles):
        if j == k or x < vehicles[k, 0]:
            continue
        if not on_lane(x, y, lane, constants.lane_width, constants.road_length, 1.0):
            continue
        if key is None or (x, -rank[j]) < key:
            best, key = j, (x, -rank[j])
    return best


def test_keeps_the_ego_last_and_every_vehicle_in_the_window(scenes):
    _, states, constants = scenes
    for state in states:
        reduced, reduced_constants, kept = local_scene(state, constants, HORIZON)
        assert kept[-1] == constants.vehicles - 1 and np.all(np.diff(kept) > 0)
        assert set(window(state, constants)) <= set(kept[:-1])
        assert reduced_constants.vehicles == reduced.vehicle_count == kept.size
        np.testing.assert_array_equal(reduced.vehicles[0], state.vehicles[0, kept])
        np.testing.assert_array_equal(reduced.target_speed[0], state.target_speed[0, kept])
        # road order restricted to the kept vehicles, and an x-order that is a permutation
        full_rank = np.where(np.arange(constants.vehicles - 1) >= state.ego_rank[0],
                             np.arange(constants.vehicles - 1) + 1, np.arange(constants.vehicles - 1))
        assert reduced.ego_rank[0] == np.count_nonzero(full_rank[kept[:-1]] < state.ego_rank[0])
        assert sorted(reduced.order[0]) == list(range(kept.size))


def test_keeps_the_leader_chains_to_the_stated_depth(scenes):
    _, states, constants = scenes
    for state in states:
        _, _, kept = local_scene(state, constants, HORIZON)
        level = set(window(state, constants))
        for _ in range(LEADER_DEPTH):
            leaders = {lane_leader(state, constants, k, lane) for k in level
                       for lane in (state.lane[0, k], state.target_lane[0, k])}
            level = leaders - {-1}
            assert level <= set(kept)
        _, _, chains = local_scene(state, constants, HORIZON, leader_depth=-1)
        for k in chains[:-1]:
            for lane in (state.lane[0, k], state.target_lane[0, k]):
                assert lane_leader(state, constants, k, lane) in set(chains) | {-1}


def test_observation_at_step_0_is_the_full_scenes(scenes):
    _, states, constants = scenes
    for state in states:
        reduced, reduced_constants, _ = local_scene(state, constants, HORIZON)
        full_observation, local_observation = np.empty((1, 30), np.float32), np.empty((1, 30), np.float32)
        full_phi, local_phi = np.empty(1), np.empty(1)
        engine.observe(state.arrays(), constants, full_observation, full_phi)
        engine.observe(reduced.arrays(), reduced_constants, local_observation, local_phi)
        np.testing.assert_array_equal(local_observation, full_observation)
        assert local_phi[0] == full_phi[0]


def test_reduced_rollout_follows_the_full_ego_trajectory(scenes):
    traffic, states, constants = scenes
    policy = MlpPolicy.random(0)
    deviation, chain_deviation = [], []
    for state in states:
        full = rollout(state, constants, policy, HORIZON)
        local = rollout(*local_scene(state, constants, HORIZON)[:2], policy, HORIZON)
        chains = rollout(*local_scene(state, constants, HORIZON, leader_depth=-1)[:2], policy, HORIZON)
        deviation.append(np.abs(local.ego - full.ego).max())
        chain_deviation.append(np.abs(chains.ego - full.ego).max())
        np.testing.assert_array_equal(local.actions[:, 0], full.actions[:, 0])  # same observation, same action
    deviation = np.array(deviation)
    assert deviation.max() <= EGO_TOLERANCE, f"{traffic}: largest deviation {deviation.max():.3g}"
    assert np.mean(deviation == 0.0) >= (0.1 if traffic == "light" else 0.5), f"{traffic}: {deviation}"
    assert max(chain_deviation) == 0.0  # whole chains: no dropped vehicle reaches the ego's observation


def test_reduced_scene_runs_both_rollout_paths_and_leaves_the_state_alone(scenes):
    _, states, constants = scenes
    state = states[0]
    before = state.copy()
    reduced, reduced_constants, kept = local_scene(state, constants, HORIZON)
    fused = rollout(reduced, reduced_constants, MlpPolicy.random(0), HORIZON, record_others=True)
    generic = rollout(reduced, reduced_constants, lambda obs: MlpPolicy.random(0)(obs), HORIZON)
    np.testing.assert_allclose(generic.ego, fused.ego, atol=1e-9)
    assert fused.others.shape == (1, HORIZON + 1, kept.size - 1, 4)
    for name in ("vehicles", "order", "lane", "ego_rank"):
        np.testing.assert_array_equal(getattr(state, name), getattr(before, name))


def test_compiled_step_cuts_and_rolls_out_as_local_rollout(scenes):
    """SRMPC's compiled step (``CompiledPlannerStep.srmpc``): with ``local`` it simulates exactly
    ``local_scene``'s vehicles and its rollout is ``local_rollout``'s bit for bit; with whole leader chains
    (the bound's exact case) and without ``local`` it is the full rollout's."""
    from srmpc.controller_factory import build_controller

    traffic, states, constants = scenes
    config = to_objects(compose_config([f"+experiment={traffic}_traffic", "tracking.enabled=false",
                                        "controller=srmpc"]))
    controller = build_controller(config, TwinScenarioEnv(config.scenario))
    compiled, policy = controller.planner.compiled_step(), controller.policy
    no_slots = np.full(6, -1, dtype=np.int64)

    def compiled_ego(state: SceneState, local: bool, leader_depth: int = LEADER_DEPTH) -> np.ndarray:
        compiled.srmpc(state, constants, policy, state.vehicles[0, -1].copy(),
                       np.ascontiguousarray(state.vehicles[0, :-1]), no_slots, np.zeros(2),
                       controller.tracking_reference, local=local, leader_depth=leader_depth)
        return compiled.last_rollout()[0][0].copy()

    for state in states[:5]:
        full = rollout(state, constants, policy, HORIZON).ego[0]
        np.testing.assert_array_equal(compiled_ego(state, False), full)
        np.testing.assert_array_equal(compiled.last_kept(), np.arange(constants.vehicles))
        np.testing.assert_array_equal(compiled_ego(state, True),
                                      local_rollout(state, constants, policy, HORIZON).ego[0])
        np.testing.assert_array_equal(compiled.last_kept(), local_scene(state, constants, HORIZON)[2])
        np.testing.assert_array_equal(compiled_ego(state, True, leader_depth=-1), full)


def test_local_rollout_predicts_every_vehicle(scenes):
    """``record_others``: every other vehicle has a trajectory, the simulated ones the reduced rollout's, the
    dropped ones constant speed; every vehicle within the perception range at t = 0 (the observed ones among
    them) is simulated."""
    _, states, constants = scenes
    policy = MlpPolicy.random(0)
    for state in states[:5]:
        reduced, reduced_constants, kept = local_scene(state, constants, HORIZON)
        result = local_rollout(state, constants, policy, HORIZON, record_others=True)
        assert result.others.shape == (1, HORIZON + 1, constants.vehicles - 1, 4)
        simulated = rollout(reduced, reduced_constants, policy, HORIZON, record_others=True)
        np.testing.assert_array_equal(result.others[0][:, kept[:-1]], simulated.others[0])
        dropped = np.setdiff1d(np.arange(constants.vehicles - 1), kept)
        step_s = constants.substeps * constants.dt
        np.testing.assert_array_equal(result.others[0][:, dropped],
                                      constant_speed_others(state.vehicles[0, dropped], HORIZON, step_s))
        in_range = np.abs(state.vehicles[0, :-1, 0] - state.vehicles[0, -1, 0]) <= constants.perception_range
        assert set(np.flatnonzero(in_range)) <= set(kept)


def test_horizon_must_be_positive(scenes):
    _, states, constants = scenes
    with pytest.raises(ValueError, match="horizon"):
        local_scene(states[0], constants, 0)
