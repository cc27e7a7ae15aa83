"""MLflow tracking: one run per CLI invocation with its composed config, flat params and metrics.

The default store is SQLite (``mlflow.db``) with artifacts under ``mlruns/``, both relative to the
working directory (the repository root in every documented command). ``make ui`` serves it.

Experiments carry the tag ``mlflow.experimentKind=custom_model_development`` (set on creation and on
every run start), which marks them as model training rather than GenAI. MLflow 3.17's UI itself picks
its view by a switch of its own, so :func:`runs_table_url` names it. Runs are tagged ``stage``,
``experiment`` (a published run's identity, also its name), ``method``, ``traffic`` and ``seed``. When
the environment variable ``SRMPC_PARENT_RUN_ID`` names a run of the same store and experiment, the run
is nested under it: ``make reproduce`` starts one parent run per pipeline invocation
(``pipelines/mlflow_parent_run.py``) and every DVC stage's ``python -m srmpc`` becomes its child;
without the variable (or with an unknown id) a run stands alone.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from collections.abc import Iterable, Iterator, Mapping
from enum import Enum
from pathlib import Path
from typing import Any

os.environ.setdefault("MLFLOW_ENABLE_ASYNC_LOGGING", "false")

MLFLOW_BATCH_LIMIT = 1000
"""Most metric values that one MLflow ``log_batch`` call takes."""
METRICS_FLUSH_S = 5.0
"""How long :class:`Run` buffers metrics before writing them (the MLflow UI lags by at most this)."""
PARENT_RUN_ENV = "SRMPC_PARENT_RUN_ID"
"""Environment variable holding the id of the run that new runs nest under (see the module doc)."""
RESULTS_TABLE_TAG = "results_table"
"""Tag (value ``"true"``) of the current run whose numbers are a row of ``results/table.json``
(pipelines/mlflow_import.py sets and clears it on every import)."""
RESULTS_VIEW, METRICS_VIEW = "results", "metrics"
"""Share keys of the two runs-table views every experiment carries (see :data:`EXPERIMENT_TAGS`)."""
RUNS_TABLE_COLUMNS = [f"tags.`{tag}`" for tag in ("method", "traffic")] + [
    f"metrics.`{metric}`" for metric in ("mean_event_cost", "mean_vx", "cost_rate", "mean_return", "mean_n_steps")
] + [f"tags.`{tag}`" for tag in ("experiment", "simulator", "seed")]
"""The views' columns, left to right: the run's method and traffic, then J_c, v_x, rho_c, J_r, n_steps, then
its experiment, simulator and seed (MLflow shows no metric by default). The list is both the views'
``selectedColumns`` (which columns) and ``columnOrder`` (their order: without it the grid lists the
metric columns alphabetically and the tag columns after them); MLflow 3.17's runs table applies
``columnOrder`` (ag-grid column ids, the same ``tags.`x```/``metrics.`x``` keys) to the columns it shows."""
RESULTS_FILTER = f'tags.{RESULTS_TABLE_TAG} = "true"'
"""The results view's filter: the runs of the table's rows. The pipeline's parent run does not match, so
its children are listed flat (the UI nests a child only under a parent it lists)."""


def _saved_view(name: str, state: Mapping[str, Any]) -> str:
    """An experiment tag value the runs table opens as a saved view (MLflow 3.17's envelope: ``name``,
    ``createdAt`` and the view state as a JSON string). The state holds UI fields (``selectedColumns``,
    ``columnOrder``)
    and search facets (``searchFilter``, ``orderByKey``, ``orderByAsc``); the UI writes the facets into
    the URL when it opens the view."""
    return json.dumps({"name": name, "createdAt": 0, "updatedAt": 0, "state": json.dumps(dict(state))})


EXPERIMENT_TAGS = {
    "mlflow.experimentKind": "custom_model_development",
    f"mlflow.sharedViewState.{RESULTS_VIEW}": _saved_view("Results table", {
        "selectedColumns": RUNS_TABLE_COLUMNS, "columnOrder": RUNS_TABLE_COLUMNS, "searchFilter": RESULTS_FILTER,
        "orderByKey": "tags.`mlflow.runName`", "orderByAsc": True}),
    f"mlflow.sharedViewState.{METRICS_VIEW}": _saved_view("All runs, paper metrics", {
        "selectedColumns": RUNS_TABLE_COLUMNS, "columnOrder": RUNS_TABLE_COLUMNS}),
}
"""Marks an experiment as model development, and stores two runs-table views (the UI's "Views" menu):
``results``, the rows of ``results/table.json`` by run name with the paper's metrics as columns, and
``metrics``, every run with those columns."""


SERVER_CHECK_TIMEOUT_S = 5.0
"""How long :func:`check_tracking_server` waits for an HTTP tracking server's ``/health``."""


SQLITE_HEADER = b"SQLite format 3\x00"
"""The first 16 bytes of every SQLite database file (an empty file is a new, empty database too)."""


class TrackingStoreUnusable(RuntimeError):
    """``tracking.uri`` names a store no run can use; the message is one line naming the key and the store."""


class TrackingServerUnreachable(TrackingStoreUnusable):
    """``tracking.uri`` names an HTTP server that does not answer; the message is one line naming it."""


def sqlite_store_path(uri: str) -> Path | None:
    """The file of a ``sqlite:///<path>`` URI (SQLAlchemy's form: three slashes and a relative path, four
    and an absolute one; a ``?query`` dropped), or None for any other store or an in-memory database."""
    if not uri.lower().startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):].split("?", 1)[0]
    return None if path in ("", ":memory:") else Path(path)


