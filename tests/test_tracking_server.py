"""An HTTP ``tracking.uri``: a server that does not answer is one line (exit 2, nothing written, no retry
WARNINGs); a real ``mlflow server`` takes the run's params, metrics and artifacts (slow: it starts in ~20 s)."""

from __future__ import annotations

import http.server
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from srmpc.tracking import PARENT_RUN_ENV, TrackingServerUnreachable, check_tracking_server
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
