"""Every result that ``dvc.lock`` records, as MLflow runs: what ``make reproduce`` shows on a fresh clone.

A fresh clone has the committed results but an empty MLflow store (``mlflow.db`` is not committed), and
``dvc repro`` reruns nothing, so no stage logs a run. After ``dvc repro``, ``make reproduce`` calls
``python -m pipelines.mlflow_parent_run import PARENT_RUN_ID``, which reads ``dvc.lock`` and logs, as children
of the pipeline's parent run:

- one run per evaluation output directory (a directory with ``summary.json`` and ``episodes.csv``): the
  composed config (``config.yaml``) as params, the summary's numbers as metrics (J_c ``mean_event_cost``,
  rho_c ``cost_rate``, J_r ``mean_return``, ``mean_n_steps``, ``mean_vx``; ``terminations/*``,
  ``outcomes/*``), ``episodes.csv``, ``summary.json`` and ``config.yaml`` as artifacts;
- one run per training output directory (one with ``metrics.csv``): every column of ``metrics.csv`` as a
  step-wise metric over env steps (``frames``), so the chart view draws the training curves, the
  summary as ``final/*`` metrics, and its files (``policy.pt`` included) as artifacts.

What a run is comes from its directory's ``config.yaml`` alone, never from the directory's or the DVC
stage's name: an evaluation's name is its experiment and traffic, as a live run's (:func:`run_name_of`, e.g.
``confirmation/srmpc_recommended_light``); the tags are a live run's (``stage``, ``experiment``, ``method``,
``traffic``, ``seed``; srmpc/tracking.run_tags), ``margin_m`` and ``simulator``, and a training's ``variant``
(its changed agent settings). Bookkeeping
tags: ``output_dir``, ``dvc_stage`` and ``dvc_lock_md5``: the MD5 of the stage's entry in ``dvc.lock``
(command, dependency and output hashes), which changes whenever DVC reruns the stage.

Every import then tags ``results_table=true`` the run of each row of ``results/table.json`` (the current
run of that method and traffic whose numbers are the row's) and clears the tag elsewhere: the runs table's
``results`` view, which ``make ui`` opens, filters on it.

Idempotent: a directory whose FINISHED imported run has the stage's current ``dvc_lock_md5`` is skipped,
so a second ``make reproduce`` adds nothing. When the hash changed (DVC reran the stage), a new run is
imported and every earlier run of that ``output_dir`` (imported, or the stage's own live run) gets
``current=false`` and ``superseded_by=<new run id>``; the runs table shows the current results alone with
the filter ``tags.current = "true"``. An import that died half-way leaves a run that is not FINISHED; the
next import deletes it and imports the directory again. Imports of one store take turns (a file lock).
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import functools
import hashlib
import json
import math
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from pipelines.reporting import EXPERIMENTS
from srmpc.numerics import SUMMARY_KEY, mlflow_tags
from srmpc.tracking import MLFLOW_BATCH_LIMIT, RESULTS_TABLE_TAG, flatten, run_tags

ROOT = Path(__file__).resolve().parents[1]
IMPORT_TAG, CURRENT_TAG, SUPERSEDED_TAG = "dvc_lock_md5", "current", "superseded_by"
PARAMS_PER_BATCH = 100
"""Most params that one MLflow ``log_batch`` call takes."""


def stage_md5(entry: dict) -> str:
    """MD5 of a stage's ``dvc.lock`` entry: its command and the hashes of its dependencies and outputs."""
    return hashlib.md5(json.dumps(entry, sort_keys=True).encode()).hexdigest()


