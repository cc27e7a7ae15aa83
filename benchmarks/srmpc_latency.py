"""Real-time latency of SRMPC and its variants against LTV-MPC, on the same closed-loop steps, one core.

Writes results/benchmarks/srmpc_latency.json:
``per_controller.<name>.{median_us,p90_us,p99_us,max_us}`` for the whole control step (``act``: scene
copy, policy rollout, prediction, linearization, QP update, solves, plan selection), the breakdown
``{rollout,qp_update,solve}_{median,p99}_us``, the ratio to LTV-MPC in the same run, and whether SRMPC
meets the targets (median <= 1 ms, p99 <= 2 ms). The paper could not measure this at all.

Method: light and dense twin episodes (the committed config, seeds ``1000 e`` / ``1000 e + 1``) are
driven by the paper's SRMPC; at every step each controller (each with its own previous solution)
computes its action from that same scene, in an order that rotates every step. Process pinned to one
core, numba and torch on one thread; the first ``--warmup`` steps of each episode are not timed.
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
from srmpc.controllers.srmpc import SrmpcController
from srmpc.sim.single_env import TwinScenarioEnv
from srmpc.stages.evaluate import build_controller

OUTPUT = Path("results/benchmarks/srmpc_latency.json")
CONTROLLERS = {  # name -> overrides
    "ltv_mpc": ["evaluation.controller=ltv_mpc"],
    "srmpc": ["evaluation.controller=srmpc"],
    "srmpc_best_of_two": ["evaluation.controller=srmpc", "srmpc=best_of_two"],
    "srmpc_rollout_prediction": ["evaluation.controller=srmpc", "srmpc=rollout_prediction"],
    "srmpc_sqp": ["evaluation.controller=srmpc", "srmpc=sqp"],
    "srmpc_track_rollout": ["evaluation.controller=srmpc", "srmpc=track_rollout"],
}
TARGETS_US = {"median_us": 1000.0, "p99_us": 2000.0}
"""SRMPC's real-time targets [us] (benchmark, not test)."""


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
    samples = {name: {"step": [], "rollout": [], "qp_update": [], "solve": []} for name in controllers}
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
            observation, _, terminated, truncated, _ = env.step(actions["srmpc"])
            if terminated or truncated:
                break
    return samples


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4, help="episodes per traffic level")
    parser.add_argument("--steps", type=int, default=200, help="steps per episode at most")
    parser.add_argument("--warmup", type=int, default=5, help="untimed steps at the start of each episode")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    merged: dict[str, dict[str, list[float]]] = {name: {} for name in CONTROLLERS}
    per_traffic = {}
    for traffic in ("light", "dense"):
        samples = run(traffic, args.episodes, args.steps, args.warmup)
        per_traffic[traffic] = {name: percentiles(s["step"]) for name, s in samples.items()}
        for name, series in samples.items():
            for key, values in series.items():
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
        "targets_us": {"srmpc": TARGETS_US},
        "srmpc_meets_targets": per_controller["srmpc"]["meets_targets"],
        "method": __doc__.split("Method: ")[1].strip(),
        "settings": vars(args),
        "machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                    "load_average_1_5_15min_before": list(load_before),
                    "load_average_1_5_15min_after": list(os.getloadavg())},
    }
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    temporary = OUTPUT.with_name(OUTPUT.name + ".tmp")
    temporary.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(temporary, OUTPUT)
    for name, row in per_controller.items():
        print(f"{name:26s} median {row['median_us']:7.0f} us  p90 {row['p90_us']:7.0f}  p99 {row['p99_us']:7.0f}  "
              f"(rollout {row['rollout_median_us']:5.0f}, qp update {row['qp_update_median_us']:5.0f}, "
              f"solve {row['solve_median_us']:5.0f})  x{row['median_ratio_vs_ltv_mpc']:.2f} LTV-MPC")


if __name__ == "__main__":
    main()
