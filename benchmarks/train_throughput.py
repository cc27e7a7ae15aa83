"""End-to-end training throughput (collection + GAE + SGD) of PPO-L-SI and PPO, against SB3's PPO.

    taskset -c 1 python benchmarks/train_throughput.py [hydra overrides, e.g. agent.num_envs=512]

Composes ``conf/`` (default: agent=ppo_lsi on the batched simulator), runs ``--warmup`` untimed
iterations (numba compilation, allocator warm-up) and then ``--iterations`` timed ones in a
temporary directory, and writes ``results/benchmarks/train_throughput.json``:
``env_steps_per_s`` (frames / wall time of the timed iterations, everything included),
``collect_steps_per_s`` (collection alone), ``split_s_per_iteration`` (seconds per iteration in each
section of ``srmpc.agents.trainer.PROFILE_SECTIONS``: collection, episode bookkeeping, advantages,
data movement, forward, backward, optimizer, multiplier step, diagnostics) and the settings.

``sb3_comparison`` (skip with ``--no-sb3``): our PPO, our PPO-L-SI and Stable-Baselines3's PPO on
the same batch layout (``agent=ppo`` / ``agent=ppo_lsi`` plus the overrides), one process on one
core, measured in this run, alternating ``--rounds`` times (ours PPO, ours PPO-L-SI, SB3, ...) so
that a change in machine load hits all three: end-to-end env steps per second over the same number
of timed iterations after the same warm-up, their medians over rounds, the ratios of the medians
(``sb3_over_ours``: SB3 / our PPO; ``ours_over_sb3`` and ``ours_ppo_lsi_over_sb3``, the target
being >= 1; per round and the t-interval of their mean over the paired rounds: ``*_per_round``,
``*_ci95``), and each one's split into collection and update (seconds per iteration; SB3's
``collect_rollouts`` and ``train``). The same rates per second of the process's CPU time
(``*_per_cpu_s``, ``*_over_sb3_cpu``) are less disturbed when other processes share the core.
Pin the run to one idle core: ``taskset -c 1 python benchmarks/train_throughput.py``.
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

from srmpc.confidence_intervals import t_interval
from srmpc.config.compose import compose_config, to_objects
from srmpc.sb3_ppo.training import IMPLEMENTATION
from srmpc.stages.train import make_training_env

ROOT = Path(__file__).resolve().parents[1]


def time_ours(config, warmup: int, iterations: int) -> tuple[float, float, dict[str, float], float]:
    """(end-to-end env steps/s, collection env steps/s, seconds per iteration by section, env steps
    per second of this process's CPU time) of our trainer over ``iterations`` after ``warmup``."""
    from srmpc.agents.trainer import PROFILE_SECTIONS, Trainer

    hp = config.agent
    env = make_training_env(config)
    split = dict.fromkeys(PROFILE_SECTIONS, 0.0)

    def add_profile(_metrics: dict) -> None:
        for section in split:
            split[section] += trainer.profile[section] / iterations

    with tempfile.TemporaryDirectory() as directory:
        trainer = Trainer(env, hp, Path(directory), run=None, progress=False)
        trainer.train(max_iterations=warmup)
        rows: list[dict] = []
        started, cpu_started = time.perf_counter(), time.process_time()
        trainer.train(max_iterations=iterations, on_iteration=lambda metrics: (rows.append(metrics),
                                                                                add_profile(metrics)))
        wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
        trainer.close()
    frames = hp.frames_per_batch * iterations
    split["other"] = wall / iterations - sum(split.values())  # metrics, CSV, checkpoints
    return frames / wall, frames / sum(r["collect_s"] for r in rows), split, frames / cpu


def time_sb3(config, warmup: int, iterations: int) -> tuple[float, dict[str, float], float]:
    """(end-to-end env steps/s, seconds per iteration in collect_rollouts / train / the rest, env
    steps per second of CPU time) of Stable-Baselines3's PPO (srmpc.sb3_ppo) over ``iterations``
    after ``warmup``."""
    import torch

    from srmpc.sb3_ppo.training import make_ppo
    from srmpc.sb3_ppo.vec_env import TwinSb3VecEnv

    hp = config.agent
    torch.set_num_threads(hp.num_threads)
    model = make_ppo(TwinSb3VecEnv(config.scenario, hp.num_envs, seed=hp.seed), hp)
    seconds = {"collect": 0.0, "update": 0.0}

    def timed(method, section: str):
        def run(*args, **kwargs):
            started = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                seconds[section] += time.perf_counter() - started
        return run

    model.collect_rollouts = timed(model.collect_rollouts, "collect")
    model.train = timed(model.train, "update")
    model.learn(total_timesteps=warmup * hp.frames_per_batch)
    seconds.update(collect=0.0, update=0.0)
    started, cpu_started = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=iterations * hp.frames_per_batch, reset_num_timesteps=False)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
    split = {k: v / iterations for k, v in seconds.items()}
    split["other"] = wall / iterations - sum(split.values())
    frames = iterations * hp.frames_per_batch
    return frames / wall, split, frames / cpu


def ratios(ours: list[tuple], sb3: list[tuple]) -> list[float]:
    """Env steps/s of ours over SB3's, round by round."""
    return [a[0] / b[0] for a, b in zip(ours, sb3, strict=True)]