def results_of(lock: dict, root: Path = ROOT) -> list[dict]:
    """Each evaluation and training output directory that ``lock`` (dvc.lock, parsed) records and that is
    on disk: ``{"kind", "dir" (relative to root), "stage", "md5"}``, in dvc.lock's order."""
    found: list[dict] = []
    for stage, entry in (lock.get("stages") or {}).items():
        md5, outs = stage_md5(entry), [out["path"] for out in entry.get("outs") or []]
        directories = {str(Path(path).parent) for path in outs if Path(path).name == "summary.json"}
        directories = sorted(d for d in directories if f"{d}/episodes.csv" in outs)
        for directory in directories:
            found.append({"kind": "evaluation", "dir": directory, "stage": stage, "md5": md5})
        for path in outs:
            if (root / path / "metrics.csv").is_file():
                found.append({"kind": "training", "dir": path, "stage": stage, "md5": md5})
    return [r for r in found if (root / r["dir"]).is_dir()]


def _plain_number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def summary_metrics(summary: dict, prefix: str = "") -> dict[str, float]:
    """The numbers of a summary.json, nested ones as ``outer/inner``; not those of the run's ``environment`` record
    (srmpc.numerics: the machine, not a result; imported as tags)."""
    metrics: dict[str, float] = {}
    for key, value in summary.items():
        if not prefix and key == SUMMARY_KEY:
            continue
        if isinstance(value, dict):
            metrics.update(summary_metrics(value, f"{prefix}{key}/"))
        elif (number := _plain_number(value)) is not None:
            metrics[f"{prefix}{key}"] = number
    return metrics


@functools.lru_cache(maxsize=8)
def _agent_defaults(name: str) -> dict[str, Any]:
    """The ``agent`` section that ``agent=<name>`` composes ({} when conf/agent has no such option)."""
    from omegaconf import OmegaConf

    from srmpc.config.compose import ConfigError, compose_config

    try:
        return OmegaConf.to_container(compose_config([f"agent={name}"]), resolve=True)["agent"]
    except ConfigError:
        return {}


