"""MLflow as researchers use it: experiments open on the runs table, pipeline runs group their children."""

import json

import mlflow
import pytest

from srmpc.tracking import (
    EXPERIMENT_TAGS,
    PARENT_RUN_ENV,
    finish_parent_run,
    run_tags,
    runs_table_url,
    start_parent_run,
    tracked_run,
)

KIND = "mlflow.experimentKind"


@pytest.fixture
def store(tmp_path, monkeypatch):
    """A temporary SQLite store; no parent run inherited from the environment."""
    monkeypatch.delenv(PARENT_RUN_ENV, raising=False)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    yield uri, str(tmp_path / "mlruns")
    mlflow.set_tracking_uri(None)


def _params(controller="srmpc", traffic="light", seed=3, policy="ppo_lsi", stage="evaluate", experiment=None):
    return {"stage": stage, "experiment": experiment, "scenario": {"traffic": traffic},
            "agent": {"name": "ppo_lsi", "seed": 1}, "controller": {"name": controller, "policy": policy},
            "evaluation": {"seed": seed}}


def test_run_tags_name_method_traffic_and_seed():
    assert run_tags(_params()) == {"stage": "evaluate", "method": "srmpc", "traffic": "light", "seed": "3"}
    assert run_tags(_params(controller="policy", policy="ppo_sb3"))["method"] == "policy-ppo_sb3"
    assert run_tags(_params(controller="ltv_mpc", policy=None))["method"] == "ltv_mpc"
    assert run_tags(_params(stage="train")) == {"stage": "train", "method": "ppo_lsi", "traffic": "light", "seed": "1"}
    named = run_tags(_params(experiment="confirmation/srmpc_recommended", seed=100000))
    assert named == {"stage": "evaluate", "experiment": "confirmation/srmpc_recommended", "method": "srmpc",
                     "traffic": "light", "seed": "100000"}


def test_new_and_existing_experiments_open_on_the_runs_table(store):
    uri, artifacts = store
    client = mlflow.MlflowClient(uri)
    with tracked_run(True, uri, artifacts, "fresh", "run", _params(), "a: 1\n"):
        pass
    assert client.get_experiment_by_name("fresh").tags[KIND] == EXPERIMENT_TAGS[KIND]

    client.create_experiment("old", artifact_location=f"file://{artifacts}")  # made before the tag existed
    assert KIND not in client.get_experiment_by_name("old").tags
    with tracked_run(True, uri, artifacts, "old", "run", _params(), "a: 1\n"):
        pass
    assert client.get_experiment_by_name("old").tags[KIND] == "custom_model_development"

    view = json.loads(client.get_experiment_by_name("old").tags["mlflow.sharedViewState.results"])
    assert view["name"] == "Results table" and isinstance(view["createdAt"], int)  # MLflow 3.17's envelope
    state = json.loads(view["state"])
    assert {"metrics.`mean_event_cost`", "metrics.`mean_vx`", "tags.`method`", "tags.`traffic`"} <= set(
        state["selectedColumns"])
    # the order the grid shows them in: method, traffic, J_c, v_x, rho_c, J_r, n_steps (MLflow 3.17's columnOrder)
    assert state["columnOrder"][:7] == ["tags.`method`", "tags.`traffic`", "metrics.`mean_event_cost`",
                                        "metrics.`mean_vx`", "metrics.`cost_rate`", "metrics.`mean_return`",
                                        "metrics.`mean_n_steps`"]
    assert state["searchFilter"] == 'tags.results_table = "true"'
    assert runs_table_url("http://h:5000/", "7") == (
        "http://h:5000/#/experiments/7/runs?viewStateShareKey=results&workflowType=machine_learning")
    assert "searchFilter" not in json.loads(json.loads(
        client.get_experiment_by_name("old").tags["mlflow.sharedViewState.metrics"])["state"])


