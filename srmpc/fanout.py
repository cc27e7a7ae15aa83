"""The pipeline's work as jobs (submitit): evaluation shards and trainings, on SLURM or as local processes.

``dvc repro`` runs its stages one after another; inside a stage, the work fans out. By default (nothing
set) it fans out over this machine's cores as it always has (``evaluation.workers``, ``train_runs --jobs``).
The one switch, outside every stage's identity, is the environment variable :data:`FANOUT_VARIABLE`
naming a YAML file of :class:`FanoutSettings` (an untracked file; ``docs/scaling.md``)::

    SRMPC_FANOUT=fanout.yaml dvc repro

Then an evaluation splits its episodes into shards of ``shard_episodes`` (:func:`shard_ranges`), each a
job (:class:`EvaluationShard`), and a training stage submits each training as a job (:class:`CommandJob`),
``executor: slurm`` (sbatch) or ``executor: local`` (a local process through the same path). The entry
points read the switch (:func:`settings_from_environment`); everything here takes plain arguments.

Nothing finished is lost, and nothing is mixed:

- a shard job appends each episode's row to its own file, fsynced; the evaluation's process (the only
  writer of ``episodes.csv``) copies the rows in episode order as they appear (:func:`evaluate_in_jobs`),
  so ``episodes.csv`` stays the contiguous prefix of finished episodes. A rerun resumes it, and each
  shard resumes from its own file: a finished shard is not rerun. Episode i is reset from seed + i
  whichever job runs it, so the rows are the sequential run's.
- a job that reaches its time limit (or is preempted) gets submitit's USR2 ``signal_delay_s`` before it:
  its ``checkpoint()`` saves (a training's SIGTERM path writes ``last.pt``; a shard's rows are on disk)
  and the job is requeued, at most ``max_requeues`` times after a time limit.
- a job that fails ends the stage with one line naming the job and its log (:class:`JobFailed`).
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import getpass
import hashlib
import io
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from enum import Enum
from pathlib import Path

import yaml

from srmpc.config.compose import ConfigError
from srmpc.episode_loop import EpisodeRecord, evaluate, evaluate_in_workers
from srmpc.errors import JobFailed
from srmpc.output_folder import EPISODE_COLUMNS, episode_from_row, episode_row

FANOUT_VARIABLE = "SRMPC_FANOUT"
"""The environment variable that names the fan-out settings file; unset or empty: this machine's cores."""

POLL_S = 1.0
"""How often the submitting process looks for finished jobs and new shard rows [s]."""
QUEUE_CHECK_S = 5.0
"""How often it asks ``squeue`` which jobs are still queued or running [s]."""
MISSING_CHECKS = 3
"""``squeue`` checks in a row that a job may be missing from the queue without its result before it counts
as failed (a result file written on a shared file system shows up late)."""
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
"""Set to a job's ``cpus_per_task`` in its environment."""


class Executor(Enum):
    slurm = "slurm"
    """One SLURM job each (sbatch)."""
    local = "local"
    """One local process each, through submitit's LocalExecutor: the SLURM path without a cluster."""


@dataclass(frozen=True)
class FanoutSettings:
    """The fan-out settings file (:data:`FANOUT_VARIABLE`); every field is a key of that file."""

    executor: Executor = Executor.slurm
    partition: str | None = None
    """sbatch --partition; required with ``executor: slurm``."""
    account: str | None = None
    """sbatch --account, where the cluster bills by account."""
    qos: str | None = None
    shard_episodes: int = 50
    """Episodes per evaluation shard [episodes]: shard k holds episodes k * shard_episodes, ...; the last
    may be shorter."""
    timeout_min: int = 60
    """Time limit of one run of a job [min] (sbatch --time); a job that reaches it is requeued."""
    cpus_per_task: int = 1
    """CPUs per job: a shard runs one episode worker per CPU; a training uses 1 + 1 (agent.num_threads,
    agent.sim_threads)."""
    mem_gb: int = 4
    """Memory per job [GB] (sbatch --mem)."""
    max_jobs: int = 64
    """Jobs of one stage queued or running at once [jobs]."""
    max_requeues: int = 3
    """Requeues after a time limit [count] (preemptions do not count)."""
    signal_delay_s: int = 90
    """submitit's USR2 this long before the time limit [s]: checkpoint, then requeue."""
    work_dir: str = ".fanout"
    """Job scripts, logs and shard rows; on a file system the compute nodes share."""
    setup: tuple[str, ...] = ()
    """Shell lines run before each job (``module load ...``)."""
    python: str = field(default=sys.executable)
    """The interpreter jobs run with (the one that submits them)."""


