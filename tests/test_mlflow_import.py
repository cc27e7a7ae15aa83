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

from pipelines.mlflow_import import IMPORT_TAG, import_results, results_of, stage_md5, summary_metrics
from pipelines.reporting import EXPERIMENTS
from srmpc.tracking import ensure_experiment

ROOT = Path(__file__).resolve().parents[1]

EVALUATION, TRAINING = "results/evaluation/table/lane_keeping_light", "results/training/ablation/ppo"


@pytest.fixture
def clone(tmp_path):
    """A repository root holding one committed evaluation and one committed training, and their dvc.lock."""
    root = tmp_path / "repo"
    for directory in (EVALUATION, TRAINING):
        shutil.copytree(ROOT / directory, root / directory, ignore=shutil.ignore_patterns("last.pt*", ".*"))
    stages = yaml.safe_load((ROOT / "dvc.lock").read_text())["stages"]
    training = copy.deepcopy(stages["train_multiplier_ablation"])
    training["outs"] = [out for out in training["outs"] if out["path"] == TRAINING]
    cell = "evaluate@table/lane_keeping-light"
    lock = {"schema": "2.0", "stages": {cell: stages[cell],
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
    assert {k: evaluation.data.tags[k] for k in ("stage", "experiment", "method", "traffic", "seed", "current")} == {
        "stage": "evaluate", "experiment": "table/lane_keeping", "method": "lane_keeping", "traffic": "light",
        "seed": "0", "current": "true"}
    assert evaluation.info.run_name == "table/lane_keeping_light"
    for key in ("mean_event_cost", "cost_rate", "mean_return", "mean_n_steps", "mean_vx"):
        assert evaluation.data.metrics[key] == pytest.approx(summary[key])
    assert evaluation.data.metrics["terminations/truncated"] == summary["terminations"]["truncated"]
    assert evaluation.data.params["controller.name"] == "lane_keeping"
    assert {a.path for a in client.list_artifacts(evaluation.info.run_id)} == {"config.yaml", "episodes.csv",
                                                                                "summary.json"}

    with (clone / TRAINING / "metrics.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    history = client.get_metric_history(training.info.run_id, "episode/return")
    assert [m.step for m in history] == [int(float(row["frames"])) for row in rows]  # the curve over env steps
    assert [m.value for m in history] == pytest.approx([float(row["episode/return"]) for row in rows])
    assert training.data.tags["method"] == "ppo" and training.data.tags["variant"] == "default"  # agent=ppo as is
    assert training.data.tags["mlflow.parentRunId"] == parent
    assert "policy.pt" in {a.path for a in client.list_artifacts(training.info.run_id)}

    again = import_results(client, experiment_id, None, lock_path, clone)  # a second make reproduce
    assert {k: again[k] for k in ("imported", "skipped", "superseded", "deleted")} == {
        "imported": 0, "skipped": 2, "superseded": 0, "deleted": 0}
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
    entry = lock["stages"]["evaluate@table/lane_keeping-light"]
    entry["outs"][0]["md5"] = "0" * 32
    lock_path.write_text(yaml.safe_dump(lock))
    dead = client.create_run(experiment_id, run_name="half an import",  # an import killed half-way
                             tags={"output_dir": EVALUATION, IMPORT_TAG: stage_md5(entry)}).info.run_id

    counts = import_results(client, experiment_id, parent, lock_path, clone)
    assert {k: counts[k] for k in ("imported", "skipped", "superseded", "deleted")} == {
        "imported": 1, "skipped": 1, "superseded": 2, "deleted": 1}
    runs = {r.info.run_id: r for r in _runs(client, experiment_id)[EVALUATION]}
    (new,) = [r for r in runs.values() if r.data.tags.get("current") == "true"]
    assert new.data.tags[IMPORT_TAG] == stage_md5(entry) and new.info.status == "FINISHED"
    assert set(runs) == {first.info.run_id, live, new.info.run_id}  # the dead import is gone
    for old in (first.info.run_id, live):
        assert runs[old].data.tags["current"] == "false" and runs[old].data.tags["superseded_by"] == new.info.run_id
    assert client.get_run(dead).info.lifecycle_stage == "deleted"
    assert import_results(client, experiment_id, parent, lock_path, clone)["imported"] == 0


@pytest.mark.parametrize("experiment, controller, policy, method", [
    ("table/ppo_sb3", "policy", "ppo_sb3", "policy-ppo_sb3"),
    ("tradeoff/ltv_mpc_margin_4m", "ltv_mpc", None, "ltv_mpc"),
    ("confirmation/srmpc_recommended", "srmpc", "ppo_lsi", "srmpc"),
])
def test_a_result_is_named_by_its_config_not_by_its_folder(experiment, controller, policy, method):
    """An evaluation's run is named by the experiment and traffic its config names, and tagged with them and its
    controller: the same config in any folder, under any stage, gives the same run."""
    from pipelines.mlflow_import import result_tags, run_name_of
    from srmpc.tracking import run_tags

    config = {"stage": "evaluate", "experiment": experiment, "scenario": {"traffic": "dense"},
              "controller": {"name": controller, "policy": policy},
              "evaluation": {"simulator": "twin", "seed": 0}, "planner": {"safety_margin_longitudinal_m": 4.0}}
    tags = {**run_tags(config), **result_tags(config, "evaluation")}
    assert tags == {"stage": "evaluate", "experiment": experiment, "method": method, "traffic": "dense", "seed": "0",
                    "margin_m": "4.0", "simulator": "twin"}
    assert run_name_of("evaluation", config) == f"{experiment}_dense"


def test_every_row_of_the_results_table_has_its_run_under_the_tables_method(tmp_path, store):
    """Each row of results/table.json: an imported run with that row's experiment and traffic tag and J_c, and
    exactly one run marked as the row (tag results_table, the runs table's "results" view), whose numbers are
    the row's. The runs are named by their config.yaml, so the check holds whatever the folders are called."""
    client, experiment_id, parent = store
    lock = yaml.safe_load((ROOT / "dvc.lock").read_text())
    evaluations = {stage for stage, entry in lock["stages"].items()
                   if any(Path(out["path"]).name == "summary.json" for out in entry.get("outs") or [])}
    lock["stages"] = {stage: lock["stages"][stage] for stage in evaluations}  # the trainings take long to log
    (tmp_path / "dvc.lock").write_text(yaml.safe_dump(lock))
    counts = import_results(client, experiment_id, parent, tmp_path / "dvc.lock", ROOT)
    table = json.loads((ROOT / "results" / "table.json").read_text())
    rows = {(traffic, method): row for traffic, methods in table.items() for method, row in methods.items()}
    assert {"srmpc_recommended"} < {method for _, method in rows} and len(rows) >= 12
    assert counts["table_rows"] == counts["table_rows_with_run"] == len(rows), counts

    runs = [run for runs in _runs(client, experiment_id).values() for run in runs]
    for (traffic, method), row in rows.items():
        same = [r for r in runs if r.data.tags.get("experiment") == EXPERIMENTS[method]
                and r.data.tags["traffic"] == traffic]
        assert any(r.data.metrics["mean_event_cost"] == row["mean_event_cost"] for r in same), (
            f"{method} {traffic}: no run with the table's J_c {row['mean_event_cost']}: "
            f"{[(r.info.run_name, r.data.metrics.get('mean_event_cost')) for r in same]}")
        marked = [r for r in same if r.data.tags.get("results_table") == "true"]
        assert len(marked) == 1, (method, traffic, [r.info.run_name for r in marked])
        for key in ("episodes", "mean_event_cost", "cost_rate", "mean_return", "mean_n_steps", "mean_vx"):
            assert marked[0].data.metrics[key] == pytest.approx(row[key], rel=1e-12), (method, traffic, key)
    assert sum(r.data.tags.get("results_table") == "true" for r in runs) == len(rows)

    table["light"].pop("ppo")  # the table drops a row: the next import unmarks its run
    (tmp_path / "table.json").write_text(json.dumps(table))
    again = import_results(client, experiment_id, parent, tmp_path / "dvc.lock", ROOT, tmp_path / "table.json")
    assert again["imported"] == 0 and again["table_rows"] == again["table_rows_with_run"] == len(rows) - 1
    marked = client.search_runs([experiment_id], filter_string='tags.results_table = "true"', max_results=1000)
    assert len(marked) == len(rows) - 1 and ("light", "ppo") not in {
        (r.data.tags["traffic"], r.data.tags["method"]) for r in marked}


def test_a_runs_environment_record_is_not_imported_as_metrics():
    """A summary's ``environment`` (srmpc.numerics: the machine) is tags, not metrics; other nesting stays."""
    summary = {"mean_vx": 20.5, "terminations": {"collision": 3}, "environment": {"threads": {"torch": 1}}}
    assert summary_metrics(summary) == {"mean_vx": 20.5, "terminations/collision": 3.0}
