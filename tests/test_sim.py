"""The twin's own API: snapshots, rollouts, the MLP, auto-reset, seeding, threads, TorchRL/gym faces,
and hand-built scenes that reach code paths random episodes rarely do (exact x ties, vehicles off
their lane centre, speeds beyond 40 m/s, reversing, the ego first in road order)."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import torch
from highway_env.vehicle.behavior import IDMVehicle
from torchrl.envs.utils import check_env_specs

from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import rollout
from srmpc.sim.simulator import TwinSimulator
from srmpc.sim.torchrl_env import TwinHighwayEnv
from srmpc.sim.vector_env import TwinVectorEnv
from tests.conftest import build_scene, make_env
from tests.test_sim_differential import vehicle_table

PARAMS = ScenarioParameters()


STATE_TOLERANCE = 1e-9
"""Twin vs highway-env state tolerance [m, rad, m/s]: over 1e5 x the largest deviation measured in this file
(3.6e-15), over 8000 x the largest in the differential test's dense traffic (1.1e-13, docs/simulator.md)."""


def _actions(rng: np.random.Generator, scenes: int, steering_scale: float = 0.02) -> np.ndarray:
    return np.column_stack([rng.uniform(-steering_scale, steering_scale, scenes), rng.uniform(-5, 5, scenes)])


def test_snapshot_restore_replays_exactly():
    sim = TwinSimulator(PARAMS, 16, seed=3)
    rng = np.random.default_rng(0)
    for _ in range(10):
        sim.step(_actions(rng, 16))
    snapshot = sim.snapshot()
    actions = [_actions(rng, 16) for _ in range(15)]
    first = [sim.step(a) for a in actions]
    after = sim.state.vehicles.copy()
    sim.restore(snapshot)
    second = [sim.step(a) for a in actions]
    np.testing.assert_array_equal(sim.state.vehicles, after)
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a.observation, b.observation)
        np.testing.assert_array_equal(a.cost, b.cost)


def test_restore_of_some_scenes_only_touches_them():
    sim = TwinSimulator(PARAMS, 4, seed=1)
    snapshot = sim.snapshot()
    sim.step(np.tile([0.0, 3.0], (4, 1)))
    moved = sim.state.vehicles.copy()
    sim.restore(snapshot.take([1, 3]), scenes=[1, 3])
    np.testing.assert_array_equal(sim.state.vehicles[[1, 3]], snapshot.vehicles[[1, 3]])
    np.testing.assert_array_equal(sim.state.vehicles[[0, 2]], moved[[0, 2]])


def test_seeding_is_per_scene_and_reproducible():
    a = TwinSimulator(PARAMS, 8, seed=5)
    b = TwinSimulator(PARAMS, 8, seed=5)
    c = TwinSimulator(PARAMS, 8, seed=6)
    np.testing.assert_array_equal(a.state.vehicles, b.state.vehicles)
    assert not np.array_equal(a.state.vehicles, c.state.vehicles)
    assert len({float(x) for x in a.state.vehicles[:, 0, 0]}) == 8  # scenes differ from each other


def test_parallel_kernel_equals_serial():
    rng = np.random.default_rng(1)
    actions = [_actions(rng, 64, 0.1) for _ in range(30)]
    serial = TwinSimulator(PARAMS, 64, seed=2, threads=1)
    parallel = TwinSimulator(PARAMS, 64, seed=2, threads=max(2, numba.get_num_threads()))
    for a in actions:
        r1 = serial.step(a, auto_reset=True)
        r2 = parallel.step(a, auto_reset=True)
        np.testing.assert_array_equal(r1.observation, r2.observation)
        np.testing.assert_array_equal(r1.terminated, r2.terminated)
    np.testing.assert_array_equal(serial.state.vehicles, parallel.state.vehicles)


def test_auto_reset_respawns_ended_scenes_and_keeps_final_observation():
    sim = TwinSimulator(PARAMS, 6, seed=0)
    hard_right = np.tile([PARAMS.steering_max_rad, 0.0], (6, 1))
    for _ in range(40):
        result = sim.step(hard_right, auto_reset=True)
        ended = result.terminated | result.truncated
        if ended.any():
            break
    assert ended.any()
    assert (sim.state.steps[ended] == 0).all() and (sim.state.steps[~ended] > 0).all()
    assert (result.final_observation[ended] != result.observation[ended]).any()
    np.testing.assert_array_equal(result.final_observation[~ended], result.observation[~ended])
    assert set(result.reason[ended]) <= {2}  # offroad