def _checked(source: str, raw: Mapping) -> FanoutSettings:
    """``raw`` (the file's mapping) as settings; a bad key or value raises ConfigError in one line."""
    known = {f.name: f for f in fields(FanoutSettings)}
    values: dict = {}
    for key, value in raw.items():
        if key not in known:
            raise ConfigError(f"{source}: unknown key '{key}' (known: {', '.join(known)})")
        default = known[key].default
        if key == "executor":
            try:
                value = Executor(value)
            except ValueError:
                choices = ", ".join(e.value for e in Executor)
                raise ConfigError(f"{source}: executor={value!r}: must be one of {choices}") from None
        elif key == "setup":
            if not isinstance(value, list) or not all(isinstance(line, str) for line in value):
                raise ConfigError(f"{source}: setup={value!r}: must be a list of shell lines")
            value = tuple(value)
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int) or value < (0 if key == "max_requeues" else 1):
                raise ConfigError(f"{source}: {key}={value!r}: must be an integer >= "
                                  f"{0 if key == 'max_requeues' else 1}")
        elif not isinstance(value, str) and not (value is None and default is None):
            raise ConfigError(f"{source}: {key}={value!r}: must be a string")
        values[key] = value
    settings = FanoutSettings(**values)
    if settings.executor is Executor.slurm and not settings.partition:
        raise ConfigError(f"{source}: partition: missing (executor: slurm needs a partition)")
    return settings


def read_settings(path: Path, source: str | None = None) -> FanoutSettings:
    """The settings in the YAML file ``path``; ConfigError (one line, naming ``source``) when it is unreadable
    or holds a bad key or value."""
    source = source or str(path)
    try:
        raw = yaml.safe_load(Path(path).read_text())
    except OSError as error:
        raise ConfigError(f"{source}: cannot read it ({error.strerror or error})") from error
    except yaml.YAMLError as error:
        raise ConfigError(f"{source}: not YAML ({str(error).splitlines()[0]})") from error
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: must be a mapping of settings (executor, partition, shard_episodes, ...)")
    return _checked(source, raw)


def settings_from_environment(environ: Mapping[str, str] = os.environ) -> FanoutSettings | None:
    """The settings that :data:`FANOUT_VARIABLE` names, None when it is unset or empty. Raises ConfigError in one
    line for a bad file, a bad value, or ``executor: slurm`` without ``sbatch`` on PATH."""
    path = environ.get(FANOUT_VARIABLE, "")
    if not path:
        return None
    settings = read_settings(Path(path), f"{FANOUT_VARIABLE}={path}")
    if settings.executor is Executor.slurm and shutil.which("sbatch", path=environ.get("PATH")) is None:
        raise ConfigError(f"{FANOUT_VARIABLE}={path}: executor: slurm, but there is no sbatch on PATH")
    return settings


# ---------------------------------------------------------------------------------------------- jobs
@dataclass(frozen=True)
class JobEnd:
    """One job that ended: ``index`` into the submitted tasks; ``error`` None when it succeeded."""

    index: int
    job_id: str
    log: Path
    error: str | None
    value: object = None
    wall_s: float = 0.0
    """From submission to its end, as this process saw it [s]."""