def median_split(splits: list[dict[str, float]]) -> dict[str, float]:
    """Section by section median over rounds [s per iteration]."""
    return {k: statistics.median(s[k] for s in splits) for k in splits[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=1, help="untimed iterations first")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds of the SB3 comparison")
    parser.add_argument("--no-sb3", action="store_true", help="skip the comparison with Stable-Baselines3's PPO")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/train_throughput.json")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides")
    args = parser.parse_args()

    config = to_objects(compose_config(["stage=train", *args.overrides]))
    hp = config.agent
    steps_per_s, collect_steps_per_s, split, _ = time_ours(config, args.warmup, args.iterations)
    frames = hp.frames_per_batch * args.iterations
    wall, collect = frames / steps_per_s, frames / collect_steps_per_s
    result = {
        "env_steps_per_s": steps_per_s,
        "collect_steps_per_s": collect_steps_per_s,
        "update_s_per_iteration": (wall - collect) / args.iterations,
        "iteration_s": wall / args.iterations,
        "split_s_per_iteration": split,
        "timed_iterations": args.iterations,
        "task": hp.task.value, "agent": hp.name, "constrained": hp.constrained,
        "num_envs": hp.num_envs, "frames_per_batch": hp.frames_per_batch, "minibatch_size": hp.minibatch_size,
        "epochs": hp.epochs, "hidden_sizes": list(hp.hidden_sizes), "torch_threads": hp.num_threads,
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"), "cpu_count": os.cpu_count(),
        "cpu_affinity": sorted(os.sched_getaffinity(0)),
        "machine": platform.machine(), "python": platform.python_version(),
        "overrides": args.overrides, "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if not args.no_sb3:
        ppo = to_objects(compose_config(["stage=train", "agent=ppo", *args.overrides]))
        ppo_lsi = to_objects(compose_config(["stage=train", "agent=ppo_lsi", *args.overrides]))
        ours, ours_lsi, sb3 = [], [], []
        for _ in range(args.rounds):
            ours.append(time_ours(ppo, args.warmup, args.iterations))
            ours_lsi.append(time_ours(ppo_lsi, args.warmup, args.iterations))
            sb3.append(time_sb3(ppo, args.warmup, args.iterations))
        ours_median = statistics.median(r[0] for r in ours)
        lsi_median = statistics.median(r[0] for r in ours_lsi)
        sb3_median = statistics.median(r[0] for r in sb3)
        cpu = {name: statistics.median(r[-1] for r in runs) for name, runs in
               (("ours", ours), ("ours_ppo_lsi", ours_lsi), ("sb3", sb3))}
        result["sb3_comparison"] = {
            "ours_env_steps_per_s": ours_median, "sb3_env_steps_per_s": sb3_median,
            "sb3_over_ours": sb3_median / ours_median,
            "ours_over_sb3": ours_median / sb3_median,
            "ours_ppo_lsi_env_steps_per_s": lsi_median,
            "ours_ppo_lsi_over_sb3": lsi_median / sb3_median,
            "ours_split_s_per_iteration": median_split([r[2] for r in ours]),
            "ours_ppo_lsi_split_s_per_iteration": median_split([r[2] for r in ours_lsi]),
            "sb3_split_s_per_iteration": median_split([r[1] for r in sb3]),
            "ours_env_steps_per_cpu_s": cpu["ours"], "ours_ppo_lsi_env_steps_per_cpu_s": cpu["ours_ppo_lsi"],
            "sb3_env_steps_per_cpu_s": cpu["sb3"], "ours_over_sb3_cpu": cpu["ours"] / cpu["sb3"],
            "ours_ppo_lsi_over_sb3_cpu": cpu["ours_ppo_lsi"] / cpu["sb3"],
            # Rounds are paired (ours, ours PPO-L-SI and SB3 back to back): the ratio per round and the t-interval
            # of its mean over rounds, so that a verdict on the 1.0x target rests on an interval
            "ours_over_sb3_per_round": ratios(ours, sb3), "ours_over_sb3_ci95": t_interval(ratios(ours, sb3)),
            "ours_ppo_lsi_over_sb3_per_round": ratios(ours_lsi, sb3),
            "ours_ppo_lsi_over_sb3_ci95": t_interval(ratios(ours_lsi, sb3)),
            "ours_rounds": [r[0] for r in ours], "ours_ppo_lsi_rounds": [r[0] for r in ours_lsi],
            "sb3_rounds": [r[0] for r in sb3], "agent": "ppo", "num_envs": ppo.agent.num_envs,
            "frames_per_batch": ppo.agent.frames_per_batch, "minibatch_size": ppo.agent.minibatch_size,
            "epochs": ppo.agent.epochs, "implementation": IMPLEMENTATION,
        }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("env_steps_per_s", "collect_steps_per_s", "iteration_s")}))
    if "sb3_comparison" in result:
        print(json.dumps({k: v for k, v in result["sb3_comparison"].items()
                          if k.endswith(("per_s", "per_cpu_s", "over_ours", "over_sb3", "over_sb3_cpu"))}))


if __name__ == "__main__":
    main()
