"""Wall time of the whole pipeline: ``dvc repro -f`` from a fresh clone, stage by stage.

    python benchmarks/pipeline_time.py [--source .] [--workdir DIR] [--keep] [--resume]

1. ``git clone`` the source repository's committed HEAD into a temporary directory (``--workdir``), so
   the run sees exactly the commit it records, and nothing of this working tree (caches, checkpoints).
2. ``make install`` there: a fresh virtual environment (``setup_s``, not part of the pipeline's time).
3. Delete every output that ``dvc.lock`` lists. The committed results are persistent outputs that a
   stage would resume from (finished episodes, finished trainings), so ``dvc repro -f`` alone would not
   recompute them; without them every stage starts from nothing, as on a machine with no results.
4. ``dvc repro -f``, timed as a whole (``dvc_repro_wall_s``) and stage by stage: a stage runs from its
   ``Running stage '<name>'`` line to the next one (DVC runs stages one after another, so the stage
   times add up to the whole, up to DVC's start). The 1-minute load average is sampled every 15 s.
   Each stage's core-seconds (``core_s``: user + system CPU time of every process the stage ran, threads
   included) come from ``/proc`` (Linux): DVC's process tree is read at each stage's start and every 15 s,
   the CPU of its reaped descendants (``cutime``) plus that of those still running; the last stage's is
   closed by the ``os.times()`` of DVC's whole run. DVC's own process is not counted in any stage.

5. ``--resume --workdir DIR``: a run that was cut (the machine went away, Ctrl-C) continues in its clone
   with ``dvc repro`` (no ``-f``): the stages it finished are up to date and skipped, the cut stage resumes
   from its persistent outputs (finished episodes, ``last.pt``), the rest run. The state of every part
   (``pipeline_state.json``: its stages and wall time, refreshed every 15 s) adds up: the whole wall time
   is the sum of the parts' (the pause between them not counted), a cut stage's time the sum of its pieces
   (with one extra start-up), and ``parts`` records each part. DVC rewrites ``dvc.lock`` in place after each
   stage, so a cut at that moment leaves it empty: the run keeps a copy of the last readable one
   (``dvc.lock.good`` in the workdir, taken as each stage starts), and ``--resume`` puts it back; the stages
   finished after that copy run again (from their persistent outputs: the episodes' rows, ``last.pt``).

6. ``--report --workdir DIR``: write ``pipeline.json`` again from a finished run (its state and clone), running
   nothing: for a report whose code changed after the run (a new key, the SLURM model).
7. ``--regroup``: where the run's workdir is gone, write the keys derived from the measured stages alone
   (``groups``, and the stage count checked against this checkout's ``dvc.lock``: ``n_stages_in_dvc_lock``,
   ``covers_every_stage``, ``dvc_lock_commit``) into the existing ``pipeline.json``, every measured key as it was.

Writes ``results/benchmarks/pipeline.json`` in the source repository, only once ``dvc repro`` has
succeeded (an interrupted or failed run leaves the previous file as it was, and keeps its directory and
log for inspection). Keys:

- ``dvc_repro_wall_s``, ``stages`` (name, kind, start, wall time and core-seconds, in pipeline order), ``core_s``
  (the stages' core-seconds summed, and per kind in ``core_s_by_kind``), ``training_s``
  (the stages that train), ``downstream_of_training_s`` (every stage that depends, directly or through
  other stages, on a training stage: evaluations, cross-checks, figures, videos, the table), ``other_s``;
- ``groups``: the stages summed per group of ``dvc.yaml`` (``evaluate@nmpc``, ``train``, ...), most core-seconds
  first, with their shares of the whole;
- ``n_stages``, ``n_stages_in_dvc_lock`` and ``covers_every_stage``: whether the timed stages are exactly those of
  the clone's ``dvc.lock`` at the end (with ``--regroup``: of the source checkout's, at ``dvc_lock_commit``);
- the target on 2 cores (``targets_s``: 10800 s whole, issue 42's) and the measured time as a ratio to it
  (``ratio_to_target``, <= 1 meets it);
- ``training_runs``: each training's own wall time (its ``summary.json``), and ``training_concurrency``,
  the sum of those over the training stages' wall time: the speedup of running the trainings side by side
  (``pipelines/train_runs.py``) over running them one after another, measured in the same run;
- ``outputs``: how many of the regenerated outputs have the same MD5 as the commit's ``dvc.lock``, and
  which differ (wall times in ``metrics.csv`` and ``summary.json`` always do);
- ``projections``: the measured stages projected onto a 2-core laptop, an 8-core workstation and a SLURM
  cluster (:func:`projections`: a model, stated there, not a measurement), and ``slurm_64_cores``: one-core
  jobs (training runs, evaluation shards of 50 episodes, with the per-job overhead measured by
  ``benchmarks/slurm_overhead.py``) list-scheduled on 64 cores, against issue 42's 20 min (:func:`slurm_schedule`);
- ``parts``: each part's wall time and stages (one part unless resumed);
- ``commit``, ``cpu_count``, ``available_cores``, the load averages, ``setup_s``, the DVC version.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import yaml

from srmpc.stages.evaluate import available_cores

ROOT = Path(__file__).resolve().parents[1]

TARGETS_S = {"dvc_repro_wall_s": 10800.0}
"""Issue 42's target on this project's 2-core machine: every stage in 3 h (issue 20's, for the 75 stages of
its time, were 120 min whole and 60 min downstream of training; ``results/benchmarks/pipeline.json`` records
the targets it was measured against). The 64-core SLURM target is ``SLURM_TARGET_S``."""
STAGE_LINE = re.compile(r"^Running stage '([^']+)':")
LOAD_SAMPLE_S = 15.0
LOCK_BACKUP = "dvc.lock.good"
"""The workdir's copy of the clone's last readable ``dvc.lock`` (see ``prepare_resume``)."""


CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _proc_stat(pid: int) -> tuple[int, float, float] | None:
    """(parent pid, own CPU [s], CPU of its reaped children [s]) of a live process, from ``/proc/<pid>/stat``."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()  # from field 3 (state) on: field n is fields[n - 3]
    return (int(fields[1]), (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S,
            (int(fields[13]) + int(fields[14])) / CLOCK_TICKS_PER_S)


def process_tree_cpu_s(root: int) -> tuple[float, float] | None:
    """CPU seconds (user + system) of process ``root``: its own, and its descendants' (those it and they reaped,
    ``cutime``, plus the running ones'), read from ``/proc``; None where there is no ``/proc`` or ``root`` is gone."""
    stats = {}
    try:
        entries = [int(entry.name) for entry in os.scandir("/proc") if entry.name.isdigit()]
    except OSError:
        return None
    for pid in entries:
        stat = _proc_stat(pid)
        if stat is not None:
            stats[pid] = stat
    if root not in stats:
        return None
    children = defaultdict(list)
    for pid, (parent, _, _) in stats.items():
        children[parent].append(pid)
    own, descendants = stats[root][1], stats[root][2]
    stack = list(children[root])
    while stack:
        pid = stack.pop()
        _, cpu, reaped = stats[pid]
        descendants += cpu + reaped
        stack.extend(children[pid])
    return own, descendants


def _children_cpu_s() -> float:
    times = os.times()
    return times.children_user + times.children_system


def run_checked(command: list[str], cwd: Path, log, env: dict | None = None) -> None:
    result = subprocess.run(command, cwd=cwd, stdout=log, stderr=subprocess.STDOUT, env=env)
    if result.returncode != 0:
        raise SystemExit(f"pipeline_time: `{' '.join(command)}` failed with exit {result.returncode} in {cwd} "
                         f"(log: {log.name})")


def locked_outputs(lock_path: Path) -> dict[str, str | None]:
    """Every output of every stage in a ``dvc.lock``: path -> its MD5 (None for a directory's tree hash)."""
    lock = yaml.safe_load(lock_path.read_text()) or {}
    outputs = {}
    for stage in lock.get("stages", {}).values():
        for out in stage.get("outs", []):
            outputs[out["path"]] = out.get("md5")
    return outputs


def stage_kinds(repository: Path, training_stages: set[str]) -> dict[str, str]:
    """``training`` for the stages that train, ``downstream`` for those that depend on one, else ``other``."""
    import networkx as nx
    from dvc.repo import Repo

    with Repo(str(repository)) as repo:
        graph = repo.index.graph  # an edge runs from a stage to a stage it depends on
        kinds = {}
        for stage in graph.nodes:
            upstream = {s.name for s in nx.descendants(graph, stage)}
            if stage.name in training_stages:
                kinds[stage.name] = "training"
            elif upstream & training_stages:
                kinds[stage.name] = "downstream"
            else:
                kinds[stage.name] = "other"
    return kinds


def stage_upstreams(repository: Path) -> dict[str, set[str]]:
    """Each stage's direct upstream stages (those whose outputs it depends on)."""
    from dvc.repo import Repo

    with Repo(str(repository)) as repo:
        graph = repo.index.graph  # an edge runs from a stage to a stage it depends on
        return {stage.name: {upstream.name for upstream in graph.successors(stage)} for stage in graph.nodes}


def stage_commands(dvc_yaml: Path) -> dict[str, str]:
    """Each stage's command as ``dvc.yaml`` writes it (its name before any ``@item``; a ``foreach``'s
    ``do.cmd``; a list of commands joined by spaces)."""
    commands = {}
    for name, stage in yaml.safe_load(dvc_yaml.read_text())["stages"].items():
        command = stage.get("cmd") or stage.get("do", {}).get("cmd", "")
        commands[name] = " ".join(command) if isinstance(command, list) else command
    return commands


def evaluation_stage_names(dvc_yaml: Path) -> set[str]:
    """Stages whose command is an evaluation: ``python -m srmpc`` without ``stage=train``."""
    return {name for name, command in stage_commands(dvc_yaml).items()
            if command.startswith("python -m srmpc") and "stage=train" not in command}


def evaluation_episodes(repository: Path, stages: list[dict], evaluations: set[str]) -> dict[str, int]:
    """Episodes of each evaluation stage ``evaluate@<question>/<name>-<traffic>``, from the identity its stage
    ``experiments`` wrote (``results/experiments/<question>/<name>_<traffic>.yaml``)."""
    episodes = {}
    for stage in stages:
        base, _, item = stage["name"].partition("@")
        if base in evaluations and item:
            experiment, _, traffic = item.rpartition("-")
            identity = repository / "results" / "experiments" / f"{experiment}_{traffic}.yaml"
            if identity.is_file():
                episodes[stage["name"]] = int(yaml.safe_load(identity.read_text())["evaluation"]["episodes"])
    return episodes


EVALUATION_START_S = 8.5
"""The part of an evaluation stage's wall time that more workers do not shorten [s]: process start, the
workers' spawn and numba cache load. From ``results/benchmarks/evaluation_workers.json``: 200 SRMPC
episodes take 59.3 s in one process (about 5 s of it the process start) and 35.7 s on 2 workers, so
35.7 = S + (59.3 - 5) / 2 gives S = 8.5 s."""
SLURM_CORES_PER_EVALUATION = 8
"""Cores of each evaluation job in the SLURM projection (``cpus_per_task``)."""


def _makespan(walls: list[float], slots: int) -> float:
    """Longest-processing-time-first schedule of ``walls`` on ``slots`` parallel slots: its makespan."""
    loads = [0.0] * max(1, slots)
    for wall in sorted(walls, reverse=True):
        loads[loads.index(min(loads))] += wall
    return max(loads)


def projected_stage_s(stage: dict, runs: list[dict], evaluations: set[str], cores: int, measured_cores: int,
                      one_job_per_run: bool = False) -> float:
    """A model of ``stage``'s wall time on ``cores`` from its time on ``measured_cores`` (this run):

    - a training stage: its runs (each single-threaded, their own measured walls) scheduled longest first on
      ``cores`` slots (every run at once with ``one_job_per_run``), times the stage's measured overhead over
      that schedule on ``measured_cores``;
    - an evaluation: ``EVALUATION_START_S`` plus the rest of its time spread over ``cores`` workers;
    - anything else (tables, figures, videos): as measured.
    The per-core speed is this machine's; memory bandwidth and turbo effects are not modelled."""
    own = [r["wall_s"] for r in runs if r["stage"] == stage["name"]]
    if stage["kind"] == "training" and own:
        measured_schedule = _makespan(own, measured_cores)
        schedule = max(own) if one_job_per_run else _makespan(own, cores)
        return stage["wall_s"] * schedule / measured_schedule
    if stage["name"].split("@")[0] in evaluations:
        work = max(stage["wall_s"] - EVALUATION_START_S, 0.0)
        return min(stage["wall_s"], EVALUATION_START_S) + work * measured_cores / cores
    return stage["wall_s"]


SLURM_CORES = 64
"""Cores of the cluster in issue 42's SLURM projection (:func:`slurm_schedule`)."""
SLURM_TARGET_S = 1200.0
"""Issue 42's target for the whole pipeline on ``SLURM_CORES`` cores through SLURM, queueing excluded [s]."""
SHARD_EPISODES = 50
"""Episodes per evaluation shard job (``srmpc.fanout.FanoutSettings.shard_episodes``' default)."""
SLURM_OVERHEAD_JSON = ROOT / "results" / "benchmarks" / "slurm_overhead.json"
"""``benchmarks/slurm_overhead.py``'s measurement on the local SLURM: a real shard's submission to result."""


def slurm_job_overhead_s(path: Path = SLURM_OVERHEAD_JSON) -> float:
    """Seconds a shard job adds to its episodes' own time, measured (``shard``: submission to result seen, minus the
    episodes): sbatch, start, importing srmpc and torch, building the scenario and controller, result polling."""
    shard = json.loads(path.read_text())["shard"]
    return shard["submit_to_result_s"] - shard["episodes_s"]


def slurm_jobs(stage: dict, runs: list[dict], evaluations: set[str], measured_cores: int, episodes: int,
               overhead_s: float) -> list[float]:
    """The one-core SLURM jobs of ``stage`` and their durations [s]: a training stage's runs (each as measured, side by
    side, one core each) plus the overhead; an evaluation's shards of ``SHARD_EPISODES`` episodes, its episodes' core
    time split evenly, plus the overhead; any other stage as measured, one job. The episodes' core time is the stage's
    measured core-seconds less ``EVALUATION_START_S`` on each of the cores it ran on (the shard's own start-up is in
    the overhead); where core-seconds were not measured, its wall minus ``EVALUATION_START_S`` times those cores."""
    own = [r["wall_s"] for r in runs if r["stage"] == stage["name"]]
    if stage["kind"] == "training" and own:
        return [wall + overhead_s for wall in own]
    if stage["name"].split("@")[0] in evaluations:
        shards = max(1, -(-episodes // SHARD_EPISODES))
        if stage.get("core_s") is not None:
            work = max(stage["core_s"] - EVALUATION_START_S * measured_cores, 0.0)
        else:
            work = max(stage["wall_s"] - EVALUATION_START_S, 0.0) * measured_cores
        return [work / shards + overhead_s] * shards
    return [stage["wall_s"]]


def slurm_schedule(jobs: dict[str, list[float]], upstreams: dict[str, set[str]], cores: int) -> float:
    """Makespan of ``jobs`` (per stage, one core each) on ``cores`` cores: a stage's jobs are released when every
    upstream stage's jobs have finished, and a free core takes the longest released job (list scheduling; SLURM's
    queueing and scheduling delays beyond the measured per-job overhead are not modelled)."""
    import heapq

    waiting = {name: {u for u in upstreams.get(name, ()) if u in jobs} for name in jobs}
    left = {name: len(durations) for name, durations in jobs.items()}
    released: list[tuple[float, str]] = []
    running: list[tuple[float, str]] = []
    now, free = 0.0, cores

    def release(name: str) -> None:
        for duration in jobs[name]:
            heapq.heappush(released, (-duration, name))

    for name, upstream in waiting.items():
        if not upstream:
            release(name)
    while released or running:
        while released and free > 0:
            negative, name = heapq.heappop(released)
            heapq.heappush(running, (now - negative, name))
            free -= 1
        now, name = heapq.heappop(running)
        free += 1
        left[name] -= 1
        if left[name] == 0:
            for downstream, upstream in waiting.items():
                if name in upstream:
                    upstream.discard(name)
                    if not upstream and left[downstream] > 0:
                        release(downstream)
    return now


def projections(stages: list[dict], runs: list[dict], evaluations: set[str], upstreams: dict[str, set[str]],
                measured_cores: int, episodes: dict[str, int] | None = None, slurm_overhead_s: float | None = None
                ) -> dict:
    """The whole pipeline's wall time projected for a 2-core laptop, an 8-core workstation (``dvc repro``:
    stages one after another, each on every core) and a SLURM cluster (every training run and every
    evaluation its own job, all at once, an evaluation on ``SLURM_CORES_PER_EVALUATION`` cores: the
    critical path through the stage graph; queueing not counted)."""
    result = {}
    for label, cores in (("laptop_2_cores", 2), ("workstation_8_cores", 8)):
        result[label] = {"cores": cores, "dvc_repro_wall_s": sum(
            projected_stage_s(s, runs, evaluations, cores, measured_cores) for s in stages)}
    own = {s["name"]: projected_stage_s(s, runs, evaluations, SLURM_CORES_PER_EVALUATION, measured_cores,
                                        one_job_per_run=True) for s in stages}
    finish: dict[str, float] = {}

    def finished_at(name: str) -> float:
        if name not in finish:
            finish[name] = own.get(name, 0.0) + max((finished_at(u) for u in upstreams.get(name, ())), default=0.0)
        return finish[name]

    critical = max((finished_at(name) for name in own), default=0.0)
    result["slurm_cluster"] = {"cores_per_evaluation": SLURM_CORES_PER_EVALUATION, "critical_path_s": critical,
                               "core_hours": sum(r["wall_s"] for r in runs) / 3600 + sum(
                                   (s["wall_s"] * measured_cores) / 3600 for s in stages if s["kind"] != "training")}
    result["model"] = ("training: runs scheduled on the cores, longest first; evaluation: "
                       f"{EVALUATION_START_S} s fixed + the rest over the cores; other stages as measured")
    if slurm_overhead_s is not None:
        jobs = {s["name"]: slurm_jobs(s, runs, evaluations, measured_cores, (episodes or {}).get(s["name"], 0),
                                      slurm_overhead_s) for s in stages}
        zero = {name: [0.0] if not durations else durations for name, durations in jobs.items()}
        makespan = slurm_schedule(zero, upstreams, SLURM_CORES)
        core_s = sum(sum(durations) for durations in jobs.values())
        result[f"slurm_{SLURM_CORES}_cores"] = {
            "cores": SLURM_CORES, "wall_s": makespan, "target_s": SLURM_TARGET_S,
            "ratio_to_target": makespan / SLURM_TARGET_S, "core_s": core_s,
            "lower_bound_core_s_over_cores": core_s / SLURM_CORES,
            "jobs": sum(len(durations) for durations in jobs.values()), "job_overhead_s": slurm_overhead_s,
            "shard_episodes": SHARD_EPISODES,
            "model": ("one-core jobs: each training run, each evaluation shard (the evaluation's measured episode "
                      "core time split evenly) plus the measured per-job overhead, every other stage as measured; "
                      "list scheduling, longest released job first, a stage released when its upstream stages "
                      "finished; queueing beyond the measured overhead not counted")}
    return result


def stage_group(name: str) -> str:
    """A stage's group in ``dvc.yaml``: an evaluation's experiment folder (``evaluate@nmpc/rollout-dense`` ->
    ``evaluate@nmpc``), a ``foreach`` stage's name (``designate_policy@ppo`` -> ``designate_policy``), else
    the stage itself."""
    base, _, item = name.partition("@")
    return f"{base}@{item.split('/')[0]}" if base == "evaluate" and "/" in item else base


def stage_groups(stages: list[dict]) -> list[dict]:
    """The stages summed per :func:`stage_group`, most core-seconds first (wall time where not measured),
    each with its share of the whole's wall time and core-seconds."""
    groups: dict[str, dict] = {}
    for stage in stages:
        name = stage_group(stage["name"])
        group = groups.setdefault(name, {"group": name, "stages": 0, "wall_s": 0.0, "core_s": 0.0})
        group["stages"] += 1
        group["wall_s"] += stage["wall_s"]
        core_s = stage["core_s"]
        group["core_s"] = None if group["core_s"] is None or core_s is None else group["core_s"] + core_s
    wall = sum(g["wall_s"] for g in groups.values())
    core = None if any(g["core_s"] is None for g in groups.values()) else sum(g["core_s"] for g in groups.values())
    for group in groups.values():
        group["share_of_wall"] = group["wall_s"] / wall if wall else None
        group["share_of_core_s"] = group["core_s"] / core if core else None
    return sorted(groups.values(), key=lambda g: -(g["core_s"] if core else g["wall_s"]))


def training_stage_names(dvc_yaml: Path) -> set[str]:
    """Stages whose command trains: ``python -m srmpc stage=train`` or ``python -m pipelines.train_runs``."""
    return {name for name, command in stage_commands(dvc_yaml).items()
            if "train_runs" in command or "stage=train" in command}


class LoadSampler(threading.Thread):
    """The 1-minute load average every ``LOAD_SAMPLE_S`` seconds while the pipeline runs; calls
    ``heartbeat()`` after each sample (the run's state file is refreshed there)."""

    def __init__(self, samples: list[float], heartbeat=None) -> None:
        super().__init__(daemon=True)
        self.samples = samples  # appended to in place: the running part's ``load_samples``
        self.stopped = threading.Event()
        self.heartbeat = heartbeat

    def run(self) -> None:
        while not self.stopped.wait(LOAD_SAMPLE_S):
            self.samples.append(os.getloadavg()[0])
            if self.heartbeat is not None:
                self.heartbeat()


class RunState:
    """``pipeline_state.json`` of a workdir: the commit, setup time, the commit's output MD5s, and per part
    its stages so far, wall time so far (refreshed every ``LOAD_SAMPLE_S``) and load samples. Written
    atomically, so a run cut at any moment leaves a readable state to resume from."""

    def __init__(self, path: Path, state: dict) -> None:
        self.path = path
        self.state = state
        self.lock = threading.Lock()

    @classmethod
    def load(cls, path: Path) -> RunState:
        try:
            return cls(path, json.loads(path.read_text()))
        except (OSError, ValueError) as error:
            raise SystemExit(f"pipeline_time: --resume: {path}: no readable run state ({error})") from error

    def new_part(self, samples: list[float]) -> dict:
        part = {"stages": [], "wall_s": 0.0, "finished": False, "load_samples": samples}
        with self.lock:
            self.state.setdefault("parts", []).append(part)
        self.write()
        return part

    def write(self) -> None:
        with self.lock:
            temporary = self.path.with_name(self.path.name + ".tmp")
            temporary.write_text(json.dumps(self.state, indent=1) + "\n")
            os.replace(temporary, self.path)


def readable_lock(path: Path) -> bool:
    """Whether ``path`` is a ``dvc.lock`` that DVC can read back: a mapping with its ``stages``."""
    try:
        content = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return False
    return isinstance(content, dict) and isinstance(content.get("stages"), dict)


def back_up_lock(lock: Path, backup: Path) -> None:
    """Copy ``lock`` to ``backup`` (atomically) if it is readable; otherwise keep the previous copy."""
    if readable_lock(lock):
        temporary = backup.with_name(backup.name + ".tmp")
        shutil.copyfile(lock, temporary)
        os.replace(temporary, backup)


def prepare_resume(clone: Path, backup: Path) -> str | None:
    """Make a cut run's clone resumable: remove the locks its gone DVC process left, and put back the last
    readable ``dvc.lock`` if the cut left it unreadable (DVC was rewriting it). Returns what was done, or
    None; exits with one line if the lock is unreadable and there is no copy."""
    for stale in ("rwlock", "lock"):  # left behind by the cut run's DVC process, which is gone
        (clone / ".dvc" / "tmp" / stale).unlink(missing_ok=True)
    lock = clone / "dvc.lock"
    if not lock.exists() or readable_lock(lock):
        return None
    if not readable_lock(backup):
        raise SystemExit(f"pipeline_time: --resume: {lock} is unreadable (the run was cut while DVC wrote it) "
                         f"and {backup} holds no copy; rebuild it with `dvc commit -f` of the finished stages")
    shutil.copyfile(backup, lock)
    return f"{lock} was unreadable (cut while DVC wrote it): put back its copy from the last stage start"


def timed_repro(clone: Path, bin_dir: Path, log_path: Path, part: dict, state: RunState, force: bool,
                lock_backup: Path | None = None) -> tuple[float, list[dict], int]:
    """``dvc repro [-f]`` in ``clone`` with ``bin_dir`` (its virtual environment's) first on PATH: the wall
    time, the stages with their start and wall time, and DVC's exit code. Each line of DVC's output goes
    to ``log_path`` (appended), with its time; ``part`` (in ``state``) holds the stages and wall time so far.
    As each stage starts, the ``dvc.lock`` its predecessors wrote is copied to ``lock_backup`` (if given)."""
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
           "TQDM_DISABLE": "1", "PYTHONUNBUFFERED": "1"}
    env.pop("SRMPC_PARENT_RUN_ID", None)
    env.pop("VIRTUAL_ENV", None)
    stages: list[dict] = part["stages"]
    started = time.perf_counter()
    part["started_perf"] = started
    children_cpu_before = _children_cpu_s()
    with log_path.open("a") as log:
        log.write(f"=== part {len(state.state['parts'])}: dvc repro{' --force' if force else ''} ===\n")
        process = subprocess.Popen([str(bin_dir / "dvc"), "repro", *(["--force"] if force else [])], cwd=clone, env=env,
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
        assert process.stdout is not None
        part["dvc_pid"] = process.pid
        for line in process.stdout:
            now = time.perf_counter() - started
            log.write(f"[{now:8.1f} s] {line}")
            log.flush()
            match = STAGE_LINE.match(line)
            if match:
                tree = process_tree_cpu_s(process.pid)
                if lock_backup is not None:
                    back_up_lock(clone / "dvc.lock", lock_backup)
                with state.lock:
                    if stages:
                        stages[-1]["wall_s"] = now - stages[-1]["started_s"]
                        _account_cpu(part, tree)
                    stages.append({"name": match.group(1), "started_s": now, "wall_s": 0.0,
                                   "cpu_at_start_s": None if tree is None else tree[1],
                                   "core_s": None if tree is None else 0.0})
                    part["wall_s"] = now
                state.write()
                print(f"[{now:8.1f} s] {match.group(1)}", flush=True)
        returncode = process.wait()
    wall = time.perf_counter() - started
    dvc_cpu_s = _children_cpu_s() - children_cpu_before  # DVC's own CPU and every stage's, all reaped now
    with state.lock:
        if stages:
            stages[-1]["wall_s"] = wall - stages[-1]["started_s"]
            if stages[-1]["cpu_at_start_s"] is not None:
                stages[-1]["core_s"] = dvc_cpu_s - part.get("dvc_own_cpu_s", 0.0) - stages[-1]["cpu_at_start_s"]
        part["wall_s"] = wall
        part["core_s"] = dvc_cpu_s
        part["finished"] = returncode == 0
        part.pop("dvc_pid", None)
    state.write()
    return wall, stages, returncode


def _account_cpu(part: dict, tree: tuple[float, float] | None) -> None:
    """The running stage's core-seconds so far, and DVC's own CPU, from a reading of DVC's process tree."""
    stage = part["stages"][-1]
    if tree is not None and stage.get("cpu_at_start_s") is not None:
        part["dvc_own_cpu_s"] = tree[0]
        stage["core_s"] = tree[1] - stage["cpu_at_start_s"]


def refresh_part(part: dict, state: RunState) -> None:
    """Heartbeat: the running part's wall time and core-seconds, and its current stage's, up to now."""
    pid = part.get("dvc_pid")
    tree = process_tree_cpu_s(pid) if pid is not None else None
    with state.lock:
        now = time.perf_counter() - part.get("started_perf", time.perf_counter())
        part["wall_s"] = now
        if part["stages"]:
            part["stages"][-1]["wall_s"] = now - part["stages"][-1]["started_s"]
            _account_cpu(part, tree)
    state.write()


def merge_parts(parts: list[dict]) -> tuple[float, list[dict]]:
    """The whole run from its parts: total wall time (pauses between parts excluded) and each stage once,
    in pipeline order, started at its first piece's time on the summed clock, its pieces' walls and core-seconds
    added (None where a piece's were not measured)."""
    offset, merged, by_name = 0.0, [], {}
    for part in parts:
        for stage in part["stages"]:
            core_s = stage.get("core_s")
            if stage["name"] in by_name:
                entry = by_name[stage["name"]]
                entry["wall_s"] += stage["wall_s"]
                entry["core_s"] = None if entry["core_s"] is None or core_s is None else entry["core_s"] + core_s
                entry["pieces"] += 1
            else:
                entry = {"name": stage["name"], "started_s": offset + stage["started_s"], "wall_s": stage["wall_s"],
                         "core_s": core_s, "pieces": 1}
                by_name[stage["name"]] = entry
                merged.append(entry)
        offset += part["wall_s"]
    return offset, merged


def training_runs(clone: Path, dvc_yaml: Path, training_stages: set[str]) -> list[dict]:
    """Each training's own wall time, from the ``summary.json`` that the training stages output."""
    stages = yaml.safe_load(dvc_yaml.read_text())["stages"]
    runs = []
    for name in sorted(training_stages):
        for out in stages[name].get("outs", []):
            path = next(iter(out)) if isinstance(out, dict) else out
            summary_path = clone / path / "summary.json"  # an output directory per training
            if path.endswith("/summary.json"):  # or its files one by one
                summary_path = clone / path
            if summary_path.is_file():
                summary = json.loads(summary_path.read_text())
                runs.append({"stage": name, "output_dir": str(summary_path.parent.relative_to(clone)),
                             "wall_s": summary["wall_s"], "frames": summary["frames"]})
    return runs


def set_up_clone(source: Path, workdir: Path, clone: Path) -> dict:
    """Clone ``source``'s HEAD, ``make install`` there, delete every output its ``dvc.lock`` lists: the new
    run's state (commit, setup time, the commit's output MD5s)."""
    print(f"pipeline_time: cloning {source} into {clone} (log: {workdir})", flush=True)
    with (workdir / "setup.log").open("w") as log:
        run_checked(["git", "clone", "--quiet", "--no-hardlinks", str(source), str(clone)], workdir, log)
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=clone, capture_output=True, text=True,
                                check=True).stdout.strip()
        setup_started = time.perf_counter()
        run_checked(["make", "install"], clone, log)
        setup_s = time.perf_counter() - setup_started
    committed_outputs = locked_outputs(clone / "dvc.lock")
    for path in committed_outputs:  # start from nothing: no finished episode or training to resume from
        target = clone / path
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    return {"commit": commit, "setup_s": setup_s, "committed_outputs": committed_outputs, "parts": []}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--source", type=Path, default=ROOT, help="the repository to clone (its HEAD)")
    parser.add_argument("--workdir", type=Path, default=None, help="where to clone (default: a new temporary dir)")
    parser.add_argument("--keep", action="store_true", help="keep the clone after a successful run")
    parser.add_argument("--output", type=Path, default=None,
                        help="default: <source>/results/benchmarks/pipeline.json")
    again = parser.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the cut run in --workdir (its clone and pipeline_state.json)")
    again.add_argument("--report", action="store_true",
                       help="write pipeline.json again from the finished run in --workdir, running nothing")
    again.add_argument("--regroup", action="store_true",
                       help="write the keys derived from the measured stages into the existing pipeline.json")
    args = parser.parse_args()
    source = args.source.resolve()
    output = args.output or source / "results" / "benchmarks" / "pipeline.json"
    if args.regroup:
        write_json(output, regroup(json.loads(output.read_text()), source))
        return
    if (args.resume or args.report) and args.workdir is None:
        raise SystemExit(f"pipeline_time: {'--resume' if args.resume else '--report'} needs the --workdir of the run")
    workdir = Path(tempfile.mkdtemp(prefix="srmpc-pipeline-")) if args.workdir is None else args.workdir.resolve()
    clone = workdir / "srmpc"
    state_path = workdir / "pipeline_state.json"
    if args.report:
        state = RunState.load(state_path)
    elif args.resume:
        state = RunState.load(state_path)
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=clone, capture_output=True, text=True).stdout.strip()
        if head != state.state["commit"]:
            raise SystemExit(f"pipeline_time: --resume: {clone} is at {head or 'no commit'}, its run at "
                             f"{state.state['commit']}")
        restored = prepare_resume(clone, workdir / LOCK_BACKUP)
        if restored:
            print(f"pipeline_time: --resume: {restored}", flush=True)
        print(f"pipeline_time: resuming the run in {clone} (part {len(state.state['parts']) + 1})", flush=True)
    else:
        workdir.mkdir(parents=True, exist_ok=True)
        if clone.exists():
            raise SystemExit(f"pipeline_time: --workdir {workdir}: already holds a clone (srmpc/); pick an empty "
                             "one, or --resume it")
        state = RunState(state_path, set_up_clone(source, workdir, clone))

    if not args.report:
        load_before = os.getloadavg()[0]
        samples: list[float] = []
        part = state.new_part(samples)
        part["load_average_1min_before"] = load_before
        sampler = LoadSampler(samples, heartbeat=lambda: refresh_part(part, state))
        sampler.start()
        _, _, returncode = timed_repro(clone, clone / ".venv" / "bin", workdir / "dvc_repro.log", part, state,
                                       force=not args.resume, lock_backup=workdir / LOCK_BACKUP)
        sampler.stopped.set()
        if returncode != 0:
            wall, _ = merge_parts(state.state["parts"])
            raise SystemExit(f"pipeline_time: dvc repro failed with exit {returncode} after {wall:.0f} s; "
                             f"log: {workdir / 'dvc_repro.log'} (results/benchmarks/pipeline.json left as it was; "
                             f"--resume --workdir {workdir} continues it)")
        part["ended_at"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        state.write()
    elif not state.state["parts"] or not state.state["parts"][-1]["finished"]:
        raise SystemExit(f"pipeline_time: --report: the run in {workdir} has not finished; --resume it")

    result = report(state.state, clone)
    write_json(output, result)
    print(json.dumps({k: result[k] for k in ("dvc_repro_wall_s", "training_s", "downstream_of_training_s",
                                             "ratio_to_target", "training_concurrency", "commit")}, indent=1))
    if not args.keep and args.workdir is None:
        shutil.rmtree(workdir, ignore_errors=True)


def write_json(path: Path, result: dict) -> None:
    """``result`` to ``path``, replaced whole (a cut leaves the previous file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(temporary, path)


def regroup(result: dict, checkout: Path) -> dict:
    """``result`` (a finished run's ``pipeline.json``) with the keys derived from its measured stages written
    again: ``groups``, and the timed stages checked against ``checkout``'s ``dvc.lock`` (``n_stages_in_dvc_lock``,
    ``covers_every_stage``, ``dvc_lock_commit``: the checkout's HEAD). Every measured key is kept as it was."""
    lock = checkout / "dvc.lock"
    if not readable_lock(lock):
        raise SystemExit(f"pipeline_time: --regroup: {lock} is missing or unreadable")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=checkout, capture_output=True, text=True).stdout.strip()
    return {**result, "groups": stage_groups(result["stages"]), **stage_coverage(result["stages"], lock),
            "dvc_lock_commit": head or None}


def stage_coverage(stages: list[dict], lock: Path) -> dict:
    """``n_stages``, ``n_stages_in_dvc_lock`` and ``covers_every_stage``: whether the timed ``stages`` are exactly
    the stages of ``lock`` (a ``dvc.lock``)."""
    locked_stages = set(yaml.safe_load(lock.read_text())["stages"])
    return {"n_stages": len(stages), "n_stages_in_dvc_lock": len(locked_stages),
            "covers_every_stage": {s["name"] for s in stages} == locked_stages}


def report(state: dict, clone: Path) -> dict:
    """``pipeline.json`` of a finished run: its state (every part) and its clone (``dvc.yaml``, ``dvc.lock``,
    the trainings' summaries)."""
    committed_outputs = state["committed_outputs"]
    training_stages = training_stage_names(clone / "dvc.yaml")
    kinds = stage_kinds(clone, training_stages)
    wall, stages = merge_parts(state["parts"])
    for stage in stages:
        stage["kind"] = kinds.get(stage["name"], "other")
    sums = {kind: sum(s["wall_s"] for s in stages if s["kind"] == kind) for kind in ("training", "downstream", "other")}
    measured_cpu = all(s["core_s"] is not None for s in stages)
    core_s_by_kind = ({kind: sum(s["core_s"] for s in stages if s["kind"] == kind)
                       for kind in ("training", "downstream", "other")} if measured_cpu else None)
    runs = training_runs(clone, clone / "dvc.yaml", training_stages)
    regenerated = locked_outputs(clone / "dvc.lock")
    differing = sorted(p for p, md5 in regenerated.items() if md5 is not None and committed_outputs.get(p) != md5)
    measured = {"dvc_repro_wall_s": wall, "downstream_of_training_s": sums["downstream"]}
    samples = [x for p in state["parts"] for x in p["load_samples"]] or [os.getloadavg()[0]]
    evaluations = evaluation_stage_names(clone / "dvc.yaml")
    projected = projections(stages, runs, evaluations, stage_upstreams(clone), available_cores(),
                            evaluation_episodes(clone, stages, evaluations), slurm_job_overhead_s())
    return {
        "dvc_repro_wall_s": wall,
        "training_s": sums["training"],
        "downstream_of_training_s": sums["downstream"],
        "other_s": sums["other"],
        "core_s": sum(core_s_by_kind.values()) if core_s_by_kind else None,
        "core_s_by_kind": core_s_by_kind,
        "targets_s": TARGETS_S,
        "ratio_to_target": {k: measured[k] / TARGETS_S[k] for k in TARGETS_S},
        "meets_targets": all(measured[k] <= TARGETS_S[k] for k in TARGETS_S),
        "stages": [{"name": s["name"], "kind": s["kind"], "started_s": s["started_s"], "wall_s": s["wall_s"],
                    "core_s": s["core_s"], **({"pieces": s["pieces"]} if s["pieces"] > 1 else {})} for s in stages],
        "groups": stage_groups(stages),
        "projections": projected,
        "parts": [{"wall_s": p["wall_s"], "core_s": p.get("core_s"), "stages_run": len(p["stages"]),
                   "finished": p["finished"]} for p in state["parts"]],
        **stage_coverage(stages, clone / "dvc.lock"),
        "training_runs": runs,
        "training_concurrency": (sum(r["wall_s"] for r in runs) / sums["training"]) if sums["training"] else None,
        "outputs": {"compared": sum(md5 is not None for md5 in regenerated.values()),
                    "same_md5_as_commit": sum(md5 is not None and committed_outputs.get(p) == md5
                                              for p, md5 in regenerated.items()),
                    "differing": differing},
        "commit": state["commit"],
        "setup_s": state["setup_s"],
        "cpu_count": os.cpu_count(),
        "available_cores": available_cores(),
        "load_average_1min_before": state["parts"][0].get("load_average_1min_before"),
        "load_average_1min_mean_during": sum(samples) / len(samples),
        "load_average_1min_max_during": max(samples),
        "machine": platform.machine(), "processor": _processor(), "python": platform.python_version(),
        "dvc": _dvc_version(clone),
        "measured_at": state["parts"][-1].get("ended_at") or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def _processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _dvc_version(clone: Path) -> str:
    dvc = clone / ".venv" / "bin" / "dvc"  # the clone's own (``make install``), else this environment's
    dvc = dvc if dvc.exists() else Path(sys.executable).parent / "dvc"
    result = subprocess.run([str(dvc), "--version"], capture_output=True, text=True)
    return result.stdout.strip()


if __name__ == "__main__":
    sys.exit(main())