def check_tracking_store(uri: str, timeout_s: float = SERVER_CHECK_TIMEOUT_S) -> None:
    """Refuse, before anything is written, a ``tracking.uri`` whose store cannot take a run: an HTTP
    server that does not answer (:func:`check_tracking_server`), or a SQLite path that is a folder, a file
    that is not an SQLite database, or a file in a folder that does not exist. MLflow itself would end
    in a SQLAlchemy traceback after its migrations start; this raises :class:`TrackingStoreUnusable`
    with one line. Other stores (a local folder, ``databricks``) are left to MLflow."""
    path = sqlite_store_path(uri)
    if path is None:
        check_tracking_server(uri, timeout_s)
        return
    problem = None
    if path.is_dir():
        problem = f"{path} is a folder, not an SQLite database file"
    elif path.exists():
        try:
            with path.open("rb") as file:
                header = file.read(len(SQLITE_HEADER))
        except OSError as error:
            problem = f"{path} cannot be read ({error.strerror or error})"
        else:
            if header and header != SQLITE_HEADER:
                problem = f"{path} is not an SQLite database (its first bytes are not SQLite's header)"
    elif not path.parent.is_dir():
        problem = f"the folder of {path} does not exist"
    if problem is not None:
        raise TrackingStoreUnusable(
            f"tracking.uri={uri}: {problem}; name a new or an existing MLflow .db file, "
            "or run without tracking: tracking.enabled=false")


def check_tracking_server(uri: str, timeout_s: float = SERVER_CHECK_TIMEOUT_S) -> None:
    """For an ``http(s)://`` ``tracking.uri``, one ``GET <uri>/health`` (what ``mlflow server`` answers
    200 to) within ``timeout_s``; raise :class:`TrackingServerUnreachable` unless it answers 200. Other
    stores (SQLite, a local folder) are not checked.

    MLflow's own client retries a refused connection with backoff for minutes, printing a urllib3
    WARNING per attempt, then fails with a traceback; a run checks once, before it writes anything."""
    import urllib.error
    import urllib.parse
    import urllib.request

    if urllib.parse.urlsplit(uri).scheme.lower() not in ("http", "https"):
        return
    url = uri.rstrip("/") + "/health"
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            if response.status == 200:
                return
            reason = f"HTTP {response.status}"
    except urllib.error.HTTPError as error:
        reason = f"HTTP {error.code} {error.reason}"
    except urllib.error.URLError as error:
        reason = str(getattr(error.reason, "strerror", None) or error.reason)
    except (OSError, ValueError) as error:  # a timeout, a malformed URI (bad port)
        reason = str(error) or type(error).__name__
    raise TrackingServerUnreachable(
        f"tracking.uri={uri}: no MLflow server answers (GET {url} within {timeout_s:g} s: {reason}); "
        "start it, or run without tracking: tracking.enabled=false")


