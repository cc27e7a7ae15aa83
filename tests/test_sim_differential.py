"""The twin against highway-env, step for step, from the same reset scenes.

For each seed: reset ``SrmpcHighwayEnv``, copy the scene into the twin, apply the same random
action sequence to both, and require at every step the same position, heading and speed of every
vehicle (1e-6 in float64; in practice they agree bit for bit), the same crash flags, termination
step and reason, truncation, and the same observation, r, r', SI cost, event cost and vx.

Default suite: 30 seeds per traffic level on the full scenario (41 vehicles), 100 steps for every
10th seed and 25 for the others (episodes with random actions often end earlier, by collision or
road exit). ``slow``: 500 seeds per level, up to the full 400 steps.
"""

from __future__ import annotations

import numpy as np
import pytest

from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.scenario.observation import closest_lane
from srmpc.scenario.parameters import SafetyIndexKind, SafetyIndexParameters, ScenarioParameters
from srmpc.scenario.spawning import spawn_statistics
from srmpc.sim.simulator import TwinSimulator

STATE_TOLERANCE = 1e-6
"""Largest allowed |twin - highway-env| of x, y [m], heading [rad], speed [m/s]."""
OBSERVATION_TOLERANCE = 1e-6
"""On the normalized float32 observation."""
SCALAR_TOLERANCE = 1e-9
"""On r, r', c, event cost, vx."""
TRAFFIC_GAPS = {"light": 25.0, "dense": 15.0}
"""mean_spawn_gap_m of the paper's two traffic levels [m]."""
STEERING_SCALES = (1.0, 0.1, 0.02)
"""Random steering amplitudes, cycled over seeds: road exits, lane changes, lane keeping."""


def vehicle_table(env: SrmpcHighwayEnv) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4) [x, y, heading, speed] and (N,) crashed of env's vehicles in the twin's storage order."""
    ordered = env.other_vehicles + [env.vehicle]
    states = np.array([[v.position[0], v.position[1], v.heading, v.speed] for v in ordered])
    return states, np.array([v.crashed for v in ordered])


def random_actions(seed: int, steps: int, params: ScenarioParameters) -> np.ndarray:
    """(steps, 2) physical actions, 20% beyond the box on each side (exercises the clipping)."""
    rng = np.random.default_rng(10_000 + seed)
    scale = np.array([params.steering_max_rad * STEERING_SCALES[seed % len(STEERING_SCALES)],
                      params.acceleration_max_mps2])
    return rng.uniform(-1.2, 1.2, (steps, 2)) * scale


def run_differential(env: SrmpcHighwayEnv, seed: int, steps: int, stop_at_end: bool = True) -> dict:
    """Run env and its twin side by side; assert agreement at every step; return the deviations."""
    env.reset(seed=seed)
    twin = TwinSimulator.from_highway_env([env], threads=1)
    states, _ = vehicle_table(env)
    np.testing.assert_array_equal(twin.state.vehicles[0], states)
    actions = random_actions(seed, steps, env.params)
    worst = {"state": 0.0, "observation": 0.0, "scalars": 0.0, "steps": 0, "termination": ""}
    for t, action in enumerate(actions):
        observation, reward, terminated, truncated, info = env.step(action)
        result = twin.step(action[None])
        states, crashed = vehicle_table(env)
        state_error = float(np.abs(twin.state.vehicles[0] - states).max())
        observation_error = float(np.abs(result.observation[0] - observation).max())
        scalar_error = max(
            abs(result.reward[0] - reward),
            abs(result.reward_prime[0] - info["reward_prime"]),
            abs(result.cost[0] - info["cost"]),
            abs(result.event_cost[0] - info["event_cost"]),
            abs(result.vx[0] - info["vx"]),
        )
        where = f"seed {seed}, step {t + 1}"
        assert state_error <= STATE_TOLERANCE, f"{where}: vehicle states differ by {state_error}"
        assert observation_error <= OBSERVATION_TOLERANCE, f"{where}: observations differ by {observation_error}"
        assert scalar_error <= SCALAR_TOLERANCE, f"{where}: r, r', c, event cost or vx differ by {scalar_error}"
        np.testing.assert_array_equal(twin.state.crashed[0], crashed, err_msg=where)
        assert bool(result.terminated[0]) == terminated, where
        assert bool(result.truncated[0]) == truncated, where
        assert result.termination(0) == info["termination"], where
        worst["state"] = max(worst["state"], state_error)
        worst["observation"] = max(worst["observation"], observation_error)
        worst["scalars"] = max(worst["scalars"], scalar_error)
        worst["steps"] = t + 1
        worst["termination"] = info["termination"] or ("truncated" if truncated else "")
        if stop_at_end and (terminated or truncated):
            break
    return worst


def _summarize(label: str, results: list[dict]) -> None:
    reasons = {}
    for r in results:
        reasons[r["termination"] or "running"] = reasons.get(r["termination"] or "running", 0) + 1
    print(
        f"\n{label}: {len(results)} seeds, {sum(r['steps'] for r in results)} steps, endings {reasons}, "
        f"max |state| {max(r['state'] for r in results):.3g}, max |obs| {max(r['observation'] for r in results):.3g}, "
        f"max |r, r', c| {max(r['scalars'] for r in results):.3g}"
    )


@pytest.mark.parametrize("traffic", sorted(TRAFFIC_GAPS))
def test_twin_matches_highway_env_step_for_step(traffic):
    env = SrmpcHighwayEnv(ScenarioParameters(traffic=traffic, mean_spawn_gap_m=TRAFFIC_GAPS[traffic]))
    results = [run_differential(env, seed, steps=100 if seed % 10 == 0 else 25) for seed in range(30)]
    _summarize(traffic, results)
    assert sum(r["termination"] == "collision" for r in results) >= 3  # collisions were exercised


def test_twin_matches_highway_env_with_the_rss_index():
    """The RSS safety index (scenario.safety_index.kind=rss) gives the same SI cost in both, and other costs
    than the paper's index on the same steps."""
    rss = SafetyIndexParameters(kind=SafetyIndexKind.rss)
    results = []
    for traffic, gap in TRAFFIC_GAPS.items():
        env = SrmpcHighwayEnv(ScenarioParameters(traffic=traffic, mean_spawn_gap_m=gap, safety_index=rss))
        results += [run_differential(env, seed, steps=25) for seed in range(10)]
    _summarize("rss", results)
    params = ScenarioParameters(mean_spawn_gap_m=15.0)
    costs = {}
    for kind in SafetyIndexKind:
        env = SrmpcHighwayEnv(ScenarioParameters(mean_spawn_gap_m=15.0,
                                                 safety_index=SafetyIndexParameters(kind=kind)))
        env.reset(seed=3)
        costs[kind] = [env.step(a)[4]["cost"] for a in random_actions(2, 20, params)]
    assert costs[SafetyIndexKind.rss] != costs[SafetyIndexKind.paper]


