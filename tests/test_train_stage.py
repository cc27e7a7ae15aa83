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
            "agent.frames_per_batch=256", "agent.minibatch_size=128", "agent.epochs=2", "agent.multiplier_steps=2",
            "agent.checkpoint_every=1", f"agent.total_frames={total_frames}", f"agent.output_dir={tmp_path / 'train'}",
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
    deadline = time.monotonic() + 600  # generous: a loaded machine starts the process slowly
    try:
        while not checkpoint.exists() and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.2)
        assert checkpoint.exists(), process.communicate()[1][-2000:] if process.poll() is not None else "timeout"
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=300)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode != 0

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["srmpc-train-test"], output_format="list")
    assert [r.info.status for r in runs] == ["FAILED"]
    import torch

    done = torch.load(checkpoint, weights_only=False)["iteration"]
    assert done >= 1

    total = 256 * (done + 2)
    result = subprocess.run(_command(tmp_path, total), cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((tmp_path / "train" / "summary.json").read_text())
    assert summary["frames"] == total and summary["iterations"] == done + 2
    runs = mlflow.search_runs(experiment_names=["srmpc-train-test"], output_format="list",
                              order_by=["attributes.start_time DESC"])
    assert runs[0].info.status == "FINISHED" and runs[0].data.tags["resumed_from_iteration"] == str(done)
    assert runs[0].data.metrics["final/frames"] == total


def _toy(tmp_path, *extra):
    from omegaconf import OmegaConf

    cfg = compose_config(["stage=train", "agent=ppo_lsi", "agent.task=toy", "agent.num_envs=16",
                          "agent.frames_per_batch=256", "agent.minibatch_size=128", "agent.epochs=1",
                          "agent.multiplier_steps=2", "agent.total_frames=256",
                          f"agent.output_dir={tmp_path / 'train'}", "tracking.enabled=false", *extra])
    return to_objects(cfg), OmegaConf.to_container(cfg, resolve=True)


def _snapshot(directory):
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())}


def test_training_refuses_committed_results_of_another_config_and_writes_nothing(tmp_path):
    import pytest
    from omegaconf import OmegaConf

    from srmpc.config.compose import ConfigError
    from srmpc.stages.train import run_training, training_identity_yaml
    from srmpc.tracking import Run

    target = tmp_path / "train"
    target.mkdir()  # a committed full training run: config.yaml, policy.pt, metrics.csv, summary.json; no last.pt
    committed = OmegaConf.to_container(compose_config(["stage=train", "agent=ppo_lsi"]), resolve=True)
    (target / "config.yaml").write_text(training_identity_yaml(committed))
    for name in ("policy.pt", "metrics.csv", "summary.json"):
        (target / name).write_bytes(f"committed {name}\n".encode())
    before = _snapshot(target)
    config, container = _toy(tmp_path)
    with pytest.raises(ConfigError, match=r"agent.output_dir=.*train: holds results of a different config"):
        run_training(config, container, Run(None), progress=False)
    assert _snapshot(target) == before

    (target / "config.yaml").unlink()  # results whose config is unknown are refused as well
    before = _snapshot(target)
    with pytest.raises(ConfigError, match=r"holds training results \(policy.pt, metrics.csv, summary.json\) without"):
        run_training(config, container, Run(None), progress=False)
    assert _snapshot(target) == before


def test_training_writes_nothing_before_the_config_is_accepted(tmp_path, monkeypatch):
    import pytest

    from srmpc.config.compose import ConfigError
    from srmpc.stages import train
    from srmpc.tracking import Run

    with pytest.raises(ConfigError, match="agent.actor_lr=nan"):
        _toy(tmp_path, "agent.actor_lr=nan")

    def refuse(config):
        raise ConfigError("agent.task=toy: refused")

    monkeypatch.setattr(train, "make_training_env", refuse)
    config, container = _toy(tmp_path)
    with pytest.raises(ConfigError, match="refused"):
        train.run_training(config, container, Run(None), progress=False)
    assert not (tmp_path / "train").exists()


def test_training_into_an_unwritable_directory_is_one_line(tmp_path):
    import pytest

    from srmpc.config.compose import ConfigError
    from srmpc.stages.train import run_training
    from srmpc.tracking import Run

    (tmp_path / "train").write_text("a file, not a directory\n")
    config, container = _toy(tmp_path)
    config.agent.output_dir = str(tmp_path / "train" / "run")
    with pytest.raises(ConfigError) as caught:
        run_training(config, container, Run(None), progress=False)
    assert str(caught.value).startswith(f"agent.output_dir={tmp_path / 'train' / 'run'}: cannot write there")
    assert "\n" not in str(caught.value)


def test_same_config_owns_its_directory_and_replaces_its_files(tmp_path):
    from srmpc.stages.train import run_training
    from srmpc.tracking import Run

    config, container = _toy(tmp_path)
    first = run_training(config, container, Run(None), progress=False)
    config, container = _toy(tmp_path, "agent.total_frames=512")  # total_frames may change on a resume
    second = run_training(config, container, Run(None), progress=False)
    assert (first["iterations"], second["iterations"]) == (1, 2)
    names = {p.name for p in (tmp_path / "train").iterdir()}
    assert {"config.yaml", "last.pt", "policy.pt", "metrics.csv", "summary.json"} <= names
    assert not [n for n in names if n.endswith(".tmp")]
