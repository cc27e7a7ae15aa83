"""An HTTP ``tracking.uri``: a server that does not answer is one line (exit 2, nothing written, no retry
WARNINGs); a real ``mlflow server`` takes the run's params, metrics and artifacts (slow: it starts in ~20 s).
A SQLite ``tracking.uri`` that is no database (a folder, another file, a missing folder) is one line too."""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from srmpc.tracking import (
    PARENT_RUN_ENV,
    TrackingServerUnreachable,
    TrackingStoreUnusable,
    check_tracking_server,
    check_tracking_store,
)
from tests.mlflow_server import free_port, serve_mlflow

ROOT = Path(__file__).resolve().parents[1]


def _smoke(tmp_path: Path, uri: str, experiment: str = "srmpc-server-test") -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "srmpc", "+experiment=smoke", f"tracking.uri={uri}",
               f"tracking.artifact_location={tmp_path / 'mlruns'}", f"tracking.experiment_name={experiment}",
               f"evaluation.output_dir={tmp_path / 'eval'}", f"hydra.run.dir={tmp_path / 'hydra'}"]
    env = {k: v for k, v in os.environ.items() if k != PARENT_RUN_ENV}
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)


def test_unreachable_server_is_one_line_and_writes_nothing(tmp_path):
    uri = f"http://127.0.0.1:{free_port()}"
    result = _smoke(tmp_path, uri)
    assert result.returncode == 2, result.stderr[-3000:]
    assert result.stderr.strip().splitlines() == [
        f"srmpc: error: tracking.uri={uri}: no MLflow server answers (GET {uri}/health within 5 s: Connection refused)"
        "; start it, or run without tracking: tracking.enabled=false"]
    assert not (tmp_path / "eval").exists() and not (tmp_path / "hydra").exists()
    assert not (tmp_path / "mlruns").exists()


class _Unhealthy(http.server.BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802  (http.server's name)
        self.send_response(503)
        self.end_headers()

    def log_message(self, *args):
        pass


def test_a_server_that_answers_but_not_healthy_is_refused():
    server = http.server.HTTPServer(("127.0.0.1", 0), _Unhealthy)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    uri = f"http://127.0.0.1:{server.server_address[1]}/"
    try:
        with pytest.raises(TrackingServerUnreachable, match=rf"^tracking.uri={uri}: no MLflow server answers "
                                                            rf"\(GET {uri}health within 5 s: HTTP 503"):
            check_tracking_server(uri)
    finally:
        server.shutdown()
        server.server_close()
    check_tracking_server("sqlite:///never-opened.db")  # only HTTP stores are checked
    with pytest.raises(TrackingServerUnreachable, match="http://127.0.0.1:99999999"):
        check_tracking_server("http://127.0.0.1:99999999")  # a malformed URI is one line too



def _unusable_stores(tmp_path: Path) -> dict[str, tuple[str, str]]:
    """name -> (tracking.uri, what the one-line error says about it)."""
    not_a_database = tmp_path / "notes.db"
    not_a_database.write_text("not a database\n")
    folder = tmp_path / "a_folder"
    folder.mkdir()
    return {
        "text file": (f"sqlite:///{not_a_database}", f"{not_a_database} is not an SQLite database"),
        "folder": (f"sqlite:///{folder}", f"{folder} is a folder, not an SQLite database file"),
        "missing folder": (f"sqlite:///{tmp_path / 'missing' / 'mlflow.db'}",
                           f"the folder of {tmp_path / 'missing' / 'mlflow.db'} does not exist"),
    }


def test_sqlite_stores_that_are_no_database_are_refused(tmp_path):
    for uri, says in _unusable_stores(tmp_path).values():
        with pytest.raises(TrackingStoreUnusable) as error:
            check_tracking_store(uri)
        assert str(error.value).startswith(f"tracking.uri={uri}: {says}")
        assert "\n" not in str(error.value)
    empty = tmp_path / "empty.db"
    empty.touch()  # SQLite opens an empty file as a new database
    check_tracking_store(f"sqlite:///{empty}")
    check_tracking_store(f"sqlite:///{tmp_path / 'new.db'}")
    check_tracking_store("sqlite:///:memory:")
    check_tracking_store(str(tmp_path / "file_store"))  # not SQLite: left to MLflow


def test_a_text_file_as_the_store_is_one_line_and_writes_nothing(tmp_path):
    uri, says = _unusable_stores(tmp_path)["text file"]
    result = _smoke(tmp_path, uri)
    assert result.returncode == 2, result.stderr[-3000:]
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"srmpc: error: tracking.uri={uri}: {says}"), line
    assert (tmp_path / "notes.db").read_text() == "not a database\n"
    assert not (tmp_path / "eval").exists() and not (tmp_path / "hydra").exists()

@pytest.mark.slow
def test_a_real_server_takes_the_run(tmp_path):
    import mlflow

    with serve_mlflow(f"sqlite:///{tmp_path / 'server.db'}", str(tmp_path / "server-artifacts"),
                      tmp_path / "server.log") as uri:
        result = _smoke(tmp_path, uri)
        assert result.returncode == 0, result.stderr[-3000:]
        client = mlflow.MlflowClient(tracking_uri=uri)
        experiment = client.get_experiment_by_name("srmpc-server-test")
        (run,) = client.search_runs([experiment.experiment_id])
        assert run.info.status == "FINISHED"
        assert run.data.params["evaluation.episodes"] == "2"
        assert {"mean_event_cost", "cost_rate", "mean_return", "mean_n_steps", "mean_vx"} <= set(run.data.metrics)
        assert len(client.get_metric_history(run.info.run_id, "episode/n_steps")) == 2  # one point per episode
        assert {a.path for a in client.list_artifacts(run.info.run_id)} >= {"config.yaml", "episodes.csv",
                                                                              "summary.json"}
