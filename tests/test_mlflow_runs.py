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


# --- what a run logs: its name carries the overrides beyond its experiment; its params are the config's YAML ---

PARAM_CASES = [
    ["+experiment=smoke", "controller=ltv_mpc"],
    ["+experiment=table/ppo_sb3", "scenario=dense"],
    ["+experiment=nmpc/rollout", "scenario=light"],
    ["+experiment=crosscheck/highway_env_srmpc", "scenario=dense"],
    ["+experiment=rss/srmpc_recommended_ppo_lsi_rss", "scenario=light"],
    ["stage=train", "agent=ppo_lsi", "agent.seed=1"],
    ["stage=train", "+experiment=training/ppo_lsi_rss", "agent.seed=2"],
    ["stage=train_sb3", "agent=ppo", "agent.name=ppo_sb3"],
    ["stage=train", "agent=ppo", "agent.task=toy"],
]
"""Evaluations (the published cells' kinds: planners, policies, the NMPC, highway-env, RSS) and trainings."""


def _yaml_leaves(tree, prefix=""):
    """{"a": {"b": 1}} -> {"a.b": "1"}, computed here from the YAML text alone (not srmpc.tracking.flatten)."""
    leaves = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            leaves.update(_yaml_leaves(value, f"{prefix}{key}."))
        else:
            leaves[f"{prefix}{key}"] = str(value)
    return leaves


@pytest.mark.parametrize("overrides", PARAM_CASES, ids=" ".join)
def test_every_logged_param_is_spelled_as_the_config_yaml(store, overrides):
    """Each param the run logs equals the composed config's value as ``OmegaConf.to_yaml`` writes it (the config
    files' spelling): ``controller.name = ltv_mpc``, never the enum repr ``ControllerName.ltv_mpc``."""
    import re

    import yaml
    from omegaconf import OmegaConf

    from srmpc.__main__ import logged_params, tracked_run_name
    from srmpc.config.compose import compose_config, recorded_yaml, to_objects

    uri, artifacts = store
    cfg = compose_config([*overrides, "tracking.enabled=false"])
    name = tracked_run_name(to_objects(cfg), overrides)
    with tracked_run(True, uri, artifacts, "srmpc", name, logged_params(cfg), recorded_yaml(cfg)) as run:
        run_id = run.run_id
    logged = mlflow.MlflowClient(uri).get_run(run_id).data.params
    expected = _yaml_leaves(yaml.safe_load(OmegaConf.to_yaml(cfg, resolve=True)))
    enum_reprs = {k: v for k, v in logged.items() if re.fullmatch(r"[A-Z][A-Za-z]*\.\w+", v)}
    assert not enum_reprs, f"params logged as enum reprs: {enum_reprs}"
    assert logged == expected, {k: (logged.get(k), expected.get(k)) for k in set(logged) | set(expected)
                                if logged.get(k) != expected.get(k)}


@pytest.mark.parametrize(("overrides", "name"), [
    (["+experiment=table/srmpc", "scenario=dense"], "table/srmpc_dense"),  # a DVC cell: its folder's name
    (["+experiment=smoke", "controller=ltv_mpc"], "smoke_light controller=ltv_mpc"),
    (["+experiment=smoke", "controller=ltv_mpc", "tracking.enabled=false", "evaluation.output_dir=/tmp/x",
      "evaluation.workers=2"], "smoke_light controller=ltv_mpc"),  # where and how it runs: not its result
    (["+experiment=table/ltv_mpc", "scenario=light", "planner=margin_1m", "evaluation.episodes=5"],
     "table/ltv_mpc_light planner=margin_1m evaluation.episodes=5"),
    (["controller=ltv_mpc", "planner=margin_4m"], "evaluate-ltv_mpc-light planner=margin_4m"),
    (["stage=train", "agent=ppo_lsi", "agent.seed=1", "agent.output_dir=/tmp/t"],
     "train-ppo_lsi-twin_highway-light agent.seed=1"),
])
def test_a_runs_name_carries_the_overrides_beyond_its_experiment(overrides, name):
    from srmpc.__main__ import tracked_run_name
    from srmpc.config.compose import compose_config, to_objects

    assert tracked_run_name(to_objects(compose_config(overrides)), overrides) == name


def test_a_sweeps_runs_are_told_apart_by_name_and_found_by_their_params(tmp_path):
    """``python -m srmpc -m +experiment=smoke controller=srmpc,ltv_mpc``: two runs, named by the controller they
    sweep, each found by the filter ``params.controller.name = '<name>'``."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if k != PARENT_RUN_ENV}
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])  # this checkout's srmpc
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    result = subprocess.run(
        [sys.executable, "-m", "srmpc", "-m", "+experiment=smoke", "controller=srmpc,ltv_mpc", f"tracking.uri={uri}",
         f"tracking.artifact_location={tmp_path / 'mlruns'}"],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    client = mlflow.MlflowClient(uri)
    experiment = client.get_experiment_by_name("srmpc-smoke").experiment_id
    runs = client.search_runs([experiment])
    assert sorted(r.info.run_name for r in runs) == ["smoke_light controller=ltv_mpc", "smoke_light controller=srmpc"]
    for controller in ("srmpc", "ltv_mpc"):
        (found,) = client.search_runs([experiment], f"params.`controller.name` = '{controller}'")
        assert found.info.run_name == f"smoke_light controller={controller}"
        assert found.data.params["stage"] == "evaluate" and found.data.params["evaluation.simulator"] == "twin"