def test_runs_nest_under_the_parent_named_in_the_environment(store, monkeypatch, tmp_path):
    uri, artifacts = store
    parent = start_parent_run(uri, "srmpc", artifacts, "pipeline", {"stage": "pipeline"})
    monkeypatch.setenv(PARENT_RUN_ENV, parent)
    for controller in ("srmpc", "ltv_mpc"):
        with tracked_run(True, uri, artifacts, "srmpc", f"evaluate-{controller}", _params(controller), "a: 1\n") as run:
            run.log_metrics({"mean_event_cost": 0.1})
    table = tmp_path / "table.md"
    table.write_text("| table |\n")
    (tmp_path / "videos").mkdir()
    (tmp_path / "videos" / "srmpc_light.mp4").write_bytes(b"\0")
    finish_parent_run(uri, parent, [("table", table), ("videos", tmp_path / "videos"),
                                    ("figures", tmp_path / "missing")], succeeded=True)

    client = mlflow.MlflowClient(uri)
    experiment = client.get_experiment_by_name("srmpc")
    children = client.search_runs([experiment.experiment_id], f"tags.mlflow.parentRunId = '{parent}'")
    assert sorted(r.data.tags["method"] for r in children) == ["ltv_mpc", "srmpc"]
    assert all(r.data.tags["traffic"] == "light" and r.data.tags["seed"] == "3" for r in children)
    assert client.get_run(parent).info.status == "FINISHED"
    logged = {a.path for a in client.list_artifacts(parent)} | {a.path for a in client.list_artifacts(parent, "videos")}
    assert {"table", "videos", "videos/srmpc_light.mp4"} <= logged


def test_an_unknown_parent_leaves_the_run_standalone(store, monkeypatch, capsys):
    uri, artifacts = store
    monkeypatch.setenv(PARENT_RUN_ENV, "0123456789abcdef0123456789abcdef")
    with tracked_run(True, uri, artifacts, "srmpc", "alone", _params(), "a: 1\n") as run:
        run_id = run.run_id
    assert "stands alone" in capsys.readouterr().err
    assert "mlflow.parentRunId" not in mlflow.MlflowClient(uri).get_run(run_id).data.tags


def _history(uri, key):
    client = mlflow.MlflowClient(uri)
    (run,) = client.search_runs([client.get_experiment_by_name("srmpc").experiment_id])
    return run, sorted((m.step, m.value) for m in client.get_metric_history(run.info.run_id, key))


def test_buffered_metrics_all_arrive_in_few_writes(store, monkeypatch):
    uri, artifacts = store
    writes = []
    original = mlflow.MlflowClient.log_batch
    monkeypatch.setattr(mlflow.MlflowClient, "log_batch",
                        lambda self, run_id, metrics=(), **kw: writes.append(len(metrics)) or
                        original(self, run_id, metrics=metrics, **kw))
    with tracked_run(True, uri, artifacts, "srmpc", "evaluate-srmpc", _params(), "a: 1\n") as run:
        run.flush_every_s = 3600.0
        for episode in range(1100):  # 5 values each, as an evaluation's episodes
            run.log_metrics({f"episode/{k}": float(episode) for k in "abcde"}, step=episode)
        run.log_metrics({"mean_event_cost": 0.25})
    mlflow_run, history = _history(uri, "episode/c")
    assert history == [(e, float(e)) for e in range(1100)]
    assert mlflow_run.data.metrics["mean_event_cost"] == 0.25 and mlflow_run.info.status == "FINISHED"
    metric_writes = [n for n in writes if n]  # log_params also goes through log_batch, without metrics
    assert metric_writes == [1000] * 5 + [501]  # full batches of 1000 values, then the rest at the end


def test_buffered_metrics_of_a_failed_run_are_kept(store):
    uri, artifacts = store
    with pytest.raises(SystemExit):
        with tracked_run(True, uri, artifacts, "srmpc", "evaluate-srmpc", _params(), "a: 1\n") as run:
            for episode in range(3):
                run.log_metrics({"episode/c": float(episode)}, step=episode)
            raise SystemExit(143)  # SIGTERM's path
    mlflow_run, history = _history(uri, "episode/c")
    assert history == [(0, 0.0), (1, 1.0), (2, 2.0)] and mlflow_run.info.status == "FAILED"
