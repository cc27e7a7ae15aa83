"""`python -m srmpc stage=train` end to end on the toy task: SIGTERM -> checkpoint + FAILED run -> resume."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import mlflow

from srmpc.config.compose import compose_config, to_objects

ROOT = Path(__file__).resolve().parents[1]


def _command(tmp_path, total_frames):
    return [sys.executable, "-m", "srmpc", "stage=train", "agent=ppo_lsi", "agent.task=toy", "agent.num_envs=16",
            "agent.frames_per_batch=256", "agent.minibatch_size=128", "agent.epochs=2", "agent.checkpoint_every=1",
            f"agent.total_frames={total_frames}", f"agent.output_dir={tmp_path / 'train'}",
            f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}", f"tracking.artifact_location={tmp_path / 'mlruns'}",
            "tracking.experiment_name=srmpc-train-test", "hydra.run.dir=" + str(tmp_path / "hydra")]


def test_train_config_composes():
    config = to_objects(compose_config(["stage=train", "agent=ppo"]))
    assert config.stage.value == "train" and not config.agent.constrained and config.agent.name == "ppo"
    assert to_objects(compose_config(["stage=train"])).agent.constrained


def test_sigterm_marks_run_failed_keeps_checkpoint_and_resume_finishes(tmp_path):
    process = subprocess.Popen(_command(tmp_path, 256 * 10_000), cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    checkpoint = tmp_path / "train" / "last.pt"
    deadline = time.monotonic() + 90
    while not checkpoint.exists() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.2)
    assert checkpoint.exists(), process.communicate()[1][-2000:] if process.poll() is not None else "timeout"
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode != 0

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["srmpc-train-test"], output_format="list")
    assert [r.info.status for r in runs] == ["FAILED"]
    import torch

    done = torch.load(checkpoint, weights_only=False)["iteration"]
    assert done >= 1

    total = 256 * (done + 2)
    result = subprocess.run(_command(tmp_path, total), cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((tmp_path / "train" / "summary.json").read_text())
    assert summary["frames"] == total and summary["iterations"] == done + 2
    runs = mlflow.search_runs(experiment_names=["srmpc-train-test"], output_format="list",
                              order_by=["attributes.start_time DESC"])
    assert runs[0].info.status == "FINISHED" and runs[0].data.tags["resumed_from_iteration"] == str(done)
    assert runs[0].data.metrics["final/frames"] == total
