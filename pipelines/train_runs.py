"""Several trainings side by side: one DVC stage that keeps every core busy.

DVC runs its stages one after another, and a training uses one core (``agent.num_threads=1``,
``agent.sim_threads=1``), so one stage per training would leave the other cores idle. This stage runs
each training as its own ``python -m srmpc stage=train <overrides>`` process, ``--jobs`` at a time
(default: one per available core), in the order given: put the longest first.

Each process is exactly the run one would start by hand, single-threaded, so its results do not depend
on how many run beside it. Its output is printed when it ends, prefixed with its output directory. When
one fails, the others still finish (nothing they did is lost) and this script then exits non-zero, naming
the failed runs. SIGTERM or Ctrl-C is passed on to the running trainings, which save their checkpoint;
a rerun resumes each from ``last.pt`` (finished runs are skipped by the trainer itself).

    python -m pipelines.train_runs --jobs 2 "agent=ppo agent.seed=0 agent.output_dir=..." "agent=..."

With ``SRMPC_FANOUT`` set (``srmpc.fanout``, docs/scaling.md), each training is a job instead, on SLURM or a
local process (``--jobs`` is then the settings' ``max_jobs``): the same command in the job, its output in the
job's log (``<work_dir>/training/<job id>/``), requeued at a time limit after saving ``last.pt``.

Runs are named three ways, combined in this order (DVC's stages name them, conf/ defines them):

- positional: one training's overrides each, e.g. ``"agent=ppo_lsi"``; a run that names its stage
  (``"stage=train_sb3 agent=ppo agent.name=ppo_sb3"``: Stable-Baselines3's PPO) runs that one instead;
- ``--seeds 0 1 2``, after the positional runs (it would take them for seeds): each positional run once per
  seed (``agent.seed=<seed>``; output directory by default ``results/training/<agent>/seed_<seed>``), in the
  order run 1 seed 0, run 1 seed 1, ..., run 2 seed 0;
- ``--experiments GROUP``: one run ``+experiment=GROUP/<name>`` per ``conf/experiment/GROUP/<name>.yaml``,
  in name order. Each experiment file defines its run whole, output directory included.
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

EXPERIMENTS = Path(__file__).resolve().parents[1] / "conf" / "experiment"


@dataclass
class Finished:
    overrides: str
    returncode: int
    wall_s: float
    output: str


def output_dir_of(overrides: str) -> str:
    """The run's ``agent.output_dir`` override, the name it is reported under."""
    for token in shlex.split(overrides):
        if token.startswith("agent.output_dir="):
            return token.split("=", 1)[1]
    return overrides


def expand_runs(runs: list[str], seeds: list[int], experiments: str | None) -> list[str]:
    """The trainings that the positional runs, ``--seeds`` and ``--experiments`` name (module docstring)."""
    expanded = [f"{run} agent.seed={seed}" for run in runs for seed in seeds] if seeds else list(runs)
    if experiments is not None:
        group = EXPERIMENTS / experiments
        names = sorted(path.stem for path in group.glob("*.yaml"))
        if not names:
            raise SystemExit(f"train_runs: --experiments {experiments}: no experiment files in {group}")
        expanded += [f"+experiment={experiments}/{name}" for name in names]
    return expanded


def training_command(overrides: str) -> list[str]:
    """``stage=train <overrides>``, unless the run names its own training stage (``stage=train_sb3 ...``)."""
    tokens = shlex.split(overrides)
    return tokens if any(t.startswith("stage=") for t in tokens) else ["stage=train", *tokens]