def _number(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def training_setting(config: dict) -> str:
    """What a training's ``agent`` section changes from its agent's defaults (``agent=<name>``), as
    ``key=value`` joined by ``,`` in the config's order (``cost_gamma=0,multiplier_lr=0.001``), or
    ``default``. The seed, the task and where it writes are not settings."""
    agent = config.get("agent") or {}
    defaults = _agent_defaults(str(agent.get("name")))
    changed = [f"{key}={_number(value)}" for key, value in agent.items()
               if key in defaults and key not in ("seed", "task", "output_dir") and value != defaults[key]]
    return ",".join(changed) or "default"


def result_tags(config: dict, kind: str) -> dict[str, str]:
    """``margin_m`` and ``simulator`` tags of an evaluation, and a training's ``variant`` (its changed agent
    settings, :func:`training_setting`), read from its composed config alone."""
    if kind == "training":
        return {"variant": training_setting(config)}
    tags = {}
    margin = (config.get("planner") or {}).get("safety_margin_longitudinal_m")
    if margin is not None:
        tags["margin_m"] = str(margin)
    simulator = (config.get("evaluation") or {}).get("simulator")
    if simulator:
        tags["simulator"] = str(simulator)
    return tags


def run_name_of(kind: str, config: dict) -> str:
    """A result's run name, from its config: an evaluation's ``<experiment>_<traffic>`` (a live run's name, its
    folder's); ``train-<agent>-seed_<n>`` with ``-<changed settings>`` for a training that changes its agent's
    defaults."""
    tags = run_tags(config)
    if kind == "training":
        setting = training_setting(config)
        return f"train-{tags.get('method', '?')}-seed_{tags.get('seed', '?')}" + (
            f"-{setting}" if setting != "default" else "")
    return f"{tags.get('experiment', '?')}_{tags.get('traffic', '?')}"


def _training_metrics(path: Path, Metric: Any) -> list[Any]:
    """Every numeric cell of metrics.csv as a metric at step ``frames`` (env steps)."""
    metrics, start_ms = [], int(time.time() * 1000)
    with path.open(newline="") as handle:
        for row in csv.DictReader(handle):
            try:
                step = int(float(row["frames"]))
            except (KeyError, TypeError, ValueError):
                continue
            try:
                stamp = start_ms + int(float(row.get("wall_s") or 0) * 1000)
            except ValueError:
                stamp = start_ms
            for key, text in row.items():
                try:
                    value = float(text)
                except (TypeError, ValueError):
                    continue
                if math.isfinite(value) and key not in ("frames",):
                    metrics.append(Metric(key, value, stamp, step))
    return metrics


def import_result(client: Any, experiment_id: str, parent_run_id: str | None, result: dict, root: Path = ROOT) -> str:
    """Log one result directory as a FINISHED run; returns its id (the run is FINISHED only once complete)."""
    from mlflow.entities import Metric, Param
    from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID, MLFLOW_RUN_NAME

    directory = root / result["dir"]
    config_path = directory / "config.yaml"
    config = yaml.safe_load(config_path.read_text()) if config_path.is_file() else {}
    config = config if isinstance(config, dict) else {}
    if result["kind"] == "training":
        config.setdefault("stage", "train")
    name = run_name_of(result["kind"], config)
    tags = {**run_tags(config), **result_tags(config, result["kind"]),
            "output_dir": result["dir"], "dvc_stage": result["stage"], IMPORT_TAG: result["md5"], CURRENT_TAG: "true",
            "imported_from": "dvc.lock", MLFLOW_RUN_NAME: name}
    if parent_run_id:
        tags[MLFLOW_PARENT_RUN_ID] = parent_run_id
    run_id = client.create_run(experiment_id, run_name=name, tags=tags).info.run_id
    params = [Param(k, v[:6000]) for k, v in flatten(config).items()]
    for start in range(0, len(params), PARAMS_PER_BATCH):
        client.log_batch(run_id, params=params[start:start + PARAMS_PER_BATCH])
    now = int(time.time() * 1000)
    summary_path = directory / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    if isinstance(summary.get(SUMMARY_KEY), dict):  # the machine that made it, as the run itself tagged it
        for key, value in mlflow_tags(summary[SUMMARY_KEY]).items():
            client.set_tag(run_id, key, value)
    if result["kind"] == "training":
        metrics = _training_metrics(directory / "metrics.csv", Metric)
        metrics += [Metric(f"final/{k}", v, now, 0) for k, v in summary_metrics(summary).items()]
    else:
        metrics = [Metric(k, v, now, 0) for k, v in summary_metrics(summary).items()]
    for start in range(0, len(metrics), MLFLOW_BATCH_LIMIT):
        client.log_batch(run_id, metrics=metrics[start:start + MLFLOW_BATCH_LIMIT])
    for path in sorted(directory.iterdir()):
        if path.is_file() and not path.name.startswith(".") and not path.name.endswith((".tmp", "last.pt")):
            client.log_artifact(run_id, str(path))
    client.set_terminated(run_id, "FINISHED")
    return run_id


@contextlib.contextmanager
def _import_lock(uri: str, experiment_id: str) -> Iterator[None]:
    key = hashlib.sha256(f"{uri}\n{experiment_id}".encode()).hexdigest()[:16]
    with (Path(tempfile.gettempdir()) / f"srmpc-mlflow-import-{key}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _result_runs(client: Any, experiment_id: str) -> dict[str, list[Any]]:
    """The experiment's runs of result directories (tag ``output_dir``), by directory."""
    runs: dict[str, list[Any]] = {}
    page = None
    while True:
        batch = client.search_runs([experiment_id], filter_string="tags.output_dir LIKE '%'", max_results=1000,
                                   page_token=page)
        for run in batch:
            runs.setdefault(run.data.tags["output_dir"], []).append(run)
        page = batch.token
        if not page:
            return runs


TABLE_NUMBERS = ("episodes", "mean_event_cost", "cost_rate", "mean_return", "mean_n_steps", "mean_vx")
"""The numbers a run must share with a row of ``results/table.json`` to be that row's run."""


def table_row_of(run: Any, table: dict) -> tuple[str, str] | None:
    """(traffic, method) of the row of ``table`` (results/table.json, parsed) that ``run`` is: the row of its
    ``traffic`` and ``experiment`` tags (reporting.EXPERIMENTS) whose numbers (:data:`TABLE_NUMBERS`) all equal the
    run's metrics."""
    tags, metrics = run.data.tags, run.data.metrics
    method = next((m for m, experiment in EXPERIMENTS.items() if experiment == tags.get("experiment")), None)
    row = (table.get(tags.get("traffic")) or {}).get(method)
    if not isinstance(row, dict):
        return None
    for key in TABLE_NUMBERS:
        if key not in row or key not in metrics or not math.isclose(float(row[key]), metrics[key],
                                                                    rel_tol=1e-12, abs_tol=1e-15):
            return None
    return tags["traffic"], method


def mark_table_rows(client: Any, experiment_id: str, table_path: Path) -> tuple[int, int]:
    """Tag ``results_table=true`` the current FINISHED runs that are rows of the results table (each row's
    run, :func:`table_row_of`), and remove the tag from every other run; returns (rows with a run, rows).
    The runs table's ``results`` view (srmpc/tracking.py) filters on that tag."""
    table = json.loads(table_path.read_text()) if table_path.is_file() else {}
    rows = {(traffic, method) for traffic, methods in table.items() for method in (methods or {})}
    found = set()
    for runs in _result_runs(client, experiment_id).values():
        for run in runs:
            row = None
            if (run.info.lifecycle_stage == "active" and run.info.status == "FINISHED"
                    and run.data.tags.get(CURRENT_TAG) != "false"):
                row = table_row_of(run, table)
            marked = run.data.tags.get(RESULTS_TABLE_TAG) == "true"
            if row is not None:
                found.add(row)
                if not marked:
                    client.set_tag(run.info.run_id, RESULTS_TABLE_TAG, "true")
            elif RESULTS_TABLE_TAG in run.data.tags:
                client.delete_tag(run.info.run_id, RESULTS_TABLE_TAG)
    return len(found & rows), len(rows)


def import_results(client: Any, experiment_id: str, parent_run_id: str | None, lock_path: Path = ROOT / "dvc.lock",
                   root: Path = ROOT, table_path: Path | None = None) -> dict[str, int]:
    """Import what :func:`results_of` finds that is not yet in the experiment (module docstring), then mark
    the rows of the results table (``table_path``, default ``<root>/results/table.json``:
    :func:`mark_table_rows`); returns the counts ``{"imported", "skipped", "superseded", "deleted",
    "table_rows", "table_rows_with_run"}``."""
    lock = yaml.safe_load(lock_path.read_text()) or {}
    counts = {"imported": 0, "skipped": 0, "superseded": 0, "deleted": 0}
    with _import_lock(client.tracking_uri, experiment_id):
        runs = _result_runs(client, experiment_id)
        for result in results_of(lock, root):
            earlier = runs.get(result["dir"], [])
            if any(r.data.tags.get(IMPORT_TAG) == result["md5"] and r.info.status == "FINISHED"
                   and r.data.tags.get(CURRENT_TAG) != "false" for r in earlier):
                counts["skipped"] += 1
                continue
            for run in earlier:
                if run.data.tags.get(IMPORT_TAG) and run.info.status != "FINISHED":  # an import that died
                    client.delete_run(run.info.run_id)
                    counts["deleted"] += 1
            run_id = import_result(client, experiment_id, parent_run_id, result, root)
            counts["imported"] += 1
            for run in earlier:
                if run.info.lifecycle_stage == "active" and run.data.tags.get(CURRENT_TAG) != "false" and not (
                        run.data.tags.get(IMPORT_TAG) and run.info.status != "FINISHED"):
                    client.set_tag(run.info.run_id, CURRENT_TAG, "false")
                    client.set_tag(run.info.run_id, SUPERSEDED_TAG, run_id)
                    counts["superseded"] += 1
        counts["table_rows_with_run"], counts["table_rows"] = mark_table_rows(
            client, experiment_id, table_path or root / "results" / "table.json")
    return counts
