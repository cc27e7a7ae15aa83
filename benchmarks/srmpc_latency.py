"""Real-time latency of SRMPC and its variants against LTV-MPC, on the same closed-loop steps, one core.

Writes results/benchmarks/srmpc_latency.json:
``per_controller.<name>.{median_us,p90_us,p99_us,max_us}`` for the whole control step (``act``: scene
copy, policy rollout, prediction, linearization, QP update, solves, plan selection), the breakdown
``{rollout,qp_update,solve}_{median,p99}_us``, the ratio to LTV-MPC in the same run, and whether SRMPC
meets the original targets (median <= 1 ms, p99 <= 2 ms). ``targets`` holds issue 20's targets (SRMPC
median <= 250 us, p99 <= 500 us, rollout median <= 100 us; LTV-MPC median <= 150 us, p99 <= 300 us)
with ``ratio_to_target`` = measured / limit; ``rollout_vs_highway_env`` times the same 25-step policy
rollout of the same scenes in the twin and in highway-env in this run. The paper could not measure this at all.
``rollout_scope`` sets SRMPC with the full rollout (``srmpc``) against the rollout on the scene cut to the horizon
(``srmpc_local_rollout``, ``controller.srmpc.rollout=local``) per traffic level: the step's and the rollout's
median and p99 and the vehicles the local rollout simulated (of the scene's); ``per_traffic`` has the same
rows for every controller.

Method: light and dense twin episodes (the committed config, seeds ``1000 e`` / ``1000 e + 1``) are
driven by the paper's SRMPC; at every step each controller (each with its own previous solution)
computes its action from that same scene, in an order that rotates every step. Process pinned to one
core, numba and torch on one thread; the first ``--warmup`` steps of each episode are not timed. The
planners run as configured (``riccati_ipm``, warm-started); ``same_qp`` re-solves each QP cold for the
iteration counts.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numba
import numpy as np
import torch

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller
from srmpc.controllers.srmpc import SrmpcController
from srmpc.mpc.solvers import make_solver
from srmpc.output_folder import atomic_write_text
from srmpc.sim.single_env import TwinScenarioEnv

OUTPUT = Path("results/benchmarks/srmpc_latency.json")
CONTROLLERS = {  # name -> overrides
    "ltv_mpc": ["controller=ltv_mpc"],
    "srmpc": ["controller=srmpc"],
    "srmpc_best_of_two": ["controller=srmpc", "controller.srmpc.selection=best_of_two"],
    "srmpc_rollout_prediction": ["controller=srmpc", "controller.srmpc.prediction=policy_rollout"],
    "srmpc_sqp": ["controller=srmpc", "controller.srmpc.relinearizations=2"],
    "srmpc_track_rollout": ["controller=srmpc", "controller.srmpc.tracking=policy_rollout"],
    "srmpc_local_rollout": ["controller=srmpc", "controller.srmpc.rollout=local"],
}
TARGETS_US = {"median_us": 1000.0, "p99_us": 2000.0}
"""SRMPC's original real-time targets [us] (``meets_targets``; benchmark, not test)."""
TARGETS = {  # controller -> row key -> limit [us], one core (issue 20; benchmark, not test)
    "srmpc": {"median_us": 250.0, "p99_us": 500.0, "rollout_median_us": 100.0},
    "srmpc_local_rollout": {"median_us": 250.0, "p99_us": 500.0, "rollout_median_us": 100.0},
    "ltv_mpc": {"median_us": 150.0, "p99_us": 300.0},
}
ROLLOUT_HORIZON = 25
"""SRMPC's N [control steps], the length of the rollout compared against highway-env."""


def percentiles(values: list[float]) -> dict[str, float]:
    array = np.asarray(values)
    return {"median_us": float(np.median(array)), "p90_us": float(np.percentile(array, 90)),
            "p99_us": float(np.percentile(array, 99)), "max_us": float(array.max())}


def breakdown(controller, start: int) -> tuple[float, float, float]:
    """(rollout, qp_update, solve) [us] of the controller's last step."""
    if isinstance(controller, SrmpcController):
        t = controller.last_timing
        return t.rollout_us, t.qp_update_us, t.solve_us
    report = controller.last_report
    return 0.0, report.step_time_us - report.solve_time_us, report.solve_time_us