def available_cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def run_trainings(runs: list[str], jobs: int, python: str = sys.executable) -> list[Finished]:
    """Run ``python -m srmpc stage=train <overrides>`` for each of ``runs``, ``jobs`` at a time."""
    processes: set[subprocess.Popen] = set()
    stopping = False

    def forward(signum, frame) -> None:  # pass SIGTERM / Ctrl-C on: each training saves its checkpoint
        nonlocal stopping
        stopping = True
        for process in list(processes):
            process.send_signal(signal.SIGTERM)

    previous = {s: signal.signal(s, forward) for s in (signal.SIGTERM, signal.SIGINT)}
    environment = {**os.environ, "TQDM_DISABLE": "1"}  # no progress bars in a shared log

    def one(overrides: str) -> Finished:
        if stopping:
            return Finished(overrides, 128 + signal.SIGTERM, 0.0, "not started: stopped\n")
        started = time.perf_counter()
        process = subprocess.Popen([python, "-m", "srmpc", *training_command(overrides)],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=environment)
        processes.add(process)
        output, _ = process.communicate()
        processes.discard(process)
        finished = Finished(overrides, process.returncode, time.perf_counter() - started, output)
        name = output_dir_of(overrides)
        lines = "".join(f"[{name}] {line}\n" for line in output.rstrip("\n").splitlines())
        print(f"{lines}[{name}] exit {finished.returncode} after {finished.wall_s:.0f} s", flush=True)
        return finished

    try:
        with ThreadPoolExecutor(max(1, jobs)) as pool:
            return list(pool.map(one, runs))
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def run_training_jobs(runs: list[str], settings, python: str = sys.executable) -> list[Finished]:
    """Each of ``runs`` as a job of ``settings`` (``srmpc.fanout.FanoutSettings``); when one fails, the others
    still finish. SIGTERM or Ctrl-C cancels the jobs (SLURM sends them SIGTERM: each saves ``last.pt``)."""
    from srmpc.fanout import CommandJob, run_jobs

    tasks = [CommandJob([python, "-m", "srmpc", *training_command(overrides)], {"TQDM_DISABLE": "1"})
             for overrides in runs]
    finished: list[Finished | None] = [None] * len(runs)
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    try:
        for end in run_jobs(settings, Path(settings.work_dir) / "training", tasks):
            if end is None:
                continue
            name = output_dir_of(runs[end.index])
            status = "exit 0" if end.error is None else f"failed: {end.error}"
            print(f"[{name}] {settings.executor.value} job {end.job_id} {status} after {end.wall_s:.0f} s; "
                  f"log: {end.log}", flush=True)
            finished[end.index] = Finished(runs[end.index], 0 if end.error is None else 1, end.wall_s, str(end.log))
    finally:
        signal.signal(signal.SIGTERM, previous)
    return [f for f in finished if f is not None]


def parse_arguments(argv: list[str] | None = None) -> tuple[list[str], int]:
    """The trainings this command line names (module docstring) and how many to run at once."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", help="one training's overrides each, e.g. 'agent=ppo agent.seed=0'")
    parser.add_argument("--jobs", type=int, default=0, help="trainings at once (0: one per available core)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[], help="each positional run once per seed")
    parser.add_argument("--experiments", default=None, metavar="GROUP",
                        help="one run per conf/experiment/GROUP/*.yaml (+experiment=GROUP/<name>)")
    args = parser.parse_args(argv)
    if args.jobs < 0:
        parser.error(f"--jobs={args.jobs}: must be >= 0 (0: one per available core)")
    if args.seeds and not args.runs:
        parser.error("--seeds: needs at least one positional run to repeat per seed")
    runs = expand_runs(args.runs, args.seeds, args.experiments)
    if not runs:
        parser.error("no trainings named: give runs, --seeds with runs, or --experiments")
    return runs, args.jobs or available_cores()


FANOUT_VARIABLE = "SRMPC_FANOUT"
"""srmpc.fanout.FANOUT_VARIABLE, named here so that a run without it does not import srmpc (2 s)."""


def main() -> None:
    runs, jobs = parse_arguments()
    settings = None
    if os.environ.get(FANOUT_VARIABLE):
        from srmpc.config.compose import ConfigError
        from srmpc.fanout import settings_from_environment

        try:
            settings = settings_from_environment()
        except ConfigError as error:
            raise SystemExit(f"train_runs: {error}") from None
    if settings is None:
        print(f"{len(runs)} trainings, {jobs} at a time", flush=True)
        finished = run_trainings(runs, jobs)
    else:
        print(f"{len(runs)} trainings, {settings.executor.value} jobs, {settings.max_jobs} at a time", flush=True)
        finished = run_training_jobs(runs, settings)
    failed = [f for f in finished if f.returncode != 0]
    if failed:
        names = ", ".join(f"{output_dir_of(f.overrides)} (exit {f.returncode})" for f in failed)
        raise SystemExit(f"train_runs: {len(failed)} of {len(finished)} trainings failed: {names}")


if __name__ == "__main__":
    main()
