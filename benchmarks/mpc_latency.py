"""Closed-loop latency of one LTV-MPC step per QP solver, and first-input accuracy.

For each solver, closed-loop episodes on light and dense scenes drive the ego with that solver.
Per step we time the whole controller step (prediction, linearization, QP value update, solve,
plan extraction) and, outside the timing, re-solve the same QP with Clarabel at tight tolerance
(1e-9) to measure the first-input error |u_0 - u_0^Clarabel|_inf.

Scenes: ``srmpc.mpc.synthetic_traffic.SyntheticHighway`` (3 lanes, IDM traffic, exact ego
model), 6 observed vehicles (leader/follower per lane), because the gymnasium env is not yet
wired to this package.

Usage: python benchmarks/mpc_latency.py [--steps 200] [--episodes 2] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from srmpc.mpc import DEFAULT_SOLVER, LtvMpcController, OcpConfig
from srmpc.mpc.solvers import available_solvers, make_solver
from srmpc.mpc.synthetic_traffic import SyntheticHighway

SCENES = {"light": 24.0, "dense": 15.0}
"""Mean spawn spacing [m]: about highway-env density 1 and 1.6 with 3 lanes."""
OTHERS_PER_SCENE = 40
TARGET_MEDIAN_US = 600.0
TARGET_P99_US = 3000.0


def run_solver(name: str, steps: int, episodes: int, config: OcpConfig) -> dict:
    controller = LtvMpcController(config, solver=name)
    reference_solver = make_solver("clarabel")
    step_times, solve_times, errors = [], [], []
    outcome_totals: dict[str, int] = {}
    collisions = 0
    for scene_name, spacing in SCENES.items():
        for episode in range(episodes):
            scene = SyntheticHighway(n_others=OTHERS_PER_SCENE, mean_spacing_m=spacing,
                                     seed=1000 * episode + (0 if scene_name == "light" else 1))
            controller.reset()
            for _ in range(steps):
                ego, others = scene.observe()
                action, report = controller.act(ego, others)
                step_times.append(report.step_time_us)
                solve_times.append(report.solve_time_us)
                if report.plan.outcome.value == "solved":
                    reference = reference_solver.solve(controller.planner.qp)
                    if reference.solved:
                        u0_reference = controller.planner.qp.split_solution(reference.z)[1][0]
                        errors.append(float(np.max(np.abs(action - u0_reference))))
                outcome = scene.step(action)
                if outcome.crashed or outcome.offroad:
                    collisions += 1
                    break
            for key, count in controller.outcome_counts.items():
                outcome_totals[key] = outcome_totals.get(key, 0) + count
    step_times = np.asarray(step_times[3:])  # drop numba/solver warm-up
    return {
        "median_us": float(np.median(step_times)),
        "p90_us": float(np.percentile(step_times, 90)),
        "p99_us": float(np.percentile(step_times, 99)),
        "max_us": float(np.max(step_times)),
        "solve_median_us": float(np.median(solve_times[3:])),
        "u0_err_max": float(np.max(errors)) if errors else None,
        "u0_err_p99": float(np.percentile(errors, 99)) if errors else None,
        "n_steps": int(len(step_times) + 3),
        "outcomes": outcome_totals,
        "episodes_ended_by_collision_or_offroad": collisions,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/mpc_latency.json"))
    args = parser.parse_args()
    config = OcpConfig()
    per_solver = {}
    for name in available_solvers():
        start = time.perf_counter()
        per_solver[name] = run_solver(name, args.steps, args.episodes, config)
        print(f"{name:12s} median {per_solver[name]['median_us']:8.0f} us  "
              f"p90 {per_solver[name]['p90_us']:8.0f}  p99 {per_solver[name]['p99_us']:8.0f}  "
              f"u0_err_max {per_solver[name]['u0_err_max']}  "
              f"({time.perf_counter() - start:.0f} s)", flush=True)
    default = per_solver[DEFAULT_SOLVER]
    result = {
        "default_solver": DEFAULT_SOLVER,
        "per_solver": per_solver,
        "targets": {"median_us": TARGET_MEDIAN_US, "p99_us": TARGET_P99_US,
                    "default_meets_median": default["median_us"] <= TARGET_MEDIAN_US,
                    "default_meets_p99": default["p99_us"] <= TARGET_P99_US},
        "scenes": {
            "source": "srmpc.mpc.synthetic_traffic.SyntheticHighway (own closed-loop scenes; "
                      "the gymnasium env is not yet wired to the planner)",
            "mean_spawn_spacing_m": SCENES,
            "vehicles_per_scene": OTHERS_PER_SCENE,
            "observed_vehicles": config.max_vehicles,
            "episodes_per_scene": args.episodes,
            "steps_per_episode": args.steps,
        },
        "problem": {"horizon": config.horizon, "max_vehicles": config.max_vehicles,
                    "n_ego_circles": config.geometry.n_ego_circles},
        "timing": "whole controller step: prediction + linearization + QP update + solve",
        "u0_reference": "clarabel via qpsolvers, tol_gap_abs = tol_gap_rel = tol_feas = 1e-9",
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                    "python": platform.python_version()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