def _executor(settings: FanoutSettings, folder: Path):
    import submitit

    environment = [f"export {name}={settings.cpus_per_task}" for name in THREAD_VARIABLES]
    if settings.executor is Executor.local:
        executor = submitit.LocalExecutor(folder, max_num_timeout=settings.max_requeues)
        executor.update_parameters(timeout_min=settings.timeout_min, signal_delay_s=settings.signal_delay_s,
                                   setup=[*settings.setup, *environment])
        return executor
    executor = submitit.SlurmExecutor(folder, max_num_timeout=settings.max_requeues, python=settings.python)
    parameters = {"partition": settings.partition, "time": settings.timeout_min,
                  "cpus_per_task": settings.cpus_per_task, "mem": f"{settings.mem_gb}GB",
                  "signal_delay_s": settings.signal_delay_s, "setup": [*settings.setup, *environment],
                  "job_name": "srmpc", "additional_parameters": {"open-mode": "append"}}  # a requeue keeps the log
    parameters |= {k: getattr(settings, k) for k in ("account", "qos") if getattr(settings, k)}
    executor.update_parameters(**parameters)
    return executor


def _queued_job_ids() -> set[str] | None:
    """Job ids this user has queued or running (array tasks one by one); None when squeue fails."""
    try:
        listing = subprocess.run(["squeue", "-h", "-r", "-o", "%i", "-u", getpass.getuser()], capture_output=True,
                                 text=True, timeout=60, check=True).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {line.strip() for line in listing.splitlines() if line.strip()}


TRACE_SEPARATOR = "-" * 22
"""The line around the traceback in submitit's FailedJobError message."""


def _last_line(text: str) -> str:
    """The job's exception in one line: the traceback's last line (submitit's FailedJobError puts the trace
    between two :data:`TRACE_SEPARATOR` lines), else the message's last line."""
    parts = text.split(TRACE_SEPARATOR)
    lines = [line.strip() for line in (parts[1] if len(parts) >= 3 else text).splitlines() if line.strip()]
    return lines[-1] if lines else "no message"


def _outcome(job, index: int, started: float) -> JobEnd:
    log = Path(job.paths.stderr)
    wall_s = time.monotonic() - started
    if not job.paths.result_pickle.exists():
        return JobEnd(index, job.job_id, log, "ended without a result (cancelled, killed or out of memory)",
                      wall_s=wall_s)
    try:
        return JobEnd(index, job.job_id, log, None, job.result(), wall_s)
    except Exception as error:  # the job's own exception, pickled with its traceback: its last line
        return JobEnd(index, job.job_id, log, _last_line(str(error)), wall_s=wall_s)


def run_jobs(settings: FanoutSettings, folder: Path, tasks: list[Callable[[], object]]) -> Iterator[JobEnd | None]:
    """Submit ``tasks`` in order, at most ``settings.max_jobs`` queued or running at once; yield each
    :class:`JobEnd` as its job ends (in any order), and None every :data:`POLL_S` without one. Job scripts
    and logs go to ``folder/<job id>/``. Closing the iterator early (an exception, SIGTERM) cancels the jobs
    still queued or running: SLURM sends them SIGTERM (a training saves ``last.pt``)."""
    executor = _executor(settings, Path(folder) / "%j")
    waiting = list(enumerate(tasks))
    running: dict[int, tuple[object, float]] = {}
    missing: dict[int, int] = {}
    last_check = 0.0
    try:
        while waiting or running:
            while waiting and len(running) < settings.max_jobs:
                index, task = waiting.pop(0)
                running[index] = (executor.submit(task), time.monotonic())
            ended = []
            if settings.executor is Executor.local:
                ended = [index for index, (job, _) in running.items() if job.done()]
            else:
                ended = [index for index, (job, _) in running.items() if job.paths.result_pickle.exists()]
                if time.monotonic() - last_check >= QUEUE_CHECK_S:
                    last_check = time.monotonic()
                    queued = _queued_job_ids()
                    for index, (job, _) in running.items():
                        gone = queued is not None and job.job_id not in queued and index not in ended
                        missing[index] = missing.get(index, 0) + 1 if gone else 0
                        if missing[index] >= MISSING_CHECKS:
                            ended.append(index)
            for index in ended:
                job, started = running.pop(index)
                yield _outcome(job, index, started)
            if not ended:
                yield None
                time.sleep(POLL_S)
    finally:
        for job, _ in running.values():
            with contextlib.suppress(Exception):
                job.cancel(check=False)


