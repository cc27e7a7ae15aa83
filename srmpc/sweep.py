"""Hydra multirun (``python -m srmpc -m ...``): where each job writes, and the MLflow store its jobs share.

A sweep's jobs run at once (``hydra/launcher=local``: processes on this machine; ``hydra/launcher=slurm``:
a SLURM job array), each a normal run with its own output directory and MLflow run:

- Output: a job's directory is Hydra's ``hydra.runtime.output_dir``. With the launchers in
  ``conf/hydra/launcher/`` it is ``multirun/<the job's overrides>`` (``conf/hydra/resumable_sweep.yaml``),
  the same every time the same job runs, so a resubmitted or requeued job resumes there: training from
  ``last.pt``, evaluation from ``episodes.csv``. Training writes there unless ``agent.output_dir`` is set
  (a single run's default, ``results/training/<agent.name>``, would be shared by every job of a seed sweep).
- MLflow: the first job creates the SQLite store and the experiment under a file lock; parallel
  processes that race to create one fail (MLflow's schema migrations collide).
"""

from __future__ import annotations

import fcntl
import hashlib
import tempfile
from pathlib import Path

from srmpc.config.schema import TrackingConfig

SQLITE_PREFIX = "sqlite:///"


MULTIRUN_FLAGS = ("-m", "--multirun")


def sweep_jobs(args: list[str]) -> list[list[str]]:
    """Each job's overrides (``hydra.*`` left out) of ``python -m srmpc -m <args>``, to validate before any
    job starts; [] when ``args`` is not a multirun, has other Hydra flags, or sweeps in a way only Hydra
    can expand (``glob``, intervals): Hydra then checks what it can and each job the rest."""
    if not any(arg in MULTIRUN_FLAGS for arg in args):
        return []
    if any(arg.startswith("-") and arg not in MULTIRUN_FLAGS for arg in args):
        return []
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    task = [arg for arg in args if arg not in MULTIRUN_FLAGS and not arg.lstrip("+~").startswith("hydra")]
    try:
        (jobs,) = BasicSweeper.split_arguments(OverridesParser.create().parse_overrides(task), None)
    except (HydraException, ValueError):
        return []
    return jobs


def in_multirun() -> bool:
    """Whether this process runs one job of a Hydra multirun."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode is RunMode.MULTIRUN


def job_output_dir() -> Path:
    """The Hydra job's output directory (``hydra.runtime.output_dir``)."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def prepare_tracking_store(tracking: TrackingConfig, ensure_experiment: bool = True) -> None:
    """Create ``tracking.uri``'s SQLite store and ``tracking.experiment_name`` once, under a lock that
    every process that may start beside others on this machine takes: a sweep's jobs, and the trainings
    that ``pipelines/train_runs.py`` runs side by side (no-op for other stores and when tracking is off).
    Without ``ensure_experiment`` an existing store is left as it is (the lock only waits for its
    creator to finish), which costs no MLflow client."""
    if not tracking.enabled or not tracking.uri.startswith(SQLITE_PREFIX):
        return
    database = Path(tracking.uri.removeprefix(SQLITE_PREFIX)).resolve()
    key = hashlib.sha256(str(database).encode()).hexdigest()[:16]
    lock_path = Path(tempfile.gettempdir()) / f"srmpc-mlflow-{key}.lock"
    with lock_path.open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if database.exists() and not ensure_experiment:
            return
        import mlflow

        client = mlflow.MlflowClient(tracking_uri=tracking.uri)  # creates the store
        if client.get_experiment_by_name(tracking.experiment_name) is None:  # the run adds the experiment's tags
            client.create_experiment(tracking.experiment_name,
                                     artifact_location=Path(tracking.artifact_location).resolve().as_uri())
