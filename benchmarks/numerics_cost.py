"""What the pinned numeric environment (srmpc.numerics, ``SRMPC_NUMERICS=pinned``) costs, paired in one run.

    taskset -c 1 python benchmarks/numerics_cost.py [--rounds 3] [--iterations 10] [--episodes 20]

Each round runs every task once natively and once pinned, in an order that alternates from round to round, so a
change in the machine's load hits both:

- ``train_ppo_lsi``: PPO-L-SI for ``--iterations`` iterations (32768 frames each, every other setting the
  default), timed by the training loop's own ``wall_s`` (metrics.csv: imports and numba's cache left out);
- ``evaluate_<cell>``: the cell's first ``--episodes`` episodes (dense), timed by the process's CPU time after one
  untimed episode, as benchmarks/evaluation_throughput.py does: the PPO-L-SI policy (numpy: OpenBLAS, NumPy's
  SIMD), SRMPC (numba's rollout and planner; the pin does not reach them).

- ``matmul``: torch's float32 matrix product (MKL's sgemm, one thread) at the networks' shapes in training (a
  batch of 1024 states in collection, a minibatch of 8192 in the update, and the weight gradients' products),
  GFLOP/s per shape and mode: what the pin costs, where it costs.

``per_task.<task>``: the seconds of each round in each mode, ``pinned_over_native`` (mean of the per-round ratios)
with a 95% t-interval over rounds, and whether both modes gave the same bytes (``same_bytes``: they need not).
Writes ``results/benchmarks/numerics_cost.json`` with the CPU model and commit. Pin it to one idle core.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "results" / "benchmarks" / "numerics_cost.json"
FRAMES_PER_ITERATION = 32768
T_975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}
"""Student's t quantile 0.975 by degrees of freedom (rounds - 1)."""

EVALUATION_CELLS = {"evaluate_ppo_lsi": "table/ppo_lsi", "evaluate_srmpc": "table/srmpc"}

CHILD = """
import hashlib, json, sys, time
from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import make_env_and_controller
from srmpc.episode_loop import evaluate
experiment, episodes = sys.argv[1], int(sys.argv[2])
config = to_objects(compose_config([f"+experiment={experiment}", "scenario=dense", "tracking.enabled=false"]))
env, controller = make_env_and_controller(config)
evaluate(env, controller, 1, config.evaluation.seed)  # untimed: imports, numba's cache, allocations
started = time.process_time()
records = evaluate(env, controller, episodes, config.evaluation.seed)
rows = repr([(r.episode, r.termination, r.metrics.as_dict()) for r in records])
print(json.dumps({"seconds": time.process_time() - started, "md5": hashlib.md5(rows.encode()).hexdigest()}))
"""


MATMUL_SHAPES = ((1024, 30, 64), (1024, 64, 64), (1024, 64, 4), (8192, 30, 64), (8192, 64, 64), (8192, 64, 4),
                 (30, 8192, 64), (64, 8192, 64))
"""(m, k, n) of an (m, k) @ (k, n) product: the actor and critics (30 -> 64 -> 64 -> outputs) forward in collection
and update, and a weight gradient's product over the minibatch."""

MATMUL_CHILD = """
import json, sys, time
import srmpc
import torch
torch.set_num_threads(1)
torch.manual_seed(0)
result = {}
for m, k, n in json.loads(sys.argv[1]):
    a, b = torch.randn(m, k), torch.randn(k, n)
    for _ in range(20):
        a @ b
    best = float("inf")
    for _ in range(5):
        started = time.perf_counter()
        for _ in range(50):
            a @ b
        best = min(best, (time.perf_counter() - started) / 50)
    result[f"{m}x{k}x{n}"] = 2 * m * k * n / best / 1e9
print(json.dumps(result))
"""


def _environment(mode: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("SRMPC_NUMERICS")}
    env.update({"SRMPC_NUMERICS": mode, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
    return env


def train(mode: str, iterations: int, folder: Path) -> dict:
    out = folder / f"train_{mode}"
    subprocess.run([sys.executable, "-m", "srmpc", "stage=train", "agent=ppo_lsi",
                    f"agent.total_frames={iterations * FRAMES_PER_ITERATION}", f"agent.output_dir={out}",
                    "tracking.enabled=false"], cwd=ROOT, env=_environment(mode), check=True, capture_output=True)
    last = (out / "metrics.csv").read_text().strip().splitlines()
    wall_column = last[0].split(",").index("wall_s")
    seconds = float(last[-1].split(",")[wall_column])
    digest = hashlib.md5((out / "policy.pt").read_bytes()).hexdigest()
    subprocess.run(["rm", "-rf", str(out)], check=True)
    return {"seconds": seconds, "md5": digest}


def evaluate(mode: str, experiment: str, episodes: int) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, experiment, str(episodes)], cwd=ROOT, env=_environment(mode),
                          check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def matmul(mode: str) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-c", MATMUL_CHILD, json.dumps(MATMUL_SHAPES)], cwd=ROOT,
                          env=_environment(mode), check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def summarize(runs: dict[str, list[dict]]) -> dict:
    ratios = [p["seconds"] / n["seconds"] for n, p in zip(runs["native"], runs["pinned"], strict=True)]
    mean = statistics.fmean(ratios)
    half = T_975[len(ratios) - 1] * statistics.stdev(ratios) / len(ratios) ** 0.5 if len(ratios) > 1 else float("nan")
    return {
        "native_s": [round(r["seconds"], 3) for r in runs["native"]],
        "pinned_s": [round(r["seconds"], 3) for r in runs["pinned"]],
        "pinned_over_native": round(mean, 4),
        "pinned_over_native_ci95": [round(mean - half, 4), round(mean + half, 4)],
        "same_bytes": runs["native"][0]["md5"] == runs["pinned"][0]["md5"],
        "reproducible_within_mode": all(len({r["md5"] for r in runs[m]}) == 1 for m in runs),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    if not 2 <= args.rounds <= 10:
        parser.error(f"--rounds={args.rounds}: must be 2..10 (a t-interval over rounds)")
    tasks = {"train_ppo_lsi": {"native": [], "pinned": []}} | {cell: {"native": [], "pinned": []}
                                                                   for cell in EVALUATION_CELLS}
    with tempfile.TemporaryDirectory() as folder:
        for round_number in range(args.rounds):
            order = ("native", "pinned") if round_number % 2 == 0 else ("pinned", "native")
            for task in tasks:
                for mode in order:
                    result = (train(mode, args.iterations, Path(folder)) if task == "train_ppo_lsi"
                              else evaluate(mode, EVALUATION_CELLS[task], args.episodes))
                    tasks[task][mode].append(result)
                    print(f"round {round_number} {task} {mode}: {result['seconds']:.2f} s", flush=True)
    gflops = {mode: matmul(mode) for mode in ("native", "pinned")}
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    from srmpc.numerics import PINNED_VARIABLES, cpu_summary

    report = {
        "cpu": cpu_summary(), "commit": commit,
        "affinity": sorted(os.sched_getaffinity(0)),
        "rounds": args.rounds, "training_iterations": args.iterations, "evaluation_episodes": args.episodes,
        "pin": PINNED_VARIABLES,
        "per_task": {task: summarize(runs) for task, runs in tasks.items()},
        "matmul_gflops": {shape: {mode: round(gflops[mode][shape], 1) for mode in gflops}
                          for shape in gflops["native"]},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["per_task"], indent=2))


if __name__ == "__main__":
    main()