# ------------------------------------------------------------------------------------- trainings
@dataclass
class CommandJob:
    """A job that runs ``command`` (with ``environment`` added), its output in the job's log. A nonzero exit
    fails the job. At a time limit, ``checkpoint()`` sends the command SIGTERM and waits for it (a training
    saves ``last.pt``); the requeued job runs the command again, which resumes."""

    command: list[str]
    environment: dict[str, str] = field(default_factory=dict)
    _process: subprocess.Popen | None = field(default=None, repr=False, compare=False)

    def __call__(self) -> int:
        sys.stdout.flush()
        self._process = subprocess.Popen(self.command, env={**os.environ, **self.environment},
                                         stderr=subprocess.PIPE, text=True)
        last = ""
        for line in self._process.stderr:  # copied to the job's log; the last line names a failure
            sys.stderr.write(line)
            last = line.strip() or last
        code = self._process.wait()
        if code != 0:
            raise RuntimeError(f"exit {code}: {last or 'no error output'}")
        return code

    def checkpoint(self):
        from submitit.helpers import DelayedSubmission

        if self._process is not None and self._process.poll() is None:
            self._process.send_signal(signal.SIGTERM)
            self._process.wait()
        return DelayedSubmission(CommandJob(self.command, self.environment))

    def __getstate__(self) -> dict:
        return {"command": self.command, "environment": self.environment, "_process": None}