def test_truncation_after_episode_steps():
    params = ScenarioParameters(episode_steps=5)
    sim = TwinSimulator(params, 2, seed=0)
    for step in range(1, 6):
        result = sim.step(np.zeros((2, 2)))
        assert result.truncated.all() == (step == 5)


def test_rollout_equals_stepping_and_leaves_the_state_alone():
    policy = MlpPolicy.random(seed=3, squash=True)
    sim = TwinSimulator(PARAMS, 5, seed=4)
    before = sim.snapshot()
    predicted = sim.rollout(policy, 25, record_others=True)
    np.testing.assert_array_equal(sim.state.vehicles, before.vehicles)
    assert predicted.ego.shape == (5, 26, 4) and predicted.actions.shape == (5, 25, 2)
    assert predicted.others.shape == (5, 26, PARAMS.vehicles_count, 4)
    ego, costs = [sim.state.ego.copy()], []
    for t in range(25):
        result = sim.step(predicted.actions[:, t])
        ego.append(sim.state.ego.copy())
        costs.append(result.cost)
    np.testing.assert_allclose(np.stack(ego, axis=1), predicted.ego, atol=1e-9)
    np.testing.assert_allclose(np.stack(costs, axis=1), predicted.cost, atol=1e-9)
    # the same policy through the generic (Python-loop) path
    generic = rollout(before, sim.constants, lambda obs: policy(obs), 25)
    np.testing.assert_allclose(generic.ego, predicted.ego, atol=1e-9)
    np.testing.assert_allclose(generic.actions, predicted.actions, atol=1e-9)


def test_parallel_rollout_equals_serial_and_leaves_the_state_alone():
    """The fused kernel over threads (shared work state, one scene per iteration) and on one thread give the
    same bits, and neither writes to the state it starts from."""
    policy = MlpPolicy.random(seed=5, squash=True)
    sim = TwinSimulator(PARAMS, 6, seed=8)
    for _ in range(3):
        sim.step(policy(sim.observation))
    before = sim.snapshot()
    serial = rollout(sim.state, sim.constants, policy, 12, record_others=True, parallel=False)
    threaded = rollout(sim.state, sim.constants, policy, 12, record_others=True, parallel=True)
    for name in ("ego", "actions", "cost", "reward_prime", "terminated", "others"):
        np.testing.assert_array_equal(getattr(threaded, name), getattr(serial, name))
    for name, array in before.arrays()._asdict().items():
        np.testing.assert_array_equal(getattr(sim.state, name), array)


def test_all_leaders_equals_the_scan_of_each_vehicle():
    """The one-sweep leader search against ``leader``'s scan per vehicle and lane, on stepped scenes and on
    the same scenes with an exact x tie (where the sweep hands over to the scan)."""
    from srmpc.sim.engine import road_ranks, sort_by_x, workspace
    from srmpc.sim.idm import all_leaders, leader

    sim = TwinSimulator(PARAMS, 8, seed=11)
    rng = np.random.default_rng(0)
    for _ in range(4):
        sim.step(_actions(rng, 8, steering_scale=0.05))
    c, n = sim.constants, sim.state.vehicle_count
    w = workspace(n, c.lane_count)
    for tie in (False, True):
        for b in range(8):
            vehicles, lane, target_lane = sim.state.vehicles[b].copy(), sim.state.lane[b], sim.state.target_lane[b]
            if tie:
                vehicles[3, 0] = vehicles[17, 0]
            order = np.argsort(vehicles[:, 0], kind="stable")
            road_ranks(sim.state.ego_rank[b], n, w.rank)
            sort_by_x(vehicles, order, w.rank, w.position)
            all_leaders(vehicles, order, w.position, lane, target_lane, c.lane_count, c.lane_width, c.road_length,
                        w.lane_leader, w.target_leader, w.last_on_lane)
            for k in range(n):
                args = (vehicles, order, w.position, k)
                assert w.lane_leader[k] == leader(*args, lane[k], c.lane_width, c.road_length)
                assert w.target_leader[k] == leader(*args, target_lane[k], c.lane_width, c.road_length)


