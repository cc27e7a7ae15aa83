"""Throughput of the twin against highway-env, and the cost of SRMPC's forward rollout.

Writes ``results/benchmarks/sim_throughput.json``:

- ``highway_env_steps_per_s``: ``SrmpcHighwayEnv`` (41 vehicles), a Python loop over B envs;
- ``twin_steps_per_s_1thread`` / ``twin_steps_per_s_all_threads``: ``TwinSimulator.step`` (public
  API, with auto-reset and result copies) on one thread / on all numba threads;
- ``ratio_vs_highway_env``: twin at B = 1024 on one thread over highway-env at B = 1024;
- ``rollout25_ms``: a 25-step forward rollout of a 2x64 tanh MLP from B scenes (fused kernel).

Both simulators get the same kind of actions (no steering, uniform acceleration in [-1, 1] m/s^2,
so most episodes run on) and auto-reset ended episodes. Timings are wall-clock medians over
repeats; the machine's load average is recorded with them.

With ``--previous PATH`` (a checkout of an earlier commit, e.g. ``git worktree add /tmp/main-ref main``)
it also writes ``previous_commit``: this checkout against that one in the same run, on one thread,
``--rounds`` alternating rounds of one worker process per checkout (previous first), each timing the
twin's steps/s at B = 1 and B = 1024, the 25-step rollout from one scene [us] and the per-kernel profile
(:func:`kernel_profile_ns`); reported are the medians over rounds (of each worker's median) and the speedups.

    taskset -c 1 python benchmarks/sim_throughput.py [--quick] [--output PATH] [--previous PATH [--rounds 5]]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.simulator import TwinSimulator

BATCH_SIZES = (1, 64, 1024)
ROLLOUT_BATCH_SIZES = (1, 1000)
ROLLOUT_HORIZON = 25
"""SRMPC's N [control steps]."""


def _actions(rng: np.random.Generator, scenes: int) -> np.ndarray:
    return np.column_stack([np.zeros(scenes), rng.uniform(-1.0, 1.0, scenes)])