# ------------------------------------------------------------------------------------ evaluations
def shard_ranges(first_episode: int, episodes: int, shard_episodes: int) -> list[tuple[int, int]]:
    """The shards of episodes ``first_episode .. episodes-1``: shard k holds ``[k * shard_episodes, (k + 1) *
    shard_episodes)``, cut to the episodes left; the boundaries stay put when a rerun resumes mid-shard."""
    starts = range(first_episode // shard_episodes * shard_episodes, episodes, shard_episodes)
    return [(max(start, first_episode), min(start + shard_episodes, episodes)) for start in starts
            if max(start, first_episode) < episodes]


def complete_rows(path: Path) -> list[EpisodeRecord]:
    """The whole rows of a shard file (episodes.csv's schema), in file order, stopping at the first that is not
    the next episode; a line still being written (no line end yet) is not read."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    records: list[EpisodeRecord] = []
    for row in csv.DictReader(io.StringIO(text[:text.rfind("\n") + 1])):
        try:
            record = episode_from_row(row)
        except (TypeError, ValueError, KeyError):
            break
        if records and record.episode != records[-1].episode + 1:
            break
        records.append(record)
    return records


def _append(handle, record: EpisodeRecord) -> None:
    csv.writer(handle).writerow(episode_row(record))
    handle.flush()
    os.fsync(handle.fileno())


@dataclass
class EvaluationShard:
    """The job of episodes ``start .. stop-1``: appends each row to ``path``, fsynced, resuming after the rows
    already there (under ``path``'s lock, so a cancelled job still ending cannot write beside its rerun).
    ``setup()`` builds the scenario and controller (``evaluate_in_workers``' setup); ``workers`` > 1 runs the
    episodes in that many processes. Returns the number of episodes it ran."""

    setup: Callable
    start: int
    stop: int
    seed: int
    path: Path
    workers: int = 1

    def __call__(self) -> int:
        signal.signal(signal.SIGTERM, lambda number, frame: sys.exit(128 + number))  # scancel: stop now
        with open(self.path.with_name(self.path.name + ".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            kept = [r for r in complete_rows(self.path) if r.episode >= self.start]
            if kept and kept[0].episode != self.start:
                kept = []
            temporary = self.path.with_name(self.path.name + ".tmp")
            with temporary.open("w", newline="") as handle:  # without a torn tail
                csv.writer(handle).writerow(EPISODE_COLUMNS)
                for record in kept:
                    csv.writer(handle).writerow(episode_row(record))
            os.replace(temporary, self.path)
            first = self.start + len(kept)
            with self.path.open("a", newline="") as handle:
                if self.workers > 1:
                    evaluate_in_workers(self.setup, self.stop, self.seed, self.workers,
                                        lambda r: _append(handle, r), first)
                else:
                    env, controller = self.setup()
                    try:
                        evaluate(env, controller, self.stop, self.seed, lambda r: _append(handle, r), first)
                    finally:
                        env.close()
        return self.stop - first

    def checkpoint(self):
        """At a time limit or preemption: the rows are on disk; the requeued job resumes after them."""
        from submitit.helpers import DelayedSubmission

        return DelayedSubmission(self)


def shard_dir(work_dir: Path, output_dir: Path, identity: str) -> Path:
    """Where the shards of the evaluation into ``output_dir`` with config ``identity`` keep their rows: one
    folder per output directory and identity, so shards of another config are never read."""
    key = hashlib.sha256(f"{Path(output_dir).resolve()}\n{identity}".encode()).hexdigest()[:12]
    return Path(work_dir) / "evaluation" / f"{Path(output_dir).name}-{key}"


def evaluate_in_jobs(
    setup: Callable,
    episodes: int,
    seed: int,
    settings: FanoutSettings,
    rows_dir: Path,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    first_episode: int = 0,
) -> list[EpisodeRecord]:
    """:func:`~srmpc.episode_loop.evaluate`'s episodes ``first_episode .. episodes-1``, one job per shard
    (:func:`shard_ranges`); ``on_episode`` sees them in episode order as their rows appear, so what it writes is
    always the contiguous prefix. Shard files in ``rows_dir`` left by an interrupted run are resumed (a
    complete one is not rerun); they are removed once every row is handed on. A failed job raises
    :class:`JobFailed` after the rows before it were handed on."""
    rows_dir.mkdir(parents=True, exist_ok=True)
    size = settings.shard_episodes
    shards = [(start, stop, rows_dir / f"shard_{start // size:06d}.csv")
              for start, stop in shard_ranges(first_episode, episodes, size)]
    planned = {path.name for _, _, path in shards}
    for stale in rows_dir.glob("shard_*.csv"):
        if stale.name not in planned:  # its rows are in episodes.csv already
            stale.unlink()
    complete = {i for i, (start, stop, path) in enumerate(shards)
                if [r.episode for r in complete_rows(path) if r.episode >= start] == list(range(start, stop))}
    todo = [i for i in range(len(shards)) if i not in complete]
    tasks = [EvaluationShard(setup, shards[i][0], shards[i][1], seed, shards[i][2], settings.cpus_per_task)
             for i in todo]
    records: list[EpisodeRecord] = []
    state = {"next": first_episode, "shard": 0}

    def hand_on() -> None:
        while state["shard"] < len(shards):
            start, stop, path = shards[state["shard"]]
            for record in complete_rows(path):
                if record.episode == state["next"]:
                    records.append(record)
                    if on_episode is not None:
                        on_episode(record)
                    state["next"] += 1
            if state["next"] < stop:
                return
            state["shard"] += 1

    for end in run_jobs(settings, rows_dir / "jobs", tasks):
        if end is not None and end.error is not None:
            hand_on()
            start, stop, _ = shards[todo[end.index]]
            raise JobFailed(f"evaluation shard of episodes {start}-{stop - 1} ({settings.executor.value} job "
                            f"{end.job_id}) failed: {end.error}; log: {end.log}")
        hand_on()
    hand_on()
    if state["next"] != episodes:
        raise JobFailed(f"evaluation shards ended at episode {state['next']} of {episodes}; rows: {rows_dir}")
    for _, _, path in shards:
        path.unlink(missing_ok=True)
        path.with_name(path.name + ".lock").unlink(missing_ok=True)
    return records