def test_rollout_from_one_scene_repeated():
    """Three copies of one scene roll out as that scene does alone, from its own start, and leave it alone."""
    sim = TwinSimulator(PARAMS, 1, seed=9)
    start = sim.state.vehicles.copy()
    many = sim.state.repeat(3)
    assert many.vehicles.shape == (3, *start.shape[1:])
    result = rollout(many, sim.constants, lambda obs: np.zeros((obs.shape[0], 2)), 10)
    alone = rollout(sim.snapshot(), sim.constants, lambda obs: np.zeros((obs.shape[0], 2)), 10)
    for copy in range(3):
        np.testing.assert_array_equal(result.ego[copy], alone.ego[0])
    np.testing.assert_array_equal(result.ego[:, 0], np.repeat(start[:, -1], 3, axis=0))  # [x, y, heading, speed]
    assert np.all(np.diff(result.ego[0, :, 0]) > 0)  # the ego drives on: the rollout stepped the scene
    np.testing.assert_array_equal(sim.state.vehicles, start)


def test_mlp_numpy_matches_torch_and_numba_path():
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Linear(30, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(), torch.nn.Linear(64, 4)
    ).double()
    policy = MlpPolicy.from_torch(net, squash=False)
    observation = np.random.default_rng(0).normal(size=(7, 30)).astype(np.float32)
    expected = net(torch.from_numpy(observation).double()).detach().numpy()[:, :2]
    np.testing.assert_allclose(policy(observation), expected, atol=1e-12)
    squashed = MlpPolicy.from_torch(net, squash=True)
    np.testing.assert_allclose(squashed(observation), np.array([0.1, 5.0]) * np.tanh(expected), atol=1e-12)


def test_torchrl_env_passes_check_env_specs_and_partial_reset():
    env = TwinHighwayEnv(PARAMS, num_envs=4, seed=0)
    check_env_specs(env)
    td = env.reset()
    before = td["observation"].clone()
    td["action"] = torch.zeros(4, 2)
    td = env.step(td)["next"]
    stepped = td["observation"].clone()
    mask = torch.tensor([[True], [False], [True], [False]])
    reset = env.reset(td.set("_reset", mask))
    assert not torch.equal(reset["observation"][0], stepped[0]) and not torch.equal(reset["observation"][0], before[0])
    torch.testing.assert_close(reset["observation"][1], stepped[1])
    rollout_td = env.rollout(60, break_when_any_done=False)
    for key in ("reward", "cost", "reward_prime", "event_cost", "vx", "done", "terminated", "truncated"):
        assert rollout_td["next", key].shape == (4, 60, 1), key
    assert rollout_td["observation"].dtype == torch.float32


def test_gym_vector_env_is_the_simulator_behind_gymnasiums_api():
    """Each value gymnasium's API returns is the simulator's own (same-step autoreset): none swapped or shifted;
    r = exp(r' / scale); a termination reason exactly where a scene terminated; the ended episode's last
    observation in final_obs, masked by _final_obs."""
    params = ScenarioParameters(episode_steps=20)  # 30 steps: every scene ends at least once
    env = TwinVectorEnv(params, num_envs=3, seed=0)
    assert env.action_space.shape == (3, 2) and env.observation_space.shape == (3, 30)
    simulator = TwinSimulator(params, 3, seed=0, threads=1)
    simulator.seed(1)
    observation, _ = env.reset(seed=1)
    np.testing.assert_array_equal(observation, simulator.reset())
    rng = np.random.default_rng(0)
    ended_scenes = np.zeros(3, dtype=bool)
    for _ in range(30):
        actions = _actions(rng, 3, 0.1)
        observation, reward, terminated, truncated, info = env.step(actions)
        expected = simulator.step(actions, auto_reset=True)
        for got, value in ((observation, expected.observation), (reward, expected.reward),
                           (terminated, expected.terminated), (truncated, expected.truncated),
                           (info["reward_prime"], expected.reward_prime), (info["cost"], expected.cost),
                           (info["event_cost"], expected.event_cost), (info["vx"], expected.vx)):
            np.testing.assert_array_equal(got, value)
        # numba's exp against NumPy's: the largest relative deviation measured 2.0e-16
        np.testing.assert_allclose(reward, np.exp(info["reward_prime"] / params.reward.scale), rtol=1e-12)
        assert [reason != "" for reason in info["termination"]] == terminated.tolist()
        assert set(info["termination"]) <= {"", "collision", "offroad"}
        ended = terminated | truncated
        assert ("_final_obs" in info) == ended.any()
        if ended.any():
            np.testing.assert_array_equal(info["_final_obs"], ended)
            np.testing.assert_array_equal(info["final_obs"][ended], expected.final_observation[ended])
            assert np.isnan(info["final_obs"][~ended]).all()
        ended_scenes |= ended
    assert ended_scenes.all()


