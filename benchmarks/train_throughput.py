"""End-to-end training throughput (collection + GAE + SGD) of PPO-L-SI, in env steps per second.

    python benchmarks/train_throughput.py [hydra overrides, e.g. agent=ppo agent.num_envs=512]

Composes ``conf/`` (default: agent=ppo_lsi on the batched simulator), runs ``--warmup`` untimed
iterations (numba compilation, allocator warm-up) and then ``--iterations`` timed ones in a
temporary directory, and writes ``results/benchmarks/train_throughput.json``:
``env_steps_per_s`` (frames / wall time of the timed iterations, everything included),
``collect_steps_per_s`` (collection alone) and the settings that produced them.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from srmpc.config.compose import compose_config, to_objects  # noqa: E402
from srmpc.stages.train import make_training_env  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=1, help="untimed iterations first")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/train_throughput.json")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides")
    args = parser.parse_args()

    config = to_objects(compose_config(["stage=train", *args.overrides]))
    from srmpc.agents.trainer import Trainer

    hp = config.agent
    env = make_training_env(config)
    with tempfile.TemporaryDirectory() as directory:
        trainer = Trainer(env, hp, Path(directory), run=None, progress=False)
        trainer.train(max_iterations=args.warmup)
        rows: list[dict] = []
        started = time.perf_counter()
        trainer.train(max_iterations=args.iterations, on_iteration=rows.append)
        wall = time.perf_counter() - started
        trainer.close()
    frames = hp.frames_per_batch * args.iterations
    collect = sum(r["collect_s"] for r in rows)
    result = {
        "env_steps_per_s": frames / wall,
        "collect_steps_per_s": frames / collect,
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
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("env_steps_per_s", "collect_steps_per_s", "iteration_s")}))


if __name__ == "__main__":
    main()