def run(traffic: str, episodes: int, steps: int, warmup: int) -> dict[str, dict[str, list[float]]]:
    base = [f"+experiment={traffic}_traffic", "tracking.enabled=false"]
    configs = {name: to_objects(compose_config(base + overrides)) for name, overrides in CONTROLLERS.items()}
    env = TwinScenarioEnv(configs["srmpc"].scenario)
    controllers = {name: build_controller(config, env) for name, config in configs.items()}
    samples = {name: {"step": [], "rollout": [], "qp_update": [], "solve": [], "simulated": []} for name in controllers}
    same_qp = {"iterations_warm": [], "iterations_cold": [], "solve_us": [], "piqp_native_us": []}
    same_qp_solvers = {"cold": make_solver("riccati_ipm_cold"), "piqp_native": make_solver("piqp_native")}
    names = list(controllers)
    for episode in range(episodes):
        observation, _ = env.reset(seed=1000 * episode + (traffic == "dense"))
        for controller in controllers.values():
            controller.reset()
        for step in range(steps):
            scene = env.unwrapped.measurement
            actions = {}
            for k in range(len(names)):  # rotate the order so no controller always runs first
                name = names[(step + k) % len(names)]
                start = time.perf_counter()
                actions[name] = controllers[name].act(observation, scene)
                elapsed_us = (time.perf_counter() - start) * 1e6
                if step >= warmup:
                    rollout_us, qp_update_us, solve_us = breakdown(controllers[name], start)
                    for key, value in (("step", elapsed_us), ("rollout", rollout_us), ("qp_update", qp_update_us),
                                       ("solve", solve_us)):
                        samples[name][key].append(value)
                    if isinstance(controllers[name], SrmpcController) and controllers[name].compiled_step():
                        samples[name]["simulated"].append(controllers[name].planner.compiled_step().last_kept().size)
            plan = controllers["srmpc"].last_plan
            if step >= warmup and plan.iterations is not None and plan.reference_source.value == "given":
                record_same_qp(controllers["srmpc"], same_qp_solvers, same_qp)
            observation, _, terminated, truncated, _ = env.step(actions["srmpc"])
            if terminated or truncated:
                break
    samples["srmpc"]["same_qp"] = same_qp
    return samples


def record_same_qp(controller, solvers: dict, record: dict) -> None:
    """SRMPC's solved policy QP re-solved (outside the step timing) cold by riccati_ipm and by piqp_native."""
    qp = controller.planner.qp
    record["iterations_warm"].append(controller.last_plan.iterations)
    record["solve_us"].append(controller.last_timing.solve_us)
    record["iterations_cold"].append(solvers["cold"].solve(qp).iterations)
    start = time.perf_counter()
    solvers["piqp_native"].solve(qp)
    record["piqp_native_us"].append((time.perf_counter() - start) * 1e6)


def rollout_vs_highway_env(scenario, policy, scenes: int, warm_steps: int = 10) -> dict:
    """The twin's N-step policy rollout against highway-env simulating the same scene for N steps.

    Each scene is a highway-env reset (seed s) advanced ``warm_steps`` steps by the policy, copied into
    the twin exactly (``state_from_highway_envs``). Timed: the twin's ``rollout`` (it copies the
    state itself) against ``copy.deepcopy`` of the env and N ``env.step`` calls with the same policy
    acting on highway-env's own observation.
    """
    import copy

    from srmpc.scenario.highway import SrmpcHighwayEnv
    from srmpc.sim.highway_copy import state_from_highway_envs
    from srmpc.sim.rollout import rollout
    from srmpc.sim.simulator import TwinSimulator

    constants = TwinSimulator(scenario, scenes=1, seed=0, threads=1).constants
    twin_us, highway_us = [], []
    for seed in range(scenes):
        env = SrmpcHighwayEnv(scenario)
        observation, _ = env.reset(seed=seed)
        for _ in range(warm_steps):
            observation, _, _, _, _ = env.step(policy(observation[None])[0])
        state = state_from_highway_envs([env])
        rollout(state, constants, policy, ROLLOUT_HORIZON)  # dispatch warm-up
        samples = []
        for _ in range(20):
            start = time.perf_counter()
            rollout(state, constants, policy, ROLLOUT_HORIZON)
            samples.append((time.perf_counter() - start) * 1e6)
        twin_us.append(float(np.median(samples)))
        start = time.perf_counter()
        copied = copy.deepcopy(env)
        obs = observation
        for _ in range(ROLLOUT_HORIZON):
            obs, _, _, _, _ = copied.step(policy(obs[None])[0])
        highway_us.append((time.perf_counter() - start) * 1e6)
        env.close()
    return {"scenes": scenes, "horizon": ROLLOUT_HORIZON, "twin_median_us": float(np.median(twin_us)),
            "highway_env_median_us": float(np.median(highway_us)),
            "highway_env_over_twin": float(np.median(highway_us) / np.median(twin_us))}


def targets(per_controller: dict) -> dict:
    """Each target with the measured value and ratio_to_target = measured / limit (<= 1 meets it)."""
    result = {}
    for name, limits in TARGETS.items():
        row = per_controller[name]
        result[name] = {key: {"limit_us": limit, "measured_us": row[key], "ratio_to_target": row[key] / limit}
                        for key, limit in limits.items()}
    return result