def runs_table_url(base: str, experiment_id: str, view: str = RESULTS_VIEW) -> str:
    """The MLflow UI's runs table of an experiment, opened on the saved view ``view`` (:data:`EXPERIMENT_TAGS`).
    MLflow 3.17's UI picks its GenAI or model-training view by a switch of its own (``workflowType``), not
    by the experiment's kind, so the URL names it. The path ends in ``/runs``: the UI redirects
    ``/experiments/<id>`` there and drops ``viewStateShareKey`` on the way."""
    return (f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs"
            f"?viewStateShareKey={view}&workflowType=machine_learning")


def config_spelling(value: Any) -> Any:
    """``value`` as the config files spell it: an Enum of the structured config by its member's name
    (``ControllerName.ltv_mpc`` -> ``ltv_mpc``, what ``conf/`` writes and ``OmegaConf.to_yaml`` prints),
    inside lists and tuples too; anything else unchanged."""
    if isinstance(value, Enum):
        return value.name
    if isinstance(value, list | tuple):
        return [config_spelling(item) for item in value]
    return value


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """{"a": {"b": 1}} -> {"a.b": "1"}: MLflow params from a nested config, each value spelled as the config
    files spell it (:func:`config_spelling`), so that a filter such as ``params.controller.name = 'ltv_mpc'``
    finds the run."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = str(config_spelling(value))
    return flat


NAMED_BY_BASE = ("experiment", "scenario", "stage")
"""Override keys (``+``/``~`` prefixes dropped) that a run's base name already says: its experiment, its
traffic level (the ``scenario`` group's option) and its stage; :func:`run_name` leaves them out."""
NOT_NAMED = ("hydra", "tracking", "evaluation.output_dir", "evaluation.workers", "agent.output_dir")
"""Override keys, and the keys below them, that change where or how a run is made, not its results (Hydra's own
settings, MLflow, the output folder, the worker count): :func:`run_name` leaves them out."""


def named_overrides(overrides: Iterable[str], also_named: Iterable[str] = ()) -> list[str]:
    """The command-line ``overrides`` (``key=value``, Hydra's task overrides) that a run's name carries, in their
    order: all but those of :data:`NAMED_BY_BASE`, ``also_named`` (more keys its base name says) and
    :data:`NOT_NAMED`."""
    said = (*NAMED_BY_BASE, *also_named)
    kept = []
    for override in overrides:
        key = override.lstrip("+~").partition("=")[0]
        if key in said or any(key == k or key.startswith(f"{k}.") for k in NOT_NAMED):
            continue
        kept.append(override)
    return kept


def run_name(base: str, overrides: Iterable[str], also_named: Iterable[str] = ()) -> str:
    """A run's MLflow name: ``base`` (its identity: ``<experiment>_<traffic>``, or its stage, method and traffic),
    then the overrides beyond it (:func:`named_overrides`), so that the runs of a sweep are told apart in the runs
    list: ``python -m srmpc -m +experiment=smoke controller=srmpc,ltv_mpc`` names ``smoke_light controller=srmpc``
    and ``smoke_light controller=ltv_mpc``. A DVC stage's run (``+experiment=<path> scenario=<traffic>``) is
    named ``base`` alone, its folder's name."""
    return " ".join([base, *named_overrides(overrides, also_named)])


def _plain(value: Any) -> Any:
    return getattr(value, "value", value)  # an Enum of the structured config -> its value


def run_tags(params: Mapping[str, Any]) -> dict[str, str]:
    """``stage``, ``experiment``, ``method``, ``traffic`` and ``seed`` of a run, from its composed config, for
    filtering and grouping in the UI. experiment: the run's identity (``+experiment=<path>``); method: the agent
    (training) or the controller (``controller.name``, a policy controller's agent: ``policy-ppo_sb3``)."""
    stage = _plain(params.get("stage"))
    scenario, agent = params.get("scenario") or {}, params.get("agent") or {}
    evaluation, controller = params.get("evaluation") or {}, params.get("controller") or {}
    if stage in ("train", "train_sb3"):
        method, seed = _plain(agent.get("name")), agent.get("seed")
    else:
        method, seed = _plain(controller.get("name")), evaluation.get("seed")
        if method == "policy":
            method = f"policy-{controller.get('policy')}"
    tags = {"stage": stage, "experiment": params.get("experiment"), "method": method,
            "traffic": _plain(scenario.get("traffic")), "seed": seed}
    return {key: str(value) for key, value in tags.items() if value not in (None, "")}


def ensure_experiment(client: Any, name: str, artifact_location: str) -> str:
    """The id of experiment ``name``, created with :data:`EXPERIMENT_TAGS` if missing; an existing one
    gets the tags it lacks."""
    experiment = client.get_experiment_by_name(name)
    if experiment is None:
        return client.create_experiment(name, artifact_location=Path(artifact_location).resolve().as_uri(),
                                        tags=EXPERIMENT_TAGS)
    for key, value in EXPERIMENT_TAGS.items():
        if experiment.tags.get(key) != value:
            client.set_experiment_tag(experiment.experiment_id, key, value)
    return experiment.experiment_id


def parent_run_id(client: Any, experiment_id: str) -> str | None:
    """The run named by ``$SRMPC_PARENT_RUN_ID`` if it exists, is not deleted and belongs to
    ``experiment_id``; otherwise None, with a warning when the variable was set."""
    run_id = os.environ.get(PARENT_RUN_ENV, "").strip()
    if not run_id:
        return None
    try:
        parent = client.get_run(run_id)
    except Exception:  # noqa: BLE001  (MlflowException or a malformed id): run standalone
        parent = None
    if parent is None or parent.info.lifecycle_stage == "deleted" or parent.info.experiment_id != experiment_id:
        print(f"srmpc: {PARENT_RUN_ENV}={run_id} is not a run of this experiment; the run stands alone",
              file=sys.stderr)
        return None
    return run_id


def start_parent_run(uri: str, experiment_name: str, artifact_location: str, run_name: str,
                     tags: Mapping[str, str] | None = None) -> str:
    """Create a RUNNING run for child processes to nest under (pass its id in ``$SRMPC_PARENT_RUN_ID``);
    returns its id. Creating the experiment here, once, also spares the children a race on a new store."""
    import mlflow
    from mlflow.utils.mlflow_tags import MLFLOW_RUN_NAME

    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment_id = ensure_experiment(client, experiment_name, artifact_location)
    run = client.create_run(experiment_id, run_name=run_name, tags={MLFLOW_RUN_NAME: run_name, **(tags or {})})
    return run.info.run_id


def finish_parent_run(uri: str, run_id: str, artifacts: Iterable[tuple[str, Path]], succeeded: bool) -> None:
    """Log each existing file or folder of ``artifacts`` ((artifact folder, local path) pairs) to the parent
    run, then end it FINISHED or FAILED."""
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=uri)
    for folder, path in artifacts:
        if path.is_dir():
            client.log_artifacts(run_id, str(path), folder or None)
        elif path.is_file():
            client.log_artifact(run_id, str(path), folder or None)
    client.set_terminated(run_id, "FINISHED" if succeeded else "FAILED")


