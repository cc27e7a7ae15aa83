"""Core-seconds per 1000 episodes of every controller the pipeline evaluates, this code against a previous checkout.

    taskset -c 1 python benchmarks/evaluation_throughput.py --previous ../srmpc-6f31ccf [--episodes 6]

For each cell of :data:`CELLS` (a published experiment and traffic level: lane keeping, the PPO-L-SI policy, LTV-MPC,
SRMPC with its rollout on the whole scene and cut to the horizon, SRMPC's SQP and best-of-two variants, the NMPC from
the rollout), a child process composes the experiment exactly as ``python -m srmpc +experiment=<name>
scenario=<traffic>`` does, builds its scenario and controller once, runs one untimed episode (imports, numba's cache,
allocations) and then the experiment's first ``--episodes`` episodes (seeds ``evaluation.seed + i``, the published
cell's own first episodes) with ``srmpc.episode_loop.evaluate``, timing them by the process's CPU time. So start-up
is left out, and what is measured is what 1000 episodes cost a stage: ``core_s_per_1000_episodes`` = CPU seconds of
the timed episodes / episodes x 1000, also per control step (``cpu_us_per_step``).

With ``--previous DIR`` (a checkout of an earlier commit, e.g. ``git worktree add ../srmpc-6f31ccf 6f31ccf``), the
same child runs that checkout's code (``PYTHONPATH=DIR``) on the same episodes, alternating with this code cell by
cell, so that a change in machine load hits both; ``previous_over_current`` is the ratio (> 1: this code is faster).
Both must give the same episode rows where the code's floats did not change (``rows_equal``). Writes
``results/benchmarks/evaluation_throughput.json``. Pin it to one idle core.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CELLS = (
    ("table/lane_keeping", "dense"),
    ("table/ppo_lsi", "dense"),
    ("table/ltv_mpc", "dense"),
    ("table/srmpc", "dense"),
    ("variants/local_rollout", "dense"),
    ("variants/sqp", "dense"),
    ("variants/best_of_two", "dense"),
    ("nmpc/rollout", "dense"),
)
"""(experiment, traffic): one cell per controller the pipeline evaluates, in dense traffic (the costlier level)."""

CHILD = """
import hashlib, json, sys, time
from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import make_env_and_controller
from srmpc.episode_loop import evaluate
experiment, traffic, episodes = sys.argv[1], sys.argv[2], int(sys.argv[3])
config = to_objects(compose_config([f"+experiment={experiment}", f"scenario={traffic}", "tracking.enabled=false"]))
env, controller = make_env_and_controller(config)
seed = config.evaluation.seed
evaluate(env, controller, 1, seed)  # untimed: imports, numba's cache, allocations
started = time.process_time()
records = evaluate(env, controller, episodes, seed)
cpu_s = time.process_time() - started
rows = repr([(r.episode, r.termination, r.metrics.as_dict()) for r in records])
print(json.dumps({"cpu_s": cpu_s, "steps": sum(r.metrics.n_steps for r in records),
                  "rows_sha256": hashlib.sha256(rows.encode()).hexdigest()}))
"""


def run_child(code_root: Path, experiment: str, traffic: str, episodes: int) -> dict | str:
    """The child's measurement with the code of ``code_root`` (its ``srmpc``), or its last error line (e.g. an
    experiment that the previous checkout does not have)."""
    env = {**os.environ, "PYTHONPATH": str(code_root), "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    result = subprocess.run([sys.executable, "-c", CHILD, experiment, traffic, str(episodes)], cwd=code_root, env=env,
                            capture_output=True, text=True)
    if result.returncode != 0:
        return (result.stderr.strip().splitlines() or ["no output"])[-1]
    return json.loads(result.stdout.strip().splitlines()[-1])


def summary(measured: dict, episodes: int) -> dict:
    return {"core_s_per_1000_episodes": measured["cpu_s"] / episodes * 1000.0,
            "cpu_us_per_step": measured["cpu_s"] / measured["steps"] * 1e6, "steps": measured["steps"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=6, help="timed episodes per cell (after one untimed)")
    parser.add_argument("--previous", type=Path, help="a checkout of an earlier commit to compare against")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/evaluation_throughput.json")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes={args.episodes}: must be >= 1")
    if args.previous is not None and not (args.previous / "srmpc" / "__init__.py").is_file():
        parser.error(f"--previous={args.previous}: not a checkout of this repository (no srmpc/__init__.py)")
    cells = []
    for experiment, traffic in CELLS:
        current = run_child(ROOT, experiment, traffic, args.episodes)
        if isinstance(current, str):
            raise SystemExit(f"{experiment} {traffic}: {current}")
        cell = {"experiment": experiment, "traffic": traffic, "episodes": args.episodes,
                "current": summary(current, args.episodes)}
        if args.previous is not None:
            previous = run_child(args.previous.resolve(), experiment, traffic, args.episodes)
            if isinstance(previous, str):
                cell["previous"] = {"error": previous}
            else:
                cell["previous"] = summary(previous, args.episodes)
                cell["previous_over_current"] = previous["cpu_s"] / current["cpu_s"]
                cell["rows_equal"] = previous["rows_sha256"] == current["rows_sha256"]
        cells.append(cell)
        print(json.dumps(cell))
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    previous_commit = None
    if args.previous is not None:
        previous_commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=args.previous, capture_output=True,
                                         text=True).stdout.strip()
    result = {"cells": cells, "commit": commit, "previous_commit": previous_commit, "episodes_per_cell": args.episodes,
              "unit": "CPU seconds of one process per 1000 episodes, start-up excluded",
              "cpu_affinity": sorted(os.sched_getaffinity(0)), "cpu_count": os.cpu_count(),
              "load_average_1min": os.getloadavg()[0], "machine": platform.machine(),
              "python": platform.python_version(), "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
