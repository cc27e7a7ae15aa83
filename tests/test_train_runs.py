"""pipelines/train_runs.py (the DVC training stages): trainings side by side give each run's own results,
and a failed run neither stops the others nor goes unreported."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOY = ("agent=ppo_lsi agent.task=toy agent.num_envs=16 agent.frames_per_batch=256 agent.minibatch_size=128 "
       "agent.epochs=2 agent.multiplier_steps=2 agent.total_frames=1024")


def _train_runs(tmp_path, *runs, jobs=2):
    return subprocess.run([sys.executable, str(ROOT / "pipelines" / "train_runs.py"), "--jobs", str(jobs), *runs],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)


def _toy(tmp_path, name, seed, extra="tracking.enabled=false"):
    return (f"{TOY} agent.seed={seed} agent.output_dir={tmp_path / name} "
            f"hydra.run.dir={tmp_path / 'hydra' / name} {extra}")


def test_side_by_side_runs_equal_the_run_alone(tmp_path):
    result = _train_runs(tmp_path, _toy(tmp_path, "a", 0), _toy(tmp_path, "b", 1))
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    alone = _train_runs(tmp_path, _toy(tmp_path, "alone", 1), jobs=1)
    assert alone.returncode == 0, alone.stdout[-3000:]
    for name in ("a", "b", "alone"):
        assert (tmp_path / name / "policy.pt").is_file() and (tmp_path / name / "summary.json").is_file()
        assert f"[{tmp_path / name}] exit 0 after" in result.stdout + alone.stdout
    # seed 1 beside seed 0 learns exactly what seed 1 learns alone (one thread per run, the same seeds)
    summary = {n: json.loads((tmp_path / n / "summary.json").read_text()) for n in ("b", "alone")}
    assert summary["b"]["return"] == summary["alone"]["return"]
    assert summary["b"]["cost_rate"] == summary["alone"]["cost_rate"]


def test_a_failed_run_is_named_and_the_others_finish(tmp_path):
    bad = _toy(tmp_path, "bad", 0, "tracking.enabled=false agent.epochs=-1")
    result = _train_runs(tmp_path, bad, _toy(tmp_path, "good", 1))
    assert result.returncode != 0
    assert f"1 of 2 trainings failed: {tmp_path / 'bad'} (exit 2)" in result.stderr
    assert "agent.epochs" in result.stdout  # the run's own one-line config error, under its name
    assert (tmp_path / "good" / "summary.json").is_file()


def test_bad_jobs_is_one_line():
    result = subprocess.run([sys.executable, str(ROOT / "pipelines" / "train_runs.py"), "--jobs", "-1", "agent=ppo"],
                            cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 2 and "--jobs=-1: must be >= 0" in result.stderr


@pytest.mark.slow  # about 40 s: three trainings started at once against one new store
def test_side_by_side_runs_create_one_mlflow_store_without_a_race(tmp_path):
    tracking = (f"tracking.enabled=true tracking.uri=sqlite:///{tmp_path / 'mlflow.db'} "
                f"tracking.artifact_location={tmp_path / 'mlruns'} tracking.experiment_name=train-runs-test")
    runs = [_toy(tmp_path, name, seed, tracking) for name, seed in (("a", 0), ("b", 1), ("c", 2))]
    result = _train_runs(tmp_path, *runs, jobs=3)
    errors = [line for line in result.stdout.splitlines() if "error" in line.lower() or "Traceback" in line]
    assert result.returncode == 0, "\n".join(errors)[-3000:] + result.stdout[-1500:] + result.stderr[-1500:]
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("train-runs-test")
    runs_logged = client.search_runs([experiment.experiment_id])
    assert sorted(r.info.status for r in runs_logged) == ["FINISHED"] * 3