class Run:
    """An active MLflow run, or a no-op when tracking is disabled.

    Metrics are buffered and written by one MLflow ``log_batch`` at most every ``flush_every_s`` seconds
    (or per :data:`MLFLOW_BATCH_LIMIT` values): one ``mlflow.log_metrics`` call is one SQLite
    transaction, 33 ms of wall time and 8.6 ms of CPU for 5 metrics (measured on the project's 2-core
    machine), and an evaluation's parent process paid it once per episode, most of a 1000-episode
    PPO-L-SI evaluation's 43 s. :meth:`flush` also runs before an artifact is logged and when the run
    ends, finished or failed; a process killed outright loses at most ``flush_every_s`` of metrics
    (``episodes.csv`` and ``metrics.csv`` have them all).
    """

    def __init__(self, mlflow_module: Any | None, flush_every_s: float = METRICS_FLUSH_S) -> None:
        self._mlflow = mlflow_module
        self.flush_every_s = flush_every_s
        self._pending: list[Any] = []
        self._last_flush = time.monotonic()

    @property
    def run_id(self) -> str | None:
        if self._mlflow is None:
            return None
        return self._mlflow.active_run().info.run_id

    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        if self._mlflow is None:
            return
        from mlflow.entities import Metric

        timestamp = int(time.time() * 1000)
        step = 0 if step is None else int(step)  # MLflow's own default step
        self._pending.extend(Metric(key, float(value), timestamp, step) for key, value in metrics.items())
        if len(self._pending) >= MLFLOW_BATCH_LIMIT or time.monotonic() - self._last_flush >= self.flush_every_s:
            self.flush()

    def flush(self) -> None:
        """Write the buffered metrics now."""
        pending, self._pending = self._pending, []
        self._last_flush = time.monotonic()
        if self._mlflow is None or not pending:
            return
        client, run_id = self._mlflow.MlflowClient(), self.run_id
        for start in range(0, len(pending), MLFLOW_BATCH_LIMIT):
            client.log_batch(run_id, metrics=pending[start:start + MLFLOW_BATCH_LIMIT])

    def log_artifact(self, path: Path) -> None:
        if self._mlflow is not None:
            self.flush()
            self._mlflow.log_artifact(str(path))

    def set_tags(self, tags: Mapping[str, str]) -> None:
        if self._mlflow is not None:
            self._mlflow.set_tags(dict(tags))


