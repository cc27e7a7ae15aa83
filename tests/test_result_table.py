"""``python -m srmpc`` ends with a compact table: the paper's metrics with 95% CIs, output dir, MLflow run."""

import io

import mlflow
import pandas as pd
from omegaconf import OmegaConf
from rich.console import Console

from srmpc.result_table import print_result
from srmpc.tracking import PARENT_RUN_ENV, tracked_run

SUMMARY = {"episodes": 4, "mean_return": -1234.5, "mean_return_per_step": -3.1, "mean_event_cost": 0.25,
           "cost_rate": 0.0009, "mean_n_steps": 300.0, "mean_vx": 23.456, "mean_si_cost_return": 1.0,
           "terminations": {"collision": 1, "offroad": 0, "truncated": 3}, "outcomes": {"solved": 10},
           "controller": "srmpc", "traffic": "dense", "simulator": "twin"}


def _cfg(stage="evaluate", output_dir=None, enabled=True):
    return OmegaConf.create({"stage": stage, "evaluation": {"output_dir": output_dir},
                             "agent": {"name": "ppo_lsi", "output_dir": output_dir}, "tracking": {"enabled": enabled}})


def _printed(cfg, summary, hydra_dir):
    buffer = io.StringIO()
    print_result(cfg, summary, hydra_dir, Console(file=buffer, width=100))
    return buffer.getvalue()


def test_evaluation_table_has_metrics_intervals_output_and_run_id(tmp_path, monkeypatch):
    monkeypatch.delenv(PARENT_RUN_ENV, raising=False)
    pd.DataFrame({"episode": range(4), "seed": range(4), "episode_return": [-1000.0, -1500.0, -1200.0, -1238.0],
                  "event_cost": [0.0, 1.0, 0.0, 0.0], "n_steps": [400, 100, 400, 300],
                  "mean_vx": [23.0, 24.0, 23.5, 23.3]}).to_csv(tmp_path / "episodes.csv", index=False)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    with tracked_run(True, uri, str(tmp_path / "mlruns"), "srmpc", "evaluate-srmpc", {"stage": "evaluate"}, "") as run:
        run_id = run.run_id
    try:
        out = _printed(_cfg(output_dir=str(tmp_path)), SUMMARY, tmp_path / "hydra")
    finally:
        mlflow.set_tracking_uri(None)
    for label in ("J_r", "J_r / step", "J_c", "rho_c", "n_steps", "v_x [m/s]", "95% CI"):
        assert label in out
    assert "0.250" in out and "[0.046, 0.699]" in out  # J_c 1 of 4 with its Wilson interval
    assert "-4.12" in out and "-3.10" not in out  # J_r per step: -4938 / 1200 from the episodes, not the summary
    assert "23.46" in out and "srmpc, dense traffic, 4 episodes on twin" in out
    assert "collision 1, offroad 0, truncated 3" in out
    assert f"output:     {tmp_path}" in out and f"MLflow run: {run_id}" in out
    assert "{" not in out


def test_without_episodes_or_tracking_the_table_still_prints(tmp_path):
    out = _printed(_cfg(enabled=False), SUMMARY, tmp_path / "hydra")
    assert "-1,234" in out and f"output:     {tmp_path / 'hydra'}" in out and "tracking disabled" in out


def test_training_table(tmp_path):
    summary = {"frames": 20_000_000, "wall_s": 1098.4, "iterations": 610, "return": -1516.9, "cost_return": 0.1677,
               "cost_rate": 0.000459, "vx": 23.72, "episodes": 2778, "name": "ppo_lsi"}
    out = _printed(_cfg(stage="train", output_dir=str(tmp_path / "run"), enabled=False), summary, tmp_path)
    assert "training ppo_lsi" in out and "20,000,000" in out and "0.168" in out and "0.00046" in out
    assert f"output:     {tmp_path / 'run'}" in out
