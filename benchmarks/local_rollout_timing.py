"""Rollout time, full scene against the scene cut to the horizon (``srmpc.sim.local_rollout``); prints, writes nothing.

    taskset -c 1 python benchmarks/local_rollout_timing.py [--scenes 40] [--reps 100]

Scenes: twin scenes 30 control steps after ``reset(seed)`` (seeds 0..scenes-1, lane keeping with a random
acceleration), per traffic level. Each repetition times, interleaved on the same scene (B = 1, 25 steps, the
random 64x64 policy): ``rollout`` on the full scene; ``local_scene`` alone; ``local_scene`` + ``rollout``; and
the fused kernel alone (``_rollout_mlp_serial``: the scene's copy and the outputs are made inside it)
on the full and on the reduced scene. Printed: the median over scenes of each scene's median [us].
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from srmpc.config.compose import compose_config, to_objects
from srmpc.sim.local_rollout import LEADER_DEPTH, local_scene
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.rollout import _rollout_mlp_serial, rollout
from srmpc.sim.single_env import TwinScenarioEnv

HORIZON = 25


def scenes_of(traffic: str, count: int):
    config = to_objects(compose_config([f"+experiment={traffic}_traffic", "tracking.enabled=false"]))
    env = TwinScenarioEnv(config.scenario)
    states = []
    for seed in range(count):
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        for _ in range(30):
            if env.step(np.array([0.0, rng.uniform(-1.0, 1.0)]))[2]:
                break
        states.append(env.simulator.state.copy())
    return states, env.simulator.constants


def kernel_us(state, constants, policy) -> float:
    arrays = state.arrays()
    (w0, w1, w2), (b0, b1, b2), low, high, squash = policy.packed
    start = time.perf_counter()
    _rollout_mlp_serial(arrays, constants, HORIZON, w0, b0, w1, b1, w2, b2, low, high, squash, False)
    return (time.perf_counter() - start) * 1e6


def timed_us(call) -> float:
    start = time.perf_counter()
    call()
    return (time.perf_counter() - start) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--reps", type=int, default=100)
    args = parser.parse_args()
    policy = MlpPolicy.random(0)
    for traffic in ("light", "dense"):
        states, constants = scenes_of(traffic, args.scenes)
        rows = {"full_rollout": [], "local_build": [], "local_build_and_rollout": [], "full_kernel": [],
                "local_kernel": [], "kept": []}
        for state in states:
            reduced, reduced_constants, kept = local_scene(state, constants, HORIZON)
            rows["kept"].append(kept.size)
            per = {key: [] for key in rows if key != "kept"}
            for _ in range(args.reps):
                per["full_rollout"].append(timed_us(lambda s=state, c=constants: rollout(s, c, policy, HORIZON)))
                per["local_build"].append(timed_us(lambda s=state, c=constants: local_scene(s, c, HORIZON)))
                per["local_build_and_rollout"].append(timed_us(
                    lambda s=state, c=constants: rollout(*local_scene(s, c, HORIZON)[:2], policy, HORIZON)))
                per["full_kernel"].append(kernel_us(state, constants, policy))
                per["local_kernel"].append(kernel_us(reduced, reduced_constants, policy))
            for key, values in per.items():
                rows[key].append(np.median(values))
        summary = {key: round(float(np.median(values)), 1) for key, values in rows.items()}
        print(f"{traffic}: vehicles {constants.vehicles}, leader_depth {LEADER_DEPTH}, {summary}")


if __name__ == "__main__":
    main()