PID_TAG, HOST_TAG = "srmpc.pid", "srmpc.host"
"""Run tags naming the process that runs it, so a later start can tell a killed run from a live one."""


def process_tags() -> dict[str, str]:
    """:data:`PID_TAG` and :data:`HOST_TAG` of this process."""
    return {PID_TAG: str(os.getpid()), HOST_TAG: socket.gethostname()}


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def fail_stale_runs(client: Any, experiment_id: str, run_name: str) -> list[str]:
    """End FAILED every RUNNING run named ``run_name`` whose process, on this host, is gone; return their ids.

    A SIGTERM ends a run FAILED from inside; a SIGKILL (or a power cut) leaves it RUNNING for ever, so the
    next start of a run of the same name cleans up. A recycled pid keeps a dead run RUNNING (never the reverse).
    """
    host, stale = socket.gethostname(), []
    for run in client.search_runs([experiment_id], filter_string="attributes.status = 'RUNNING'", max_results=1000):
        tags = run.data.tags
        if run.info.run_name != run_name or tags.get(HOST_TAG) != host or not tags.get(PID_TAG, "").isdigit():
            continue
        if not _process_alive(int(tags[PID_TAG])):
            client.set_terminated(run.info.run_id, "FAILED")
            stale.append(run.info.run_id)
    return stale


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
    or FAILED if the block raises (SystemExit from the SIGTERM handler included). Runs of the same name
    left RUNNING by a killed process are first ended FAILED (:func:`fail_stale_runs`)."""
    if not enabled:
        yield Run(None)
        return
    import mlflow

    mlflow.set_tracking_uri(uri)
    client = mlflow.MlflowClient()
    experiment_id = ensure_experiment(client, experiment_name, artifact_location)
    mlflow.set_experiment(experiment_id=experiment_id)
    parent = parent_run_id(client, experiment_id)
    fail_stale_runs(client, experiment_id, run_name)
    with mlflow.start_run(run_name=run_name, parent_run_id=parent, tags={**run_tags(params), **process_tags()}):
        mlflow.log_params(flatten(params))
        mlflow.log_text(config_yaml, "config.yaml")
        run = Run(mlflow)
        try:
            yield run
        finally:
            run.flush()  # the buffered metrics, before the run is ended (FINISHED or FAILED)
