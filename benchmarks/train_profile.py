"""Where a training iteration's time goes: this checkout against a previous one, side by side.

    git worktree add /tmp/srmpc-961b49e 961b49e
    taskset -c 1 python benchmarks/train_profile.py --previous /tmp/srmpc-961b49e

For agent=ppo and agent=ppo_lsi (default batch layout: 1024 envs x 32 steps, 4 epochs of 4
minibatches of 8192), runs ``--rounds`` times, alternating, one training process of this checkout
and one of the checkout at ``--previous`` (the trainer as of 961b49e: TorchRL's Collector,
TensorDict minibatches, TorchRL's GAE modules). Each does ``--warmup`` untimed iterations, then
``--iterations`` timed ones, and reports wall seconds per iteration in the sections of
``srmpc.agents.trainer.PROFILE_SECTIONS``: this checkout's from ``Trainer.profile``, the previous
one's from an instrumented copy of its own ``Trainer.update`` loop (:func:`previous_iteration`:
the same calls, with clocks between them). Writes ``results/benchmarks/train_profile.json``: the
per-section medians over rounds of each, and their ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ("collect", "episodes", "advantage", "data", "forward", "backward", "optimizer", "multiplier",
            "diagnostics")


def previous_iteration(trainer, clock=time.perf_counter) -> dict[str, float]:
    """One iteration of the 961b49e trainer (``next(trainer._batches)``, ``episodes.update``,
    ``Trainer.update``'s body), timed by section; the same calls in the same order."""
    import torch

    hp, seconds = trainer.hp, dict.fromkeys(SECTIONS, 0.0)
    started = clock()
    batch = next(trainer._batches)
    lap = clock()
    seconds["collect"] = lap - started
    trainer.episodes.update(batch)
    seconds["episodes"], lap = clock() - lap, clock()
    trainer.loss.compute_advantages(batch)
    seconds["advantage"], lap = clock() - lap, clock()
    flat = batch.reshape(-1)
    seconds["data"] += clock() - lap
    update_multiplier = hp.constrained and (trainer.iteration + 1) % hp.multiplier_update_every == 0
    sums: dict[str, float] = {}
    count = 0
    for _ in range(hp.epochs):
        order = torch.randperm(flat.shape[0], generator=trainer.shuffle)
        for start in range(0, flat.shape[0], hp.minibatch_size):
            lap = clock()
            minibatch = flat[order[start:start + hp.minibatch_size]]
            now = clock()
            seconds["data"] += now - lap
            terms = trainer.loss(minibatch)
            total = sum(v for k, v in terms.items() if k.startswith("loss_"))
            lap, now = now, clock()
            seconds["forward"] += now - lap
            trainer._check_finite({k: v for k, v in terms.items() if k.startswith("loss_")}, "loss term")
            lap, now = now, clock()
            seconds["diagnostics"] += now - lap
            for optimizer in trainer.optimizers.values():
                optimizer.zero_grad(set_to_none=True)
            total.backward()
            lap, now = now, clock()
            seconds["backward"] += now - lap
            torch.nn.utils.clip_grad_norm_(trainer.groups["actor"], hp.max_grad_norm)
            torch.nn.utils.clip_grad_norm_(trainer.groups["critic"], hp.max_grad_norm)
            trainer.optimizers["actor"].step()
            trainer.optimizers["critic"].step()
            lap, now = now, clock()
            seconds["optimizer"] += now - lap
            if update_multiplier and count < hp.multiplier_steps:
                if hp.multiplier_max_grad_norm is not None:
                    torch.nn.utils.clip_grad_norm_(trainer.groups["multiplier"], hp.multiplier_max_grad_norm)
                trainer.optimizers["multiplier"].step()
            lap, now = now, clock()
            seconds["multiplier"] += now - lap
            for k, v in terms.items():
                sums[k] = sums.get(k, 0.0) + float(v.detach())
            seconds["diagnostics"] += clock() - now
            count += 1
    lap = clock()
    trainer._check_finite({k: v for k, v in trainer.loss.named_parameters()}, "parameter")
    seconds["diagnostics"] += clock() - lap
    trainer.iteration += 1
    return seconds


def worker(which: str, agent: str, warmup: int, iterations: int) -> dict[str, float]:
    """Seconds per iteration by section of this process's ``srmpc`` (``which``: current / previous)."""
    from srmpc.agents.trainer import Trainer
    from srmpc.config.compose import compose_config, to_objects
    from srmpc.stages.train import make_training_env

    config = to_objects(compose_config(["stage=train", f"agent={agent}"]))
    with tempfile.TemporaryDirectory() as directory:
        trainer = Trainer(make_training_env(config), config.agent, Path(directory), run=None, progress=False)
        total = dict.fromkeys(SECTIONS, 0.0)
        for iteration in range(warmup + iterations):
            if which == "current":
                trainer.train(max_iterations=1)
                seconds = {k: trainer.profile[k] for k in SECTIONS}
            else:
                seconds = previous_iteration(trainer)
            if iteration >= warmup:
                total = {k: total[k] + seconds[k] / iterations for k in SECTIONS}
        trainer.close()
    total["iteration"] = sum(total.values())
    return total


def run_worker(checkout: Path, which: str, agent: str, args) -> dict[str, float]:
    environment = dict(os.environ, PYTHONPATH=str(checkout))
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", which, "--agent", agent,
               "--warmup", str(args.warmup), "--iterations", str(args.iterations)]
    output = subprocess.run(command, cwd=checkout, env=environment, check=True, capture_output=True, text=True)
    return json.loads(output.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--previous", type=Path, help="a checkout of the trainer to compare with (961b49e)")
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations per process")
    parser.add_argument("--warmup", type=int, default=1, help="untimed iterations first")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/train_profile.json")
    parser.add_argument("--worker", choices=("current", "previous"), help=argparse.SUPPRESS)
    parser.add_argument("--agent", default="ppo", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.agent, args.warmup, args.iterations)))
        return
    if args.previous is None:
        parser.error("--previous is required")
    previous_commit = subprocess.run(["git", "-C", str(args.previous), "rev-parse", "--short", "HEAD"],
                                     capture_output=True, text=True, check=True).stdout.strip()
    result: dict = {
        "previous_commit": previous_commit, "timed_iterations": args.iterations, "rounds": args.rounds,
        "unit": "wall seconds per iteration (32768 env steps), median over rounds",
        "cpu_affinity": sorted(os.sched_getaffinity(0)), "cpu_count": os.cpu_count(),
        "machine": platform.machine(), "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    for agent in ("ppo", "ppo_lsi"):
        runs: dict[str, list[dict[str, float]]] = {"previous": [], "current": []}
        for _ in range(args.rounds):
            runs["previous"].append(run_worker(args.previous.resolve(), "previous", agent, args))
            runs["current"].append(run_worker(ROOT, "current", agent, args))
        medians = {which: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for which, rs in runs.items()}
        medians["previous_over_current"] = {k: medians["previous"][k] / medians["current"][k]
                                            for k in medians["current"] if medians["current"][k] > 0}
        medians["rounds"] = runs
        result[agent] = medians
        print(agent, json.dumps({k: round(v, 3) for k, v in medians["previous_over_current"].items()}))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