@pytest.mark.slow
@pytest.mark.parametrize("traffic", sorted(TRAFFIC_GAPS))
def test_twin_matches_highway_env_long(traffic):
    env = SrmpcHighwayEnv(ScenarioParameters(traffic=traffic, mean_spawn_gap_m=TRAFFIC_GAPS[traffic]))
    results = [run_differential(env, seed, steps=400) for seed in range(1000, 1500)]
    _summarize(traffic, results)


def test_twin_matches_highway_env_after_termination():
    """Past the ego's crash both keep simulating: crashed vehicles, impacts, chain collisions."""
    env = SrmpcHighwayEnv(ScenarioParameters(mean_spawn_gap_m=15.0))
    collided = 0
    for seed in range(3):
        run_differential(env, seed=3 * seed + 2, steps=60, stop_at_end=False)
        collided += any(v.crashed for v in env.road.vehicles)
    assert collided >= 1


def twin_spawn_statistics(params: ScenarioParameters, scenes: int, seed: int) -> dict[str, float]:
    """The statistics of ``srmpc.scenario.spawning.spawn_statistics`` over the twin's own resets."""
    twin = TwinSimulator(params, scenes, seed=seed)
    state = twin.state
    gaps, lanes = [], []
    for b in range(scenes):
        rank = state.ego_rank[b]
        road = np.concatenate([state.others[b, :rank], state.ego[b : b + 1], state.others[b, rank:]])
        gaps.append(np.diff(road[:, 0]))
        lanes.append([closest_lane(y) for y in state.others[b, :, 1]])
    gaps = np.concatenate(gaps)
    lane_counts = np.bincount(np.concatenate(lanes), minlength=3)
    return {
        "spawn_gap_mean_m": float(gaps.mean()),
        "spawn_gap_std_m": float(gaps.std()),
        "spawn_gap_min_m": float(gaps.min()),
        "spawn_gap_max_m": float(gaps.max()),
        "other_speed_mean_mps": float(state.others[:, :, 3].mean()),
        "ego_speed_mean_mps": float(state.ego[:, 3].mean()),
        "lane_share": [float(c) for c in lane_counts / lane_counts.sum()],
        "delta_mean": float(state.delta[:, :-1].mean()),
        "vehicles_behind_ego_mean": float((state.others[:, :, 0] < state.ego[:, None, 0]).sum(axis=1).mean()),
    }


@pytest.mark.parametrize("traffic", sorted(TRAFFIC_GAPS))
def test_twin_resets_have_highway_env_statistics(traffic):
    params = ScenarioParameters(traffic=traffic, mean_spawn_gap_m=TRAFFIC_GAPS[traffic])
    reference = spawn_statistics(SrmpcHighwayEnv(params), range(150))
    twin = twin_spawn_statistics(params, scenes=2000, seed=7)
    # 150 x 40 reference gaps: standard error of the mean ~ std / 77
    gap_se = reference["spawn_gap_std_m"] / np.sqrt(150 * 40)
    assert abs(twin["spawn_gap_mean_m"] - reference["spawn_gap_mean_m"]) < 5 * gap_se
    assert twin["spawn_gap_mean_m"] == pytest.approx(params.mean_spawn_gap_m, rel=0.03)
    assert twin["spawn_gap_std_m"] == pytest.approx(reference["spawn_gap_std_m"], rel=0.1)
    slowest = min(params.other_speed_min_mps, params.ego_speed_min_mps)
    assert twin["spawn_gap_min_m"] >= 0.9 * params.spawn_spacing * (12 + slowest) * np.exp(-5 / 40 * 3) - 1e-9
    assert twin["other_speed_mean_mps"] == pytest.approx(reference["other_speed_mean_mps"], abs=0.1)
    assert twin["ego_speed_mean_mps"] == pytest.approx(reference["ego_speed_mean_mps"], abs=0.4)
    np.testing.assert_allclose(twin["lane_share"], reference["lane_share"], atol=0.03)
    np.testing.assert_allclose(twin["lane_share"], [1 / 3] * 3, atol=0.01)
    assert twin["delta_mean"] == pytest.approx(4.0, abs=0.01)
    assert twin["vehicles_behind_ego_mean"] == reference["vehicles_behind_ego_mean"] == params.vehicles_behind_ego
