"""``stage=evaluate``: closed-loop episodes of one controller, resumable, tracked in MLflow.

Files in the output directory:
- ``config.yaml``: the composed config the episodes belong to, plus ``policy_sha256`` for a
  controller that runs a policy; a config that differs in what the episodes depend on (see
  :func:`evaluation_identity`: not the training hyperparameters, MLflow settings or output paths)
  refuses to write there, so earlier results are never mixed or lost;
- ``episodes.csv``: one row per finished episode, appended and flushed as each one ends, so an
  interrupted run keeps every finished episode and the next run with the same config resumes;
- ``summary.json``: the paper's table metrics over all episodes, replaced atomically at the end.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import os
from pathlib import Path

import yaml

from srmpc.config.compose import ConfigError
from srmpc.config.schema import Config, controller_label
from srmpc.controller_factory import make_env_and_controller, policy_file
from srmpc.controllers.outcomes import OUTCOME_KEYS
from srmpc.episode_loop import EpisodeRecord, evaluate, evaluate_in_workers
from srmpc.fanout import FanoutSettings, evaluate_in_jobs, shard_dir
from srmpc.metrics import aggregate_metrics
from srmpc.output_folder import (
    CONFIG_NAME,
    EPISODES_NAME,
    SUMMARY_NAME,
    atomic_write_text,
    episode_row,
    read_finished_episodes,
    write_episodes,
)
from srmpc.tracking import Run


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask: a SLURM allocation, taskset)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def evaluation_workers(config: Config, remaining: int) -> int:
    """Worker processes for ``remaining`` episodes: ``evaluation.workers`` (0: every available core),
    at most one per episode; 1 means this process runs them."""
    requested = config.evaluation.workers
    if requested < 0:
        raise ConfigError(f"evaluation.workers={requested}: must be >= 0 (0: one per CPU core, 1: this process)")
    return max(1, min(requested or available_cores(), remaining))


NOT_IDENTITY = (("agent",), ("tracking",), ("evaluation", "output_dir"), ("evaluation", "workers"))
"""Config entries that do not change an evaluation's episodes: the training hyperparameters (the
policy enters through its file's hash), MLflow settings, where the results go and how many processes
produce them."""


def evaluation_identity(config_yaml: str) -> dict:
    """What an evaluation's episodes depend on: the config without :data:`NOT_IDENTITY`, plus ``policy_sha256``
    where the controller runs a policy."""
    try:
        identity = yaml.safe_load(config_yaml) or {}
    except yaml.YAMLError:
        identity = None
    if not isinstance(identity, dict):  # not a config mapping: the text itself is the identity
        return {"text": config_yaml}
    for path in NOT_IDENTITY:
        node = identity
        for key in path[:-1]:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(path[-1], None)
    return identity


def identity_yaml(config: Config, config_yaml: str) -> str:
    """``config_yaml`` with the SHA-256 of the evaluated policy file appended (see evaluation_identity)."""
    policy = policy_file(config)
    if policy is None or not policy[0].is_file() or "text" in evaluation_identity(config_yaml):
        return config_yaml
    return config_yaml.rstrip("\n") + f"\npolicy_sha256: {hashlib.sha256(policy[0].read_bytes()).hexdigest()}\n"


def prepare_output_dir(output_dir: Path, config_yaml: str) -> list[EpisodeRecord]:
    """Claim ``output_dir`` for this config; return the episodes a previous run already finished.

    A directory whose ``config.yaml`` has another :func:`evaluation_identity` is refused (its episodes
    belong to another scenario, planner, controller, seed or policy)."""
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"evaluation.output_dir={output_dir}: cannot write there ({error.strerror or error})"
                          ) from error
    config_path = output_dir / CONFIG_NAME
    if config_path.exists() and evaluation_identity(config_path.read_text()) != evaluation_identity(config_yaml):
        raise ConfigError(
            f"evaluation.output_dir={output_dir}: holds results of a different config or policy ({config_path}); "
            "choose another directory"
        )
    atomic_write_text(config_path, config_yaml)
    finished = read_finished_episodes(output_dir / EPISODES_NAME)
    finished = [r for i, r in enumerate(finished) if r.episode == i]  # keep the contiguous prefix
    write_episodes(output_dir / EPISODES_NAME, finished)  # rewrite without a torn tail
    return finished


def run_evaluation(config: Config, config_yaml: str, output_dir: Path, run: Run, progress: bool = True,
                   fanout: FanoutSettings | None = None) -> dict:
    """Evaluate, appending to ``output_dir``; returns the summary written to ``summary.json``.

    The episodes run in ``evaluation.workers`` processes (:func:`evaluation_workers`), or, with ``fanout``
    settings, in shards, one job each (SLURM or local, :func:`srmpc.fanout.evaluate_in_jobs`); this process
    alone writes ``episodes.csv`` (in episode order, each row fsync'd), logs to MLflow and shows the
    progress bar, so the file is the same, and resumes the same, whatever runs the episodes."""
    evaluation_workers(config, 1)  # a bad evaluation.workers fails before anything is written
    env, controller = make_env_and_controller(config)  # also in the parent: a bad policy fails here, in one line
    identity = identity_yaml(config, config_yaml)
    finished = prepare_output_dir(output_dir, identity)
    episodes = config.evaluation.episodes
    workers = evaluation_workers(config, episodes - len(finished))
    run.set_tags({"evaluation_workers": str(workers)} if fanout is None else
                 {"evaluation_fanout": fanout.executor.value, "evaluation_shard_episodes": str(fanout.shard_episodes)})
    if finished:
        run.set_tags({"resumed_from_episode": str(len(finished))})
    csv_handle = (output_dir / EPISODES_NAME).open("a", newline="")
    writer = csv.writer(csv_handle)
    bar = None
    if progress:
        from tqdm import tqdm

        label = f"{config.experiment or controller_label(config.controller)} {config.scenario.traffic}"
        bar = tqdm(total=episodes, initial=len(finished), desc=label, unit="ep")

    def on_episode(record: EpisodeRecord) -> None:
        writer.writerow(episode_row(record))
        csv_handle.flush()
        os.fsync(csv_handle.fileno())
        run.log_metrics({f"episode/{k}": v for k, v in record.metrics.as_dict().items()}, step=record.episode)
        if bar is not None:
            bar.update(1)

    try:
        if fanout is not None:
            setup = functools.partial(make_env_and_controller, config)
            rows_dir = shard_dir(Path(fanout.work_dir), output_dir, identity)
            new = evaluate_in_jobs(setup, episodes, config.evaluation.seed, fanout, rows_dir, on_episode, len(finished))
        elif workers > 1:
            setup = functools.partial(make_env_and_controller, config)
            new = evaluate_in_workers(setup, episodes, config.evaluation.seed, workers, on_episode, len(finished))
        else:
            new = evaluate(env, controller, episodes, config.evaluation.seed, on_episode, len(finished))
        records = finished + new
    finally:
        csv_handle.close()
        env.close()
        if bar is not None:
            bar.close()
    summary = aggregate_metrics([r.metrics for r in records]).as_dict()
    reasons = [r.termination for r in records]
    summary["terminations"] = {reason: reasons.count(reason) for reason in ("collision", "offroad", "truncated")}
    summary["outcomes"] = {key: sum(r.outcomes.get(key, 0) for r in records) for key in OUTCOME_KEYS}
    summary["controller"] = config.controller.name.value
    summary["traffic"] = config.scenario.traffic
    summary["simulator"] = config.evaluation.simulator.value
    if config.experiment:
        summary["experiment"] = config.experiment
    atomic_write_text(output_dir / SUMMARY_NAME, json.dumps(summary, indent=2) + "\n")
    run.log_metrics({k: v for k, v in summary.items() if isinstance(v, float | int)})
    run.log_artifact(output_dir / EPISODES_NAME)
    run.log_artifact(output_dir / SUMMARY_NAME)
    return summary
