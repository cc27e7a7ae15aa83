"""An evaluation killed mid-run (SIGTERM or SIGKILL) loses no finished episode, its MLflow run ends
FAILED, and the rerun resumes to the summary an uninterrupted run gives."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import fields
from pathlib import Path

import mlflow

from srmpc.config.compose import compose_config, to_objects
from srmpc.config.schema import EvaluationConfig
from srmpc.numerics import SUMMARY_KEY
from srmpc.stages.evaluate import run_evaluation
from srmpc.tracking import HOST_TAG, PID_TAG, Run, tracked_run

ROOT = Path(__file__).resolve().parents[1]
EPISODES = 40
OVERRIDES = ["controller=lane_keeping", f"evaluation.episodes={EPISODES}", "scenario.episode_steps=100"]
if "workers" in {f.name for f in fields(EvaluationConfig)}:
    OVERRIDES.append("evaluation.workers=1")
EXPERIMENT = "srmpc-interruption-test"


def _rows(path: Path) -> int:
    try:
        return max(len(path.read_text().splitlines()) - 1, 0)
    except FileNotFoundError:
        return 0


def _command(tmp_path: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "srmpc", *OVERRIDES, f"evaluation.output_dir={out}",
            f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}", f"tracking.artifact_location={tmp_path / 'mlruns'}",
            f"tracking.experiment_name={EXPERIMENT}", f"hydra.run.dir={tmp_path / 'hydra'}"]


def _interrupt_after(process: subprocess.Popen, csv: Path, rows: int, signum: int) -> int:
    """Send ``signum`` (to the whole process group for SIGKILL) once ``csv`` holds ``rows`` rows."""
    deadline = time.monotonic() + 600
    while _rows(csv) < rows and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert process.poll() is None, process.communicate()[1][-3000:]
    if signum == signal.SIGKILL:
        os.killpg(process.pid, signal.SIGKILL)
    else:
        process.send_signal(signum)
    process.communicate(timeout=300)
    done = _rows(csv)
    assert rows <= done < EPISODES, f"{done} rows: the interruption was not mid-run"
    return process.returncode


def _statuses(tmp_path: Path) -> list[str]:
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=[EXPERIMENT], output_format="list",
                              order_by=["attributes.start_time ASC"])
    return [run.info.status for run in runs]


def test_sigterm_then_sigkill_lose_no_episode_and_the_rerun_matches_an_uninterrupted_run(tmp_path, start_process):
    reference = run_evaluation(to_objects(compose_config([*OVERRIDES, "tracking.enabled=false"])), "reference\n",
                               tmp_path / "reference", Run(None), progress=False)
    out = tmp_path / "eval"
    csv = out / "episodes.csv"

    code = _interrupt_after(start_process(_command(tmp_path, out)), csv, 2, signal.SIGTERM)
    assert code == 128 + signal.SIGTERM
    assert _statuses(tmp_path) == ["FAILED"]
    kept = csv.read_text()

    code = _interrupt_after(start_process(_command(tmp_path, out)), csv, _rows(csv) + 2, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert csv.read_text().startswith(kept)  # the first run's episodes are still there
    assert _statuses(tmp_path) == ["FAILED", "RUNNING"]  # a killed process cannot end its run

    process = start_process(_command(tmp_path, out))
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary.pop(SUMMARY_KEY)["cpu"]["model"]  # the machine's record (the entry point's), beside the results
    assert summary == json.loads(json.dumps(reference))
    assert _rows(csv) == EPISODES
    assert _statuses(tmp_path) == ["FAILED", "FAILED", "FINISHED"]  # the rerun ended the killed run


def test_only_runs_of_dead_processes_on_this_host_are_ended(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    client = mlflow.MlflowClient(tracking_uri=uri)
    experiment = client.create_experiment(EXPERIMENT, artifact_location=(tmp_path / "mlruns").as_uri())
    dead = subprocess.Popen(["true"])
    dead.wait()  # its pid is free now
    host = socket.gethostname()
    runs = {
        "dead": {PID_TAG: str(dead.pid), HOST_TAG: host},
        "alive": {PID_TAG: str(os.getpid()), HOST_TAG: host},
        "elsewhere": {PID_TAG: str(dead.pid), HOST_TAG: host + "-other"},
        "untagged": {},
    }
    ids = {name: client.create_run(experiment, run_name="evaluate-x", tags=tags).info.run_id
           for name, tags in runs.items()}
    other_name = client.create_run(experiment, run_name="evaluate-y",
                                   tags={PID_TAG: str(dead.pid), HOST_TAG: host}).info.run_id

    with tracked_run(True, uri, str(tmp_path / "mlruns"), EXPERIMENT, "evaluate-x", {"a": 1}, "a: 1\n") as run:
        new = run.run_id
    status = {name: client.get_run(run_id).info.status for name, run_id in ids.items()}
    assert status == {"dead": "FAILED", "alive": "RUNNING", "elsewhere": "RUNNING", "untagged": "RUNNING"}
    assert client.get_run(other_name).info.status == "RUNNING"  # another run name: not this run's business
    tags = client.get_run(new).data.tags
    assert (tags[PID_TAG], tags[HOST_TAG], client.get_run(new).info.status) == (str(os.getpid()), host, "FINISHED")
