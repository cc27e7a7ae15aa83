"""End-to-end training throughput (collection + GAE + SGD) of PPO-L-SI, in env steps per second.

    python benchmarks/train_throughput.py [hydra overrides, e.g. agent=ppo agent.num_envs=512]

Composes ``conf/`` (default: agent=ppo_lsi on the batched simulator), runs ``--warmup`` untimed
iterations (numba compilation, allocator warm-up) and then ``--iterations`` timed ones in a
temporary directory, and writes ``results/benchmarks/train_throughput.json``:
``env_steps_per_s`` (frames / wall time of the timed iterations, everything included),
``collect_steps_per_s`` (collection alone) and the settings that produced them.

``sb3_comparison`` (skip with ``--no-sb3``): PPO in both implementations on the same batch layout
(``agent=ppo`` plus the overrides), one core each, measured in this run, alternating ``--rounds`` times
(ours, SB3, ours, SB3, ...) so that a change in machine load hits both: end-to-end env steps per second
of our trainer and of Stable-Baselines3's PPO over the same number of timed iterations after the same
warm-up, their medians over rounds, and ``sb3_over_ours``, the ratio of the medians.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from srmpc.config.compose import compose_config, to_objects
from srmpc.sb3_ppo.training import IMPLEMENTATION
from srmpc.stages.train import make_training_env

ROOT = Path(__file__).resolve().parents[1]


def time_ours(config, warmup: int, iterations: int) -> tuple[float, float]:
    """(end-to-end env steps/s, collection env steps/s) of our trainer over ``iterations`` after ``warmup``."""
    from srmpc.agents.trainer import Trainer

    hp = config.agent
    env = make_training_env(config)
    with tempfile.TemporaryDirectory() as directory:
        trainer = Trainer(env, hp, Path(directory), run=None, progress=False)
        trainer.train(max_iterations=warmup)
        rows: list[dict] = []
        started = time.perf_counter()
        trainer.train(max_iterations=iterations, on_iteration=rows.append)
        wall = time.perf_counter() - started
        trainer.close()
    frames = hp.frames_per_batch * iterations
    return frames / wall, frames / sum(r["collect_s"] for r in rows)


def time_sb3(config, warmup: int, iterations: int) -> float:
    """End-to-end env steps/s of Stable-Baselines3's PPO (srmpc.sb3_ppo) over ``iterations`` after ``warmup``."""
    import torch

    from srmpc.sb3_ppo.training import make_ppo
    from srmpc.sb3_ppo.vec_env import TwinSb3VecEnv

    hp = config.agent
    torch.set_num_threads(hp.num_threads)
    model = make_ppo(TwinSb3VecEnv(config.scenario, hp.num_envs, seed=hp.seed), hp)
    model.learn(total_timesteps=warmup * hp.frames_per_batch)
    started = time.perf_counter()
    model.learn(total_timesteps=iterations * hp.frames_per_batch, reset_num_timesteps=False)
    return iterations * hp.frames_per_batch / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=1, help="untimed iterations first")
    parser.add_argument("--rounds", type=int, default=2, help="alternating rounds of the SB3 comparison")
    parser.add_argument("--no-sb3", action="store_true", help="skip the comparison with Stable-Baselines3's PPO")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/train_throughput.json")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides")
    args = parser.parse_args()

    config = to_objects(compose_config(["stage=train", *args.overrides]))
    hp = config.agent
    steps_per_s, collect_steps_per_s = time_ours(config, args.warmup, args.iterations)
    frames = hp.frames_per_batch * args.iterations
    wall, collect = frames / steps_per_s, frames / collect_steps_per_s
    result = {
        "env_steps_per_s": steps_per_s,
        "collect_steps_per_s": collect_steps_per_s,
        "update_s_per_iteration": (wall - collect) / args.iterations,
        "iteration_s": wall / args.iterations,
        "timed_iterations": args.iterations,
        "task": hp.task.value, "agent": hp.name, "constrained": hp.constrained,
        "num_envs": hp.num_envs, "frames_per_batch": hp.frames_per_batch, "minibatch_size": hp.minibatch_size,
        "epochs": hp.epochs, "hidden_sizes": list(hp.hidden_sizes), "torch_threads": hp.num_threads,
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"), "cpu_count": os.cpu_count(),
        "machine": platform.machine(), "python": platform.python_version(),
        "overrides": args.overrides, "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if not args.no_sb3:
        ppo = to_objects(compose_config(["stage=train", "agent=ppo", *args.overrides]))
        ours, sb3 = [], []
        for _ in range(args.rounds):
            ours.append(time_ours(ppo, args.warmup, args.iterations)[0])
            sb3.append(time_sb3(ppo, args.warmup, args.iterations))
        result["sb3_comparison"] = {
            "ours_env_steps_per_s": statistics.median(ours), "sb3_env_steps_per_s": statistics.median(sb3),
            "sb3_over_ours": statistics.median(sb3) / statistics.median(ours),
            "ours_rounds": ours, "sb3_rounds": sb3, "agent": "ppo", "num_envs": ppo.agent.num_envs,
            "frames_per_batch": ppo.agent.frames_per_batch, "minibatch_size": ppo.agent.minibatch_size,
            "epochs": ppo.agent.epochs, "implementation": IMPLEMENTATION,
        }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("env_steps_per_s", "collect_steps_per_s", "iteration_s")}))
    if "sb3_comparison" in result:
        print(json.dumps({k: v for k, v in result["sb3_comparison"].items() if not k.endswith("rounds")}))


if __name__ == "__main__":
    main()
