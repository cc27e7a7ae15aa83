"""Hydra multirun through hydra-submitit-launcher: each job a normal run in its own directory, resumed on
resubmission; the committed SLURM launcher config composes."""

import os
import signal
import subprocess
import sys
from pathlib import Path

import mlflow
import pytest
import yaml

from srmpc.sweep import sweep_jobs

ROOT = Path(__file__).resolve().parents[1]
TOY_SEED_SWEEP = ["stage=train", "agent=ppo_lsi", "agent.task=toy", "agent.seed=0,1", "agent.num_envs=16",
                  "agent.frames_per_batch=512", "agent.minibatch_size=128", "agent.epochs=2", "agent.total_frames=1024"]


def _srmpc(tmp_path, *args, timeout=600):
    """``python -m srmpc`` in ``tmp_path``: the default MLflow store (mlflow.db, mlruns/) lands there too.
    On a timeout the whole process group goes, the sweep's job processes included."""
    process = subprocess.Popen([sys.executable, "-m", "srmpc", *args], cwd=tmp_path, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = process.communicate(timeout=timeout)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)


@pytest.mark.slow  # about 45 s: two training jobs started twice; the evaluation sweep below stays default
def test_seed_sweep_on_submitit_local_runs_each_job_in_its_own_directory_and_resumes_it(tmp_path):
    sweep = tmp_path / "sweep"
    command = ["-m", *TOY_SEED_SWEEP, "hydra/launcher=local", f"hydra.sweep.dir={sweep}"]
    result = _srmpc(tmp_path, *command)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    jobs = {seed: sweep / ",".join(sorted(o.replace("0,1", str(seed)) for o in TOY_SEED_SWEEP)) for seed in (0, 1)}
    for job in jobs.values():
        assert {"config.yaml", "last.pt", "policy.pt", "metrics.csv", "summary.json"} <= {p.name for p in job.iterdir()}
    assert (jobs[0] / "policy.pt").read_bytes() != (jobs[1] / "policy.pt").read_bytes()

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["srmpc"], output_format="list")
    assert sorted((r.data.params["agent.seed"], r.info.status) for r in runs) == [("0", "FINISHED"), ("1", "FINISHED")]

    resubmitted = _srmpc(tmp_path, *command)  # the same jobs again: same directories, nothing left to train
    assert resubmitted.returncode == 0, resubmitted.stderr[-2000:]
    runs = mlflow.search_runs(experiment_names=["srmpc"], output_format="list", order_by=["attributes.start_time"])
    assert len(runs) == 4
    assert [r.data.tags.get("resumed_from_iteration") for r in runs[2:]] == ["2", "2"]


def test_evaluation_sweep_writes_each_controller_into_its_job_directory(tmp_path):
    sweep = tmp_path / "sweep"
    result = _srmpc(tmp_path, "-m", "+experiment=smoke", "controller=lane_keeping,ltv_mpc",
                    "evaluation.workers=1", "tracking.enabled=false", "hydra/launcher=local",
                    f"hydra.sweep.dir={sweep}")
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    for controller in ("lane_keeping", "ltv_mpc"):
        (job,) = sweep.glob(f"*controller={controller},*")
        summary = yaml.safe_load((job / "summary.json").read_text())
        assert summary["controller"] == controller and summary["episodes"] == 2
    assert not (tmp_path / "outputs").exists() and not (tmp_path / "multirun").exists()


def test_a_bad_job_config_stops_the_sweep_before_any_job_starts(tmp_path):
    result = _srmpc(tmp_path, "-m", "stage=train", "agent.task=toy", "agent.seed=0,1", "agent.epochs=0,1",
                    "hydra/launcher=local", f"hydra.sweep.dir={tmp_path / 'sweep'}")
    assert result.returncode == 2
    assert result.stderr.startswith("srmpc: config error: sweep job #0 (") and "agent.epochs=0" in result.stderr
    assert not (tmp_path / "sweep").exists()


def test_sweep_jobs_expand_the_overrides_of_a_multirun():
    assert sweep_jobs(["-m", "stage=train", "agent.seed=0,1", "hydra/launcher=slurm"]) == [
        ["stage=train", "agent.seed=0"], ["stage=train", "agent.seed=1"]]
    assert sweep_jobs(["stage=train", "agent.seed=0"]) == []
    assert sweep_jobs(["-m", "agent.seed=0,1", "--cfg", "job"]) == []


def test_slurm_launcher_config_shows_partition_time_cpus_and_memory(tmp_path):
    result = _srmpc(tmp_path, "hydra/launcher=slurm", "hydra.launcher.mem_gb=32", "--cfg", "hydra")
    assert result.returncode == 0, result.stderr[-2000:]
    hydra = yaml.safe_load(result.stdout)["hydra"]
    launcher, committed = hydra["launcher"], yaml.safe_load((ROOT / "conf/hydra/launcher/slurm.yaml").read_text())
    assert launcher["_target_"] == "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"
    for key in ("partition", "timeout_min", "cpus_per_task", "max_num_timeout"):
        assert launcher[key] == committed["launcher"][key] is not None, key
    assert launcher["mem_gb"] == 32
    assert hydra["sweep"] == {"dir": "multirun", "subdir": "${hydra.job.override_dirname}"}
