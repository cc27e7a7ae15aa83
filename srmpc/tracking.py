"""MLflow tracking: one run per CLI invocation with its composed config, flat params and metrics.

The default store is SQLite (``mlflow.db``) with artifacts under ``mlruns/``, both relative to the
working directory (the repository root in every documented command). ``make ui`` serves it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

os.environ.setdefault("MLFLOW_ENABLE_ASYNC_LOGGING", "false")


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """{"a": {"b": 1}} -> {"a.b": "1"}: MLflow params from a nested config."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = str(value)
    return flat


class Run:
    """An active MLflow run, or a no-op when tracking is disabled."""

    def __init__(self, mlflow_module: Any | None) -> None:
        self._mlflow = mlflow_module

    @property
    def run_id(self) -> str | None:
        if self._mlflow is None:
            return None
        return self._mlflow.active_run().info.run_id

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        if self._mlflow is not None:
            self._mlflow.log_metrics({k: float(v) for k, v in metrics.items()}, step=step)

    def log_artifact(self, path: Path) -> None:
        if self._mlflow is not None:
            self._mlflow.log_artifact(str(path))

    def set_tags(self, tags: Mapping[str, str]) -> None:
        if self._mlflow is not None:
            self._mlflow.set_tags(dict(tags))


@contextlib.contextmanager
def tracked_run(
    enabled: bool,
    uri: str,
    artifact_location: str,
    experiment_name: str,
    run_name: str,
    params: Mapping[str, Any],
    config_yaml: str,
) -> Iterator[Run]:
    """Start a run, log ``params`` (flattened) and ``config_yaml`` as ``config.yaml``; end it FINISHED,
    or FAILED if the block raises (SystemExit from the SIGTERM handler included)."""
    if not enabled:
        yield Run(None)
        return
    import mlflow

    mlflow.set_tracking_uri(uri)
    experiment = mlflow.get_experiment_by_name(experiment_name)
    if experiment is None:
        mlflow.create_experiment(experiment_name, artifact_location=Path(artifact_location).resolve().as_uri())
    mlflow.set_experiment(experiment_name)
    with mlflow.start_run(run_name=run_name):
        mlflow.log_params(flatten(params))
        mlflow.log_text(config_yaml, "config.yaml")
        yield Run(mlflow)
