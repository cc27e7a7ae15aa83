"""srmpc/Highway-v0: registration, gymnasium API, actions, termination, truncation, spawning."""

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import srmpc
from srmpc.scenario import road
from srmpc.scenario.spawning import spawn_statistics
from tests.conftest import build_scene, make_env


def test_registered_and_passes_check_env():
    env = gymnasium.make(srmpc.SCENARIO_ID)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (30,)
    np.testing.assert_allclose(env.action_space.low, [-0.1, -5.0])
    np.testing.assert_allclose(env.action_space.high, [0.1, 5.0])


def test_renders_rgb_array_frames_of_the_scene(monkeypatch):
    """The frame shows the scenario's road where its geometry puts it: the viewer centres the ego (yellow) at
    ``centering_position``, so the four lane lines (y = -2, 2, 6, 10 m) are drawn ``scaling`` pixels per metre
    above and below it, the road edges solid, the lane separators dashed; the IDM vehicles are blue."""
    from highway_env.vehicle.graphics import VehicleGraphics

    monkeypatch.delenv("SDL_VIDEODRIVER", raising=False)  # =dummy (the Dockerfile's): highway-env draws nothing
    env = gymnasium.make(srmpc.SCENARIO_ID, render_mode="rgb_array")
    env.reset(seed=1)
    env.step(np.zeros(2))
    frame = env.render()
    config, ego = env.unwrapped.config, env.unwrapped.vehicle
    height, width = config["screen_height"], config["screen_width"]
    assert frame.shape == (height, width, 3) == (200, 800, 3) and frame.dtype == np.uint8
    centre_column, centre_row = config["centering_position"][0] * width, config["centering_position"][1] * height
    lines_m = [road.LEFT_ROAD_EDGE + k * road.LANE_WIDTH for k in range(road.LANE_COUNT + 1)]
    expected_rows = [round(centre_row + (y - ego.position[1]) * config["scaling"]) for y in lines_m]
    white = np.all(frame == 255, axis=-1).sum(axis=1)
    assert np.nonzero(white)[0].tolist() == expected_rows  # [45, 67, 89, 111] for the ego on the right lane
    assert white[expected_rows[0]] == white[expected_rows[-1]] == width  # the edges: solid
    assert all(0 < white[row] < 0.8 * width for row in expected_rows[1:-1])  # the separators: dashed
    rows, columns = np.nonzero(np.all(frame == VehicleGraphics.YELLOW, axis=-1))
    # the ego's box, 5 m x 2 m at 5.5 px/m; its centre 2.6 px from the centring point at most (measured)
    assert abs(columns.mean() - centre_column) < 4 and abs(rows.mean() - centre_row) < 4
    assert np.all(frame == VehicleGraphics.BLUE, axis=-1).sum() > 200  # other vehicles


def test_physical_action_reaches_the_vehicle_in_paper_order(env):
    build_scene(env, ego=(100.0, 4.0, 0.0, 20.0), others=[])
    env.step(np.array([0.03, -2.0]))  # (steering, acceleration)
    assert env.vehicle.action["steering"] == pytest.approx(0.03, abs=1e-12)
    assert env.vehicle.action["acceleration"] == pytest.approx(-2.0, abs=1e-12)
    # 3 sub-steps of 1/15 s at -2 m/s^2
    assert env.vehicle.speed == pytest.approx(20.0 - 2.0 * 0.2, abs=1e-9)


def test_out_of_range_action_is_clipped_and_malformed_action_rejected(env):
    build_scene(env, ego=(100.0, 4.0, 0.0, 20.0), others=[])
    env.step(np.array([1.0, 100.0]))
    assert env.vehicle.action["steering"] == pytest.approx(0.1)
    assert env.vehicle.action["acceleration"] == pytest.approx(5.0)
    with pytest.raises(ValueError, match="2 finite floats"):
        env.step(np.array([0.0, np.nan]))


def test_collision_terminates_with_event_cost(env):
    # a stopped vehicle 8 m ahead in the ego's lane, ego at 20 m/s
    build_scene(env, ego=(100.0, 4.0, 0.0, 20.0), others=[(108.0, 4.0, 0.0, 0.0)])
    _, _, terminated, truncated, info = env.step(np.array([0.0, 0.0]))
    assert terminated and not truncated
    assert info["termination"] == "collision" and info["event_cost"] == 1.0 and info["crashed"]


def test_road_exit_terminates_with_event_cost(env):
    build_scene(env, ego=(100.0, 8.0, 0.0, 20.0), others=[])
    for step in range(30):  # noqa: B007
        _, _, terminated, _, info = env.step(np.array([0.1, 0.0]))  # full right steering
        if terminated:
            break
    assert terminated and info["termination"] == "offroad" and info["event_cost"] == 1.0
    assert env.vehicle.position[1] > 10.0  # the centre crossed the right edge
    assert step > 0  # not at once: the ego needed a few steps to reach the edge


def test_truncation_after_400_steps():
    env = make_env(vehicles_count=1, vehicles_behind_ego=1)
    env.reset(seed=0)
    build_scene(env, ego=(100.0, 8.0, 0.0, 25.0), others=[])
    for step in range(1, 401):  # noqa: B007
        _, _, terminated, truncated, info = env.step(np.array([0.0, 0.0]))
        assert not terminated
        if truncated:
            break
    assert step == 400 and truncated and info["event_cost"] == 0.0


def test_reward_on_reference_is_one_and_info_carries_r_prime(env):
    build_scene(env, ego=(100.0, 8.0, 0.0, 25.0), others=[])
    _, reward, _, _, info = env.step(np.zeros(2))
    assert reward == pytest.approx(1.0) and info["reward_prime"] == pytest.approx(0.0)
    build_scene(env, ego=(100.0, 4.0, 0.0, 25.0), others=[])
    _, reward, _, _, info = env.step(np.zeros(2))
    # one lane off: r' = -(1 - g) * 4^2 = -8, r = exp(-8 / 10)
    assert info["reward_prime"] == pytest.approx(-8.0, abs=1e-6)
    assert reward == pytest.approx(np.exp(-0.8), rel=1e-6)


def test_same_seed_same_episode():
    def rollout():
        env = make_env()
        obs, _ = env.reset(seed=7)
        trace = [obs]
        for _ in range(20):
            obs, *_ = env.step(np.array([0.01, 1.0]))
            trace.append(obs)
        return np.array(trace)

    np.testing.assert_array_equal(rollout(), rollout())


def test_other_vehicles_keep_their_lane():
    env = make_env(mean_spawn_gap_m=15.0)
    env.reset(seed=3)
    lanes = [v.lane_index for v in env.other_vehicles]
    assert all(not v.enable_lane_change for v in env.other_vehicles)
    for _ in range(25):
        env.step(np.array([0.0, 0.0]))
    assert [v.lane_index for v in env.other_vehicles] == lanes


def test_spawn_spacing_light_vs_dense():
    light = spawn_statistics(make_env(mean_spawn_gap_m=25.0), range(100))
    dense = spawn_statistics(make_env(mean_spawn_gap_m=15.0), range(100))
    assert light["spawn_gap_mean_m"] == pytest.approx(25.0, abs=0.5)
    assert dense["spawn_gap_mean_m"] == pytest.approx(15.0, abs=0.5)
    for stats in (light, dense):
        assert stats["vehicles_behind_ego_mean"] == 16 and stats["vehicles_ahead_of_ego_mean"] == 24
        assert 21.0 <= stats["other_speed_mean_mps"] <= 24.0
        assert min(stats["lane_share"]) > 0.28  # lanes drawn uniformly
