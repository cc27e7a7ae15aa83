"""Per-job overhead of the fan-out through a SLURM (``SRMPC_FANOUT``, ``srmpc.fanout``): the model's input.

    python benchmarks/slurm_overhead.py [--trivial 5] [--shard-episodes 50] [--partition cpu]

Needs ``sbatch`` on PATH (``bash ../shared/tools/local_slurm.sh start``: a one-node SLURM on localhost). Runs,
one after another through ``srmpc.fanout.run_jobs`` (the path an evaluation's shards and a training take):

- ``--trivial`` jobs that only return the time they started: ``submit_s`` (sbatch returning),
  ``submit_to_start_s`` (from before sbatch to the job's function starting: SLURM's scheduling, the job
  script, Python starting and unpickling the job), ``start_to_finish_s`` (from the function starting to the
  submitting process seeing its result: the function returns at once, so this is writing the result and
  this process's polling, every ``srmpc.fanout.POLL_S``);
- one real shard: episodes 0 .. ``--shard-episodes``-1 of the published lane-keeping cell in light traffic
  (``+experiment=table/lane_keeping scenario=light``), as ``evaluate_in_jobs`` submits it
  (``srmpc.fanout.EvaluationShard``): ``submit_to_start_s``, ``setup_s`` (imports, the scenario and controller
  built in the job), ``episodes_s`` and ``start_to_finish_s``; its rows are checked against the committed
  ``results/evaluation/table/lane_keeping_light/episodes.csv``.

Writes ``results/benchmarks/slurm_overhead.json`` (every trivial job's numbers, their medians, the shard's),
with the commit, the machine and the load average: one node, so jobs share its cores with everything else.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import statistics
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import make_env_and_controller
from srmpc.fanout import POLL_S, EvaluationShard, Executor, FanoutSettings, complete_rows, run_jobs
from srmpc.output_folder import read_finished_episodes

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "results" / "benchmarks" / "slurm_overhead.json"
CELL = ["+experiment=table/lane_keeping", "scenario=light"]
COMMITTED_ROWS = ROOT / "results" / "evaluation" / "table" / "lane_keeping_light" / "episodes.csv"


def started_at() -> float:
    """The trivial job: the time its function started [s since the epoch]."""
    return time.time()


@dataclass
class TimedShard:
    """An :class:`EvaluationShard` that also reports when its function started and when its episodes began."""

    shard: EvaluationShard

    def __call__(self) -> dict:
        entered = time.time()
        setup = self.shard.setup
        built: list[float] = []

        def timed_setup():
            pair = setup()
            built.append(time.time())
            return pair

        self.shard.setup = timed_setup
        episodes = self.shard()
        return {"entered": entered, "built": built[0], "returned": time.time(), "episodes": episodes}


def _one_job(settings: FanoutSettings, folder: Path, task) -> tuple[float, float, float, object]:
    """(before sbatch, after sbatch, result seen) [s since the epoch] and the job's value."""
    jobs = run_jobs(settings, folder, [task])
    before = time.time()
    end = next(jobs)  # submits, then polls once
    submitted = time.time()
    while end is None:
        end = next(jobs)
    seen = time.time()
    if end.error is not None:
        raise SystemExit(f"slurm_overhead: job {end.job_id} failed: {end.error}; log: {end.log}")
    return before, submitted, seen, end.value


def _load() -> float:
    return os.getloadavg()[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trivial", type=int, default=5, help="trivial jobs, one after another")
    parser.add_argument("--shard-episodes", type=int, default=50, help="episodes of the real shard")
    parser.add_argument("--partition", default="cpu")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="slurm_overhead_", dir=ROOT / ".fanout" if (ROOT / ".fanout").is_dir()
                                 else None))
    settings = FanoutSettings(executor=Executor.slurm, partition=args.partition, shard_episodes=args.shard_episodes,
                              max_jobs=1, mem_gb=2, timeout_min=30, work_dir=str(work))
    load_before = _load()
    trivial = []
    for number in range(args.trivial):
        before, submitted, seen, entered = _one_job(settings, work / f"trivial_{number}", started_at)
        trivial.append({"submit_s": submitted - before, "submit_to_start_s": entered - before,
                        "start_to_finish_s": seen - entered, "submit_to_result_s": seen - before})
    config = to_objects(compose_config([*CELL, "tracking.enabled=false"]))
    shard = EvaluationShard(functools.partial(make_env_and_controller, config), 0, args.shard_episodes,
                            config.evaluation.seed, work / "shard_000000.csv")
    before, _, seen, times = _one_job(settings, work / "shard", TimedShard(shard))
    rows = complete_rows(work / "shard_000000.csv")
    committed = read_finished_episodes(COMMITTED_ROWS)[:args.shard_episodes]
    result = {
        "trivial_jobs": trivial,
        "trivial_median": {key: statistics.median(job[key] for job in trivial) for key in trivial[0]},
        "shard": {"episodes": times["episodes"], "submit_to_start_s": times["entered"] - before,
                  "setup_s": times["built"] - times["entered"], "episodes_s": times["returned"] - times["built"],
                  "start_to_finish_s": seen - times["entered"], "submit_to_result_s": seen - before,
                  "overrides": CELL, "rows_equal_committed": rows == committed},
        "poll_s": POLL_S,
        "slurm": subprocess.run(["sinfo", "--version"], capture_output=True, text=True).stdout.strip(),
        "nodes": subprocess.run(["sinfo", "-h", "-o", "%N %c CPUs %m MB"], capture_output=True,
                                text=True).stdout.strip(),
        "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                 text=True).stdout.strip(),
        "cpu_count": os.cpu_count(),
        "load_average_1min_before": load_before,
        "load_average_1min_after": _load(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    OUTPUT.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({"trivial_median": result["trivial_median"], "shard": result["shard"]}, indent=1))
    if not result["shard"]["rows_equal_committed"]:
        raise SystemExit("slurm_overhead: the shard's rows differ from the committed episodes.csv")


if __name__ == "__main__":
    main()