def same_qp_summary(same_qp: dict) -> dict:
    """IPM iterations warm (as run) and cold (the same QPs), and the solve against piqp_native on the same QPs."""
    def stats(values):
        return {"median": float(np.median(values)), "p99": float(np.percentile(values, 99))}
    return {"ipm_iterations_warm": stats(same_qp["iterations_warm"]),
            "ipm_iterations_cold": stats(same_qp["iterations_cold"]),
            "solve_median_us": float(np.median(same_qp["solve_us"])),
            "piqp_native_median_us": float(np.median(same_qp["piqp_native_us"])),
            "solve_over_piqp_native": float(np.median(same_qp["solve_us"]) / np.median(same_qp["piqp_native_us"])),
            "n_qps": len(same_qp["solve_us"])}


def step_and_rollout(series: dict[str, list[float]]) -> dict[str, float]:
    """The step's percentiles and the rollout part's median and p99 [us]."""
    row = percentiles(series["step"])
    row["rollout_median_us"] = float(np.median(series["rollout"]))
    row["rollout_p99_us"] = float(np.percentile(series["rollout"], 99))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4, help="episodes per traffic level")
    parser.add_argument("--steps", type=int, default=200, help="steps per episode at most")
    parser.add_argument("--warmup", type=int, default=5, help="untimed steps at the start of each episode")
    parser.add_argument("--highway-env-scenes", type=int, default=6, help="scenes of the rollout comparison")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    merged: dict[str, dict[str, list[float]]] = {name: {} for name in CONTROLLERS}
    same_qp: dict[str, list[float]] = {}
    per_traffic, rollout_scope = {}, {}
    for traffic in ("light", "dense"):
        samples = run(traffic, args.episodes, args.steps, args.warmup)
        per_traffic[traffic] = {name: step_and_rollout(s) for name, s in samples.items()}
        rollout_scope[traffic] = {
            "full": per_traffic[traffic]["srmpc"], "local": per_traffic[traffic]["srmpc_local_rollout"],
            "vehicles": to_objects(compose_config([f"+experiment={traffic}_traffic"])).scenario.vehicles_count + 1,
            "vehicles_simulated_local_mean": float(np.mean(samples["srmpc_local_rollout"]["simulated"])),
            "vehicles_simulated_local_min_max": [int(np.min(samples["srmpc_local_rollout"]["simulated"])),
                                                 int(np.max(samples["srmpc_local_rollout"]["simulated"]))]}
        for name, series in samples.items():
            for key, values in series.items():
                if key == "simulated":
                    continue
                if key == "same_qp":
                    for part, part_values in values.items():
                        same_qp.setdefault(part, []).extend(part_values)
                else:
                    merged[name].setdefault(key, []).extend(values)
    per_controller = {}
    for name, series in merged.items():
        row = percentiles(series["step"])
        for part in ("rollout", "qp_update", "solve"):
            row[f"{part}_median_us"] = float(np.median(series[part]))
            row[f"{part}_p99_us"] = float(np.percentile(series[part], 99))
        row["n_steps"] = len(series["step"])
        per_controller[name] = row
    baseline = per_controller["ltv_mpc"]
    for row in per_controller.values():
        row["median_ratio_vs_ltv_mpc"] = row["median_us"] / baseline["median_us"]
        row["p99_ratio_vs_ltv_mpc"] = row["p99_us"] / baseline["p99_us"]
        row["meets_targets"] = all(row[key] <= limit for key, limit in TARGETS_US.items())
    result = {
        "per_controller": per_controller,
        "per_traffic": per_traffic,
        "rollout_scope": rollout_scope,
        "targets_us": {"srmpc": TARGETS_US},
        "srmpc_meets_targets": per_controller["srmpc"]["meets_targets"],
        "targets": {**targets(per_controller), "srmpc_same_qps": same_qp_summary(same_qp)},
        "rollout_vs_highway_env": rollout_vs_highway_env(
            to_objects(compose_config(["+experiment=dense_traffic"])).scenario,
            build_controller(to_objects(compose_config(["+experiment=dense_traffic", "tracking.enabled=false",
                                                        *CONTROLLERS["srmpc"]])),
                             TwinScenarioEnv(to_objects(compose_config(["+experiment=dense_traffic"])).scenario)).policy,
            args.highway_env_scenes),
        "method": __doc__.split("Method: ")[1].strip(),
        "settings": vars(args),
        "machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                    "load_average_1_5_15min_before": list(load_before),
                    "load_average_1_5_15min_after": list(os.getloadavg())},
    }
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(OUTPUT, json.dumps(result, indent=2) + "\n")
    print(json.dumps({"targets": result["targets"], "rollout_vs_highway_env": result["rollout_vs_highway_env"],
                      "rollout_scope": rollout_scope}, indent=1))
    for name, row in per_controller.items():
        print(f"{name:26s} median {row['median_us']:7.0f} us  p90 {row['p90_us']:7.0f}  p99 {row['p99_us']:7.0f}  "
              f"(rollout {row['rollout_median_us']:5.0f}, qp update {row['qp_update_median_us']:5.0f}, "
              f"solve {row['solve_median_us']:5.0f})  x{row['median_ratio_vs_ltv_mpc']:.2f} LTV-MPC")


if __name__ == "__main__":
    main()
