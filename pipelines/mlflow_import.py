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

Runs carry the tags of a live run (``stage``, ``method``, ``traffic``, ``seed``; srmpc/tracking.run_tags)
and ``variant`` (SRMPC's variant, the planner setting, the ablation's run), ``planner``, ``margin_m``
(the planner's longitudinal safety margin), ``simulator``, ``output_dir``, ``dvc_stage`` and
``dvc_lock_md5``: the MD5 of the stage's entry in ``dvc.lock`` (command, dependency and output hashes),
which changes whenever DVC reruns the stage.

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
import hashlib
import json
import math
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from srmpc.tracking import MLFLOW_BATCH_LIMIT, flatten, run_tags

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
    """The numbers of a summary.json, nested ones as ``outer/inner``."""
    metrics: dict[str, float] = {}
    for key, value in summary.items():
        if isinstance(value, dict):
            metrics.update(summary_metrics(value, f"{prefix}{key}/"))
        elif (number := _plain_number(value)) is not None:
            metrics[f"{prefix}{key}"] = number
    return metrics


def _variant(stage: str, config: dict, kind: str, directory: str) -> dict[str, str]:
    """``variant``, ``planner``, ``margin_m`` and ``simulator`` tags of a result."""
    tags: dict[str, str] = {}
    if kind == "training":
        if "/ablation/" in f"/{directory}/":
            tags["variant"] = Path(directory).name
        return tags
    planner = "default"  # the conf/planner option, from the stage's matrix values
    values = stage.split("@", 1)[1].split("-") if "@" in stage else []
    if stage.startswith("evaluate_planner_variant@"):
        planner = values[0]
    elif stage.startswith("evaluate_tradeoff@"):  # <method>-<planner>-<traffic>
        planner = values[1]
    elif stage.startswith("evaluate_confirmation@"):
        margin = (config.get("planner") or {}).get("safety_margin_longitudinal_m")
        planner = "default" if margin in (None, 8.0) else f"margin_{margin:g}m"
    tags["planner"] = planner
    margin = (config.get("planner") or {}).get("safety_margin_longitudinal_m")
    if margin is not None:
        tags["margin_m"] = str(margin)
    variants = []
    if (config.get("evaluation") or {}).get("controller") == "srmpc":
        variants.append(str((config.get("srmpc") or {}).get("variant", "paper")))
    if planner != "default":
        variants.append(planner)
    tags["variant"] = "+".join(variants) or "default"
    simulator = (config.get("evaluation") or {}).get("simulator")
    if simulator:
        tags["simulator"] = str(simulator)
    return tags


def run_name_of(kind: str, config: dict, directory: str, planner: str = "default") -> str:
    """``evaluate-<controller>[-<planner>]-<traffic>-<simulator folder>`` (the live run's name, srmpc/__main__.py,
    with the planner setting and where it ran), or ``train-<the directory under results/training>``."""
    if kind == "training":
        return "train-" + "-".join(Path(directory).parts[2:])  # results/training/<agent>/<seed> -> train-agent-seed
    controller = (config.get("evaluation") or {}).get("controller", "?")
    if controller == "srmpc":
        controller = f"srmpc-{(config.get('srmpc') or {}).get('variant', 'paper')}"
    if planner != "default":
        controller = f"{controller}-{planner}"
    return f"evaluate-{controller}-{(config.get('scenario') or {}).get('traffic', '?')}-{Path(directory).parent.name}"


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
    variant = _variant(result["stage"], config, result["kind"], result["dir"])
    name = run_name_of(result["kind"], config, result["dir"], variant.get("planner", "default"))
    tags = {**run_tags(config), **variant,
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


def import_results(client: Any, experiment_id: str, parent_run_id: str | None, lock_path: Path = ROOT / "dvc.lock",
                   root: Path = ROOT) -> dict[str, int]:
    """Import what :func:`results_of` finds that is not yet in the experiment (module docstring); returns
    the counts ``{"imported", "skipped", "superseded", "deleted"}``."""
    lock = yaml.safe_load(lock_path.read_text()) or {}
    counts = {"imported": 0, "skipped": 0, "superseded": 0, "deleted": 0}
    with _import_lock(client.tracking_uri, experiment_id):
        runs: dict[str, list[Any]] = {}
        page = None
        while True:
            batch = client.search_runs([experiment_id], filter_string="tags.output_dir LIKE '%'", max_results=1000,
                                       page_token=page)
            for run in batch:
                runs.setdefault(run.data.tags["output_dir"], []).append(run)
            page = batch.token
            if not page:
                break
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
    return counts
