"""Speedup of a sharded evaluation (``evaluation.workers``) over one process, on the same episodes.

    python benchmarks/evaluation_workers.py [--episodes 200] [--workers 2] [hydra overrides]

Composes ``conf/`` (default: SRMPC in light traffic on the twin, ``+experiment=light_traffic
controller=srmpc``, the controller that takes most of the pipeline's evaluation time), runs
one untimed episode in this process (numba's cache, imports), then the same ``--episodes`` episodes
with ``evaluation.workers=1`` and with ``--workers`` worker processes, each into a temporary directory
through ``run_evaluation`` (no MLflow), and checks that the two ``episodes.csv`` are identical. Writes
``results/benchmarks/evaluation_workers.json``: ``sequential_s`` and ``sharded_s`` (wall time of the
whole evaluation; the sharded one includes starting its workers, about 6 s here: importing torch and
loading numba's cache), ``speedup`` = sequential_s / sharded_s, episodes per second of each, and the
core count and load average, since other processes on the same cores make the ratio meaningless.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from srmpc.config.compose import compose_config, to_objects
from srmpc.stages.evaluate import available_cores, run_evaluation
from srmpc.tracking import Run

ROOT = Path(__file__).resolve().parents[1]

DEFAULT_OVERRIDES = ["+experiment=light_traffic", "controller=srmpc"]


def _timed_evaluation(overrides: list[str], episodes: int, workers: int, directory: Path) -> float:
    config = to_objects(compose_config([*overrides, f"evaluation.episodes={episodes}",
                                        f"evaluation.workers={workers}", "tracking.enabled=false"]))
    started = time.perf_counter()
    run_evaluation(config, "benchmark\n", directory, Run(None), progress=False)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=200, help="episodes per evaluation")
    parser.add_argument("--workers", type=int, default=2, help="worker processes of the sharded evaluation")
    parser.add_argument("--output", type=Path, default=ROOT / "results/benchmarks/evaluation_workers.json")
    parser.add_argument("overrides", nargs="*", help=f"Hydra overrides (default: {' '.join(DEFAULT_OVERRIDES)})")
    args = parser.parse_args()
    overrides = args.overrides or DEFAULT_OVERRIDES

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as temporary:
        directory = Path(temporary)
        _timed_evaluation(overrides, 1, 1, directory / "warmup")
        sequential = _timed_evaluation(overrides, args.episodes, 1, directory / "sequential")
        sharded = _timed_evaluation(overrides, args.episodes, args.workers, directory / "sharded")
        identical = ((directory / "sequential" / "episodes.csv").read_text()
                     == (directory / "sharded" / "episodes.csv").read_text())
    result = {
        "speedup": sequential / sharded,
        "sequential_s": sequential,
        "sharded_s": sharded,
        "sequential_episodes_per_s": args.episodes / sequential,
        "sharded_episodes_per_s": args.episodes / sharded,
        "identical_episodes": identical,
        "episodes": args.episodes, "workers": args.workers, "overrides": overrides,
        "available_cores": available_cores(), "cpu_count": os.cpu_count(),
        "load_average_1min_before": load_before[0], "load_average_1min_after": os.getloadavg()[0],
        "machine": platform.machine(), "python": platform.python_version(),
        "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("speedup", "sequential_s", "sharded_s", "identical_episodes",
                                             "load_average_1min_before")}))
    if not identical:
        raise SystemExit("evaluation_workers: the sharded episodes differ from the sequential ones")


if __name__ == "__main__":
    main()
