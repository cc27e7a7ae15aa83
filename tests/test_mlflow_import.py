"""dvc.lock's results as MLflow runs (pipelines/mlflow_import.py): one per evaluation and training output
directory, nested under the parent, idempotent by the stage's hash, superseding the runs of a rerun stage,
and an import that died half-way is redone."""

from __future__ import annotations

import copy
import csv
import json
import shutil
from pathlib import Path

import mlflow
import pytest
import yaml

from pipelines.mlflow_import import IMPORT_TAG, import_results, results_of, stage_md5
from srmpc.tracking import ensure_experiment

ROOT = Path(__file__).resolve().parents[1]

EVALUATION, TRAINING = "results/evaluation/twin/lane_keeping_light", "results/training/ablation/ppo"


@pytest.fixture
def clone(tmp_path):
    """A repository root holding one committed evaluation and one committed training, and their dvc.lock."""
    root = tmp_path / "repo"
    for directory in (EVALUATION, TRAINING):
        shutil.copytree(ROOT / directory, root / directory, ignore=shutil.ignore_patterns("last.pt*", ".*"))
    stages = yaml.safe_load((ROOT / "dvc.lock").read_text())["stages"]
    training = copy.deepcopy(stages["train_multiplier_ablation"])
    training["outs"] = [out for out in training["outs"] if out["path"] == TRAINING]
    lock = {"schema": "2.0", "stages": {"evaluate@lane_keeping-light": stages["evaluate@lane_keeping-light"],
                                        "train_multiplier_ablation": training, "table": stages["table"]}}
    (root / "dvc.lock").write_text(yaml.safe_dump(lock))
    return root


@pytest.fixture
def store(tmp_path):
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    experiment_id = ensure_experiment(client, "srmpc", str(tmp_path / "mlruns"))
    parent = client.create_run(experiment_id, run_name="make reproduce").info.run_id
    return client, experiment_id, parent


def _runs(client, experiment_id) -> dict[str, list]:
    runs: dict[str, list] = {}
    for run in client.search_runs([experiment_id], filter_string="tags.output_dir LIKE '%'"):
        runs.setdefault(run.data.tags["output_dir"], []).append(run)
    return runs


def test_a_fresh_store_gets_every_result_once(clone, store):
    client, experiment_id, parent = store
    lock_path = clone / "dvc.lock"
    assert [r["dir"] for r in results_of(yaml.safe_load(lock_path.read_text()), clone)] == [EVALUATION, TRAINING]
    assert import_results(client, experiment_id, parent, lock_path, clone)["imported"] == 2
    runs = _runs(client, experiment_id)
    (evaluation,), (training,) = runs[EVALUATION], runs[TRAINING]

    summary = json.loads((clone / EVALUATION / "summary.json").read_text())
    assert evaluation.info.status == "FINISHED" and evaluation.data.tags["mlflow.parentRunId"] == parent
    assert {k: evaluation.data.tags[k] for k in ("stage", "method", "traffic", "seed", "variant", "current")} == {
        "stage": "evaluate", "method": "lane_keeping", "traffic": "light", "seed": "0", "variant": "default",
        "current": "true"}
    for key in ("mean_event_cost", "cost_rate", "mean_return", "mean_n_steps", "mean_vx"):
        assert evaluation.data.metrics[key] == pytest.approx(summary[key])
    assert evaluation.data.metrics["terminations/truncated"] == summary["terminations"]["truncated"]
    assert evaluation.data.params["evaluation.controller"] == "lane_keeping"
    assert {a.path for a in client.list_artifacts(evaluation.info.run_id)} == {"config.yaml", "episodes.csv",
                                                                                "summary.json"}

    with (clone / TRAINING / "metrics.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    history = client.get_metric_history(training.info.run_id, "episode/return")
    assert [m.step for m in history] == [int(float(row["frames"])) for row in rows]  # the curve over env steps
    assert [m.value for m in history] == pytest.approx([float(row["episode/return"]) for row in rows])
    assert training.data.tags["method"] == "ppo" and training.data.tags["variant"] == "ppo"
    assert training.data.tags["mlflow.parentRunId"] == parent
    assert "policy.pt" in {a.path for a in client.list_artifacts(training.info.run_id)}

    again = import_results(client, experiment_id, None, lock_path, clone)  # a second make reproduce
    assert again == {"imported": 0, "skipped": 2, "superseded": 0, "deleted": 0}
    assert sum(len(v) for v in _runs(client, experiment_id).values()) == 2


def test_a_rerun_stage_supersedes_its_runs_and_a_dead_import_is_redone(clone, store):
    client, experiment_id, parent = store
    lock_path = clone / "dvc.lock"
    import_results(client, experiment_id, parent, lock_path, clone)
    (first,) = _runs(client, experiment_id)[EVALUATION]
    live = client.create_run(experiment_id, run_name="evaluate-lane_keeping-light",  # the rerun stage's own run
                             tags={"output_dir": EVALUATION}).info.run_id
    client.set_terminated(live, "FINISHED")

    lock = yaml.safe_load(lock_path.read_text())  # DVC reran the evaluation: its lock entry changed
    entry = lock["stages"]["evaluate@lane_keeping-light"]
    entry["outs"][0]["md5"] = "0" * 32
    lock_path.write_text(yaml.safe_dump(lock))
    dead = client.create_run(experiment_id, run_name="half an import",  # an import killed half-way
                             tags={"output_dir": EVALUATION, IMPORT_TAG: stage_md5(entry)}).info.run_id

    counts = import_results(client, experiment_id, parent, lock_path, clone)
    assert counts == {"imported": 1, "skipped": 1, "superseded": 2, "deleted": 1}
    runs = {r.info.run_id: r for r in _runs(client, experiment_id)[EVALUATION]}
    (new,) = [r for r in runs.values() if r.data.tags.get("current") == "true"]
    assert new.data.tags[IMPORT_TAG] == stage_md5(entry) and new.info.status == "FINISHED"
    assert set(runs) == {first.info.run_id, live, new.info.run_id}  # the dead import is gone
    for old in (first.info.run_id, live):
        assert runs[old].data.tags["current"] == "false" and runs[old].data.tags["superseded_by"] == new.info.run_id
    assert client.get_run(dead).info.lifecycle_stage == "deleted"
    assert import_results(client, experiment_id, parent, lock_path, clone)["imported"] == 0


@pytest.mark.parametrize("stage, margin, planner, variant", [
    ("evaluate_tradeoff@srmpc_track_rollout-margin_2m-dense", 2.0, "margin_2m", "track_rollout+margin_2m"),
    ("evaluate_planner_variant@short_margin-ltv_mpc-light", 4.0, "short_margin", "short_margin"),
    ("evaluate_confirmation@srmpc_recommended-light", 1.0, "margin_1m", "track_rollout+margin_1m"),
    ("evaluate@srmpc-light", 8.0, "default", "paper"),
])
def test_sweep_points_are_tagged_by_their_planner_setting(stage, margin, planner, variant):
    """The runs table groups the trade-off sweep by method and planner setting (tags planner, margin_m)."""
    from pipelines.mlflow_import import _variant

    controller = "ltv_mpc" if "ltv_mpc" in stage else "srmpc"
    config = {"evaluation": {"controller": controller},
              "srmpc": {"variant": "track_rollout" if "track_rollout" in stage or "recommended" in stage else "paper"},
              "planner": {"safety_margin_longitudinal_m": margin}}
    tags = _variant(stage, config, "evaluation", "results/evaluation/x")
    assert (tags["planner"], tags["margin_m"], tags["variant"]) == (planner, str(margin), variant)