def highway_env_steps_per_s(params: ScenarioParameters, scenes: int, min_steps: int) -> float:
    """Steps/s of a Python loop over ``scenes`` highway-env instances (resets of ended episodes included)."""
    envs = [SrmpcHighwayEnv(params) for _ in range(scenes)]
    for i, env in enumerate(envs):
        env.reset(seed=i)
    rng = np.random.default_rng(0)
    rounds = max(1, -(-min_steps // scenes))
    steps = 0
    start = time.perf_counter()
    for _ in range(rounds):
        actions = _actions(rng, scenes)
        for env, action in zip(envs, actions, strict=True):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
            steps += 1
    return steps / (time.perf_counter() - start)


def twin_steps_per_s(params: ScenarioParameters, scenes: int, threads: int | None, min_steps: int,
                     repeats: int) -> float:
    """Median steps/s of ``TwinSimulator.step(..., auto_reset=True)``."""
    sim = TwinSimulator(params, scenes, seed=0, threads=threads)
    rng = np.random.default_rng(0)
    actions = [_actions(rng, scenes) for _ in range(16)]
    for a in actions:  # warm-up (and JIT)
        sim.step(a, auto_reset=True)
    calls = max(4, -(-min_steps // scenes))
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for i in range(calls):
            sim.step(actions[i % 16], auto_reset=True)
        rates.append(calls * scenes / (time.perf_counter() - start))
    return float(np.median(rates))


def rollout_ms(params: ScenarioParameters, scenes: int, policy: MlpPolicy, repeats: int) -> float:
    """Median milliseconds of one ``ROLLOUT_HORIZON``-step rollout of ``policy`` from ``scenes`` scenes."""
    sim = TwinSimulator(params, scenes, seed=1)
    for _ in range(10):
        sim.step(_actions(np.random.default_rng(1), scenes))
    sim.rollout(policy, ROLLOUT_HORIZON)
    inner = 50 if scenes == 1 else 1
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(inner):
            sim.rollout(policy, ROLLOUT_HORIZON)
        times.append((time.perf_counter() - start) / inner * 1e3)
    return float(np.median(times))


COMPARED_BATCH_SIZES = (1, 1024)
"""B of the twin's steps/s in the ``--previous`` comparison."""
PROFILE_SCENES = 64
"""Scenes (after 15 control steps of the 2x64 policy) on which each kernel of the profile is timed."""
PROFILE_REPEATS = 2000
"""Calls of each kernel per scene in the profile."""


def kernel_profile_ns() -> dict[str, float]:
    """Nanoseconds per call and scene of the kernels a control step is made of, each called
    ``PROFILE_REPEATS`` times in a compiled loop on ``PROFILE_SCENES`` real scenes (one thread).

    A control step (``engine.simulate_in``) runs ``sort_by_x`` 4 times and ``all_leaders``, the IDM
    vehicles' act, ``integrate`` + ``apply_impacts`` and ``handle_collisions`` 3 times each (one per
    sub-step); ``measure`` (observation and phi) and, in a rollout, ``mlp_action`` once. The IDM act
    is inlined in ``simulate_in``: ``idm_act_and_rest`` is ``simulate_in`` minus the timed kernels.
    ``integrate`` is timed with a restore of the scene before each call (``restore`` alone subtracted).
    Uses only kernels and signatures that both compared checkouts have.
    """
    from numba import njit

    from srmpc.sim.collision import handle_collisions
    from srmpc.sim.engine import measure, road_ranks, simulate_in, sort_by_x, workspace
    from srmpc.sim.idm import all_leaders
    from srmpc.sim.mlp import mlp_action
    from srmpc.sim.vehicle import apply_impacts, integrate

    @njit
    def prepare(s, w, b):
        road_ranks(s.ego_rank[b], s.vehicles.shape[1], w.rank)
        sort_by_x(s.vehicles[b], s.order[b], w.rank, w.position)

    @njit
    def time_kernel(kernel, s, c, w, repeats, observation, slot_vehicle, raw):
        n = s.vehicles.shape[1]
        for b in range(s.vehicles.shape[0]):
            prepare(s, w, b)
            vehicles, lane, control = s.vehicles[b].copy(), s.lane[b].copy(), s.control[b].copy()
            for _ in range(repeats):
                if kernel == 0:
                    sort_by_x(s.vehicles[b], s.order[b], w.rank, w.position)
                elif kernel == 1:
                    all_leaders(s.vehicles[b], s.order[b], w.position, s.lane[b], s.target_lane[b], c.lane_count,
                                c.lane_width, c.road_length, w.lane_leader, w.target_leader, w.last_on_lane)
                elif kernel == 2 or kernel == 3:
                    s.vehicles[b] = vehicles
                    s.lane[b] = lane
                    s.control[b] = control
                    if kernel == 3:
                        for k in range(n):
                            integrate(s.vehicles[b], s.control[b], s.crashed[b], s.lane[b], k, c.dt, c.lane_count,
                                      c.lane_width, c.road_length)
                        apply_impacts(s.vehicles[b], s.crashed[b], s.impact[b], s.has_impact[b], s.lane[b],
                                      c.lane_count, c.lane_width, c.road_length)
                elif kernel == 4:
                    handle_collisions(s.vehicles[b], s.crashed[b], s.impact[b], s.has_impact[b], s.order[b], w.rank,
                                      c.dt, w.pair_keys, w.poly_a, w.poly_b, w.pair_first, w.pair_second)
                else:
                    measure(s, c, b, observation, slot_vehicle, raw)
            s.vehicles[b] = vehicles
            s.lane[b] = lane
            s.control[b] = control

    @njit
    def time_mlp(observation, w0, b0, w1, b1, w2, b2, low, high, squash, repeats):
        h0, h1, z = np.empty(w0.shape[1]), np.empty(w1.shape[1]), np.empty(w2.shape[1])
        total = 0.0
        for _ in range(repeats):
            total += mlp_action(observation, w0, b0, w1, b1, w2, b2, low, high, squash, h0, h1, z)[0]
        return total

    @njit
    def time_steps(s, c, w, steps):
        for b in range(s.vehicles.shape[0]):
            for _ in range(steps):
                simulate_in(s, c, b, 0.0, 0.0, w)

    params = ScenarioParameters()
    policy = MlpPolicy.random(seed=0, hidden=(64, 64), squash=True)
    sim = TwinSimulator(params, PROFILE_SCENES, seed=3, threads=1)
    for _ in range(15):
        sim.step(policy(sim.observation), auto_reset=True)
    constants, work = sim.constants, workspace(sim.state.vehicle_count, sim.constants.lane_count)
    observation, slot_vehicle, raw = np.empty(30, dtype=np.float32), np.empty(6, dtype=np.int64), np.empty(30)
    names = ("sort_by_x", "all_leaders", "restore", "integrate_and_impacts", "handle_collisions", "measure")
    per_call = {}
    for kernel, name in enumerate(names):
        snapshot = sim.snapshot()
        time_kernel(kernel, sim.state.arrays(), constants, work, 1, observation, slot_vehicle, raw)
        start = time.perf_counter()
        time_kernel(kernel, sim.state.arrays(), constants, work, PROFILE_REPEATS, observation, slot_vehicle, raw)
        per_call[name] = (time.perf_counter() - start) / PROFILE_REPEATS / PROFILE_SCENES * 1e9
        sim.restore(snapshot)
    per_call["integrate_and_impacts"] -= per_call.pop("restore")
    (w0, w1, w2), (b0, b1, b2), low, high, squash = policy.packed
    time_mlp(sim.observation[0], w0, b0, w1, b1, w2, b2, low, high, squash, 1)
    start = time.perf_counter()
    time_mlp(sim.observation[0], w0, b0, w1, b1, w2, b2, low, high, squash, 50 * PROFILE_REPEATS)
    per_call["mlp_action"] = (time.perf_counter() - start) / (50 * PROFILE_REPEATS) * 1e9
    snapshot = sim.snapshot()
    time_steps(sim.state.arrays(), constants, work, 1)
    sim.restore(snapshot)
    start = time.perf_counter()
    time_steps(sim.state.arrays(), constants, work, 20)
    per_call["simulate_in"] = (time.perf_counter() - start) / 20 / PROFILE_SCENES * 1e9
    per_call["idm_act_and_rest"] = per_call["simulate_in"] - (
        4 * per_call["sort_by_x"] + 3 * (per_call["all_leaders"] + per_call["integrate_and_impacts"]
                                         + per_call["handle_collisions"]))
    return {name: round(value, 1) for name, value in per_call.items()}


def compared_worker(quick: bool) -> dict:
    """One round of the ``--previous`` comparison for this process's ``srmpc`` (one thread), with
    :func:`kernel_profile_ns`."""
    numba.set_num_threads(1)
    params = ScenarioParameters()
    min_steps = 2_000 if quick else 30_000
    steps = {str(b): twin_steps_per_s(params, b, 1, min_steps, 3) for b in COMPARED_BATCH_SIZES}
    policy = MlpPolicy.random(seed=0, hidden=(64, 64), squash=True)
    return {"twin_steps_per_s_1thread": steps,
            "rollout25_us_1thread_at_1": rollout_ms(params, 1, policy, 3 if quick else 9) * 1e3,
            "kernel_ns": kernel_profile_ns()}


def compare_with_previous(previous: Path, rounds: int, quick: bool) -> dict:
    """This checkout against ``previous``: alternating worker processes, medians over rounds."""
    here = Path(__file__).resolve()
    checkouts = {"previous": previous.resolve(), "current": here.parents[1]}
    runs: dict[str, list[dict]] = {"previous": [], "current": []}
    for _ in range(rounds):
        for which, checkout in checkouts.items():
            command = [sys.executable, str(here), "--worker"] + (["--quick"] if quick else [])
            output = subprocess.run(command, cwd=checkout, env=dict(os.environ, PYTHONPATH=str(checkout)),
                                    check=True, capture_output=True, text=True)
            runs[which].append(json.loads(output.stdout.strip().splitlines()[-1]))
            print(which, runs[which][-1], flush=True)
    medians = {which: {"twin_steps_per_s_1thread": {str(b): round(statistics.median(
                           r["twin_steps_per_s_1thread"][str(b)] for r in rs)) for b in COMPARED_BATCH_SIZES},
                       "rollout25_us_1thread_at_1": round(statistics.median(
                           r["rollout25_us_1thread_at_1"] for r in rs), 1)}
               for which, rs in runs.items()}
    current, before = medians["current"], medians["previous"]
    commit = subprocess.run(["git", "-C", str(previous), "rev-parse", "HEAD"], capture_output=True, text=True,
                            check=True).stdout.strip()
    return {
        "commit": commit,
        "rounds": rounds,
        "statistic": "median over rounds of each worker's median; workers alternate, previous first",
        "previous": before,
        "current": current,
        "kernel_ns_per_call": {which: {name: round(statistics.median(r["kernel_ns"][name] for r in rs), 1)
                                       for name in rs[0]["kernel_ns"]} for which, rs in runs.items()},
        "speedup": {
            "rollout25_us_1thread_at_1": round(before["rollout25_us_1thread_at_1"]
                                               / current["rollout25_us_1thread_at_1"], 3),
            **{f"steps_per_s_at_{b}": round(current["twin_steps_per_s_1thread"][str(b)]
                                            / before["twin_steps_per_s_1thread"][str(b)], 3)
               for b in COMPARED_BATCH_SIZES},
        },
        "note": "speedup: previous time / current time (rollout), current / previous steps/s (twin); "
                "> 1: this checkout is faster",
        "rounds_raw": runs,
    }


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few steps (a smoke run, not for the record)")
    parser.add_argument("--output", type=Path, default=Path("results/benchmarks/sim_throughput.json"))
    parser.add_argument("--previous", type=Path, help="a checkout of an earlier commit to compare with")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds of the --previous comparison")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(compared_worker(args.quick)))
        return
    params = ScenarioParameters()
    highway_min_steps = 60 if args.quick else 1024
    twin_min_steps = 2_000 if args.quick else 100_000
    repeats = 2 if args.quick else 5
    all_threads = numba.config.NUMBA_NUM_THREADS
    load_before = os.getloadavg()

    highway = {}
    for scenes in BATCH_SIZES:
        highway[scenes] = highway_env_steps_per_s(params, scenes, highway_min_steps)
        print(f"highway-env B={scenes}: {highway[scenes]:.1f} steps/s", flush=True)
    one_thread, every_thread = {}, {}
    numba.set_num_threads(all_threads)
    for scenes in BATCH_SIZES:
        one_thread[scenes] = twin_steps_per_s(params, scenes, 1, twin_min_steps, repeats)
        every_thread[scenes] = twin_steps_per_s(params, scenes, None, twin_min_steps, repeats)
        print(f"twin B={scenes}: {one_thread[scenes]:.0f} steps/s (1 thread), "
              f"{every_thread[scenes]:.0f} ({all_threads} threads)", flush=True)
    policy = MlpPolicy.random(seed=0, hidden=(64, 64), squash=True)
    rollouts, rollouts_1thread = {}, {}
    for scenes in ROLLOUT_BATCH_SIZES:
        rollouts[scenes] = rollout_ms(params, scenes, policy, repeats)
        numba.set_num_threads(1)
        rollouts_1thread[scenes] = rollout_ms(params, scenes, policy, repeats)
        numba.set_num_threads(all_threads)
        print(f"rollout H={ROLLOUT_HORIZON} B={scenes}: {rollouts[scenes]:.3f} ms "
              f"({rollouts_1thread[scenes]:.3f} ms on 1 thread)", flush=True)
    comparison = compare_with_previous(args.previous, args.rounds, args.quick) if args.previous else None
    load_after = os.getloadavg()

    result = {
        "highway_env_steps_per_s": {str(b): round(v, 2) for b, v in highway.items()},
        "twin_steps_per_s_1thread": {str(b): round(v) for b, v in one_thread.items()},
        "twin_steps_per_s_all_threads": {str(b): round(v) for b, v in every_thread.items()},
        "ratio_vs_highway_env": round(one_thread[1024] / highway[1024], 1),
        "rollout25_ms": {str(b): round(v, 4) for b, v in rollouts.items()},
        "rollout25_ms_1thread": {str(b): round(v, 4) for b, v in rollouts_1thread.items()},
        "targets": {"ratio_vs_highway_env": 1000, "twin_steps_per_s_1thread_at_1024": 30000,
                    "rollout25_ms_at_1": 0.5},
        "setup": {
            "scenario": "srmpc/Highway-v0 defaults: 40 IDM vehicles + ego, 15 Hz simulation, 5 Hz control",
            "actions": "steering 0, acceleration U(-1, 1) m/s^2; ended episodes auto-reset (both simulators)",
            "twin_api": "TwinSimulator.step(actions, auto_reset=True), result arrays copied",
            "rollout_policy": "2x64 tanh MLP (random weights), fused numba kernel; all threads for B=1000",
            "statistic": "median of repeats (twin, rollouts); one timed pass (highway-env)",
            "quick": bool(args.quick),
        },
        "machine": {
            "cpu_count": os.cpu_count(),
            "numba_threads": all_threads,
            "numba_threading_layer": numba.threading_layer(),
            "numba": numba.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(),
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in load_after],
            "note": "shared 2-core machine: other engineers' jobs ran at the same time; load averages above",
        },
        "git_commit": _git_commit(),
        "date_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    }
    if comparison is not None:
        result["previous_commit"] = comparison
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