def test_copy_rejects_lane_changing_vehicles():
    env = make_env()
    env.reset(seed=0)
    env.other_vehicles[0].enable_lane_change = True
    with pytest.raises(ValueError, match="enable_lane_change"):
        TwinSimulator.from_highway_env([env])


STRESS_SCENES = {
    # ego first in road order, crashing into a stopped vehicle: impacts, crashed dynamics
    "rear_end": ((100.0, 4.0, 0.0, 20.0), [(108.0, 4.0, 0.0, 0.0), (140.0, 0.0, 0.0, 25.0)]),
    # exact x ties between vehicles on overlapping lane margins, an IDM vehicle between lanes
    "ties": ((50.0, 0.0, 0.0, 22.0), [(90.0, 4.0, 0.0, 22.0), (90.0, 6.5, 0.0, 21.0), (90.0, 8.0, 0.0, 23.0),
                                       (60.0, 8.0, 0.0, 24.0), (60.0, 4.0, 0.02, 26.0)]),
    # beyond 40 m/s (clipped), a reversing ego, headings off the lane
    "extremes": ((200.0, 8.0, -0.05, -3.0), [(150.0, 8.0, 0.0, 45.0), (230.0, 1.0, 0.1, 30.0), (220.0, 4.0, 0.0, 0.0)]),
}


@pytest.mark.parametrize("name", sorted(STRESS_SCENES))
def test_hand_built_scenes_match_highway_env(name):
    ego, others = STRESS_SCENES[name]
    env = make_env()
    env.reset(seed=0)
    build_scene(env, ego=ego, others=others)
    for v in env.road.vehicles:
        if isinstance(v, IDMVehicle):
            v.randomize_behavior()
    twin = TwinSimulator.from_highway_env([env], threads=1)
    rng = np.random.default_rng(0)
    for step in range(40):
        action = np.array([rng.uniform(-0.01, 0.01), rng.uniform(-2, 2)])
        _, reward, terminated, _, info = env.step(action)
        result = twin.step(action[None])
        states, crashed = vehicle_table(env)
        np.testing.assert_allclose(twin.state.vehicles[0], states, atol=1e-6, rtol=0, err_msg=f"step {step}")
        np.testing.assert_array_equal(twin.state.crashed[0], crashed)
        assert bool(result.terminated[0]) == terminated and result.termination(0) == info["termination"]
        assert result.cost[0] == pytest.approx(info["cost"], abs=1e-9)


def test_copy_of_several_highway_env_scenes_steps_each_like_its_source():
    envs = [make_env(mean_spawn_gap_m=gap) for gap in (25.0, 15.0, 20.0)]
    for seed, env in enumerate(envs):
        env.reset(seed=seed)
    twin = TwinSimulator.from_highway_env(envs, threads=1)
    rng = np.random.default_rng(5)
    for step in range(15):
        actions = _actions(rng, 3, 0.005)
        for b, env in enumerate(envs):
            env.step(actions[b])
        twin.step(actions)
        for b, env in enumerate(envs):
            states, _ = vehicle_table(env)
            # Not bit for bit on every CPU: on AVX-512 machines NumPy runs highway-env's np.power / np.arcsin /
            # np.arctan in its own SIMD kernels, which differ from glibc's libm (what numba calls) by up to
            # 1 ULP; the largest deviation measured here was 3.6e-15 (a speed of 22.06 m/s). With
            # NPY_DISABLE_CPU_FEATURES="X86_V4,AVX512_ICL,AVX512_SPR" the two agree exactly.
            np.testing.assert_allclose(twin.state.vehicles[b], states, rtol=0, atol=STATE_TOLERANCE,
                                       err_msg=f"scene {b}, step {step}")
