"""pipelines/reproduction_check.py: a user's ``dvc repro`` against the committed results.

The fixture is a small git repository holding the committed outputs of six stages of this one (a training, its
designation, two evaluations, the table) with their entries of the committed ``dvc.lock``: the hashes are DVC's own,
so a clean checkout reporting every output equal checks the hashing too. Each test works in a fresh clone of it.
"""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import pandas as pd
import pytest
import yaml

from pipelines import reproduction_check

ROOT = Path(reproduction_check.ROOT)
STAGES = ("train", "designate_policy@ppo_lsi", "experiments", "evaluate@table/srmpc-light",
          "evaluate@table/ltv_mpc-light", "table")
EPISODES = "results/evaluation/table/srmpc_light/episodes.csv"


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.com", *args], cwd=cwd,
                          check=True, capture_output=True, text=True).stdout


@pytest.fixture(scope="module")
def committed(tmp_path_factory) -> Path:
    """A repository: a first commit without dvc.lock, then the six stages' outputs and their dvc.lock."""
    repository = tmp_path_factory.mktemp("committed")
    lock = yaml.load(_git(ROOT, "show", "HEAD:dvc.lock"), Loader=yaml.CSafeLoader)
    lock["stages"] = {name: lock["stages"][name] for name in STAGES}
    paths = [out["path"] for stage in lock["stages"].values() for out in stage["outs"]]
    archive = subprocess.run(["git", "archive", "HEAD", "--", "dvc.yaml", ".dvcignore", *paths], cwd=ROOT,
                             check=True, capture_output=True).stdout
    _git(repository, "init", "-q")
    (repository / "README.md").write_text("before the pipeline\n")
    _git(repository, "add", "README.md")
    _git(repository, "commit", "-q", "-m", "no dvc.lock")
    subprocess.run(["tar", "-x"], input=archive, cwd=repository, check=True)
    (repository / "dvc.lock").write_text(yaml.safe_dump(lock, sort_keys=False))
    _git(repository, "add", ".")
    _git(repository, "commit", "-q", "-m", "the pipeline's outputs")
    return repository


@pytest.fixture
def clone(committed, tmp_path) -> Path:
    _git(tmp_path, "clone", "-q", str(committed), "clone")
    return tmp_path / "clone"


def _check(clone: Path, capsys, *args: str) -> tuple[int, dict, str]:
    code = reproduction_check.main(["--json", str(clone.parent / "report.json"), *args], root=clone)
    return code, json.loads((clone.parent / "report.json").read_text()), capsys.readouterr().out


def test_a_clean_checkout_equals_every_committed_output(clone, capsys):
    code, report, out = _check(clone, capsys)
    outs = sum(len(stage["outs"]) for stage in yaml.safe_load((clone / "dvc.lock").read_text())["stages"].values())
    assert code == 0 and report["all_equal"] and report["first_differing_stage"] is None
    assert report["outputs"] == {"total": outs, "equal": outs, "equal_apart_from_machine": 0, "left_out": [],
                                 "differing": 0, "missing": 0}
    assert report["pairing"]["counts"]["table_cells"] == 2 and report["pairing"]["all_agree"]
    assert report["verdicts"]["compared"] and report["verdicts"]["all_agree"] and report["verdicts"]["claims"] > 0
    assert f"outputs: {outs} of {outs} equal the committed ones\n" in out and "table verdicts: all agree" in out
    assert "first stage that differs: none" in out


def test_a_changed_episode_names_its_evaluation_first_and_is_paired_on_the_seeds(clone, capsys):
    episodes = pd.read_csv(clone / EPISODES)
    episodes.loc[7, "mean_vx"] += 0.01  # one episode, a little faster: within the noise
    episodes.to_csv(clone / EPISODES, index=False)
    (clone / "results/table.md").write_text("regenerated\n")  # downstream of it
    code, report, out = _check(clone, capsys)
    assert code == 1 and not report["all_equal"]
    assert report["first_differing_stage"] == "evaluate@table/srmpc-light"
    assert report["downstream_of_first"] == ["table"] and report["differences_start_in"] == [
        "evaluate@table/srmpc-light"]
    assert report["outs"][EPISODES] == {"stage": "evaluate@table/srmpc-light", "status": "differs",
                                        "what": "columns mean_vx in 1 of 1000 rows"}
    cell = report["pairing"]["traffic"]["light"]["srmpc"]
    assert cell["identical_episodes"] == 999 and cell["episodes_paired"] == 1000 and cell["agrees"]
    assert report["pairing"]["all_agree"] and report["pairing"]["counts"]["table_cells_identical"] == 1
    assert "first stage that differs: evaluate@table/srmpc-light (1 other stage differs: 1 downstream of it" in out
    assert f"{EPISODES} [evaluate@table/srmpc-light]: columns mean_vx in 1 of 1000 rows" in out

    episodes["mean_vx"] += 1.0  # every episode 1 m/s faster: far outside the paired interval
    episodes.to_csv(clone / EPISODES, index=False)
    code, report, out = _check(clone, capsys)
    assert code == 1 and report["pairing"]["moved"] == ["table/srmpc light mean_vx"]
    assert not report["pairing"]["traffic"]["light"]["srmpc"]["agrees"] and "moved: table/srmpc light mean_vx" in out


def test_a_summary_that_differs_only_in_its_environment_counts_as_equal(clone, capsys):
    evaluation = clone / "results/evaluation/table/ltv_mpc_light/summary.json"
    training = clone / "results/training/ppo_lsi/seed_1/summary.json"  # inside the training's directory out
    for path in (evaluation, training):
        summary = json.loads(path.read_text())
        summary["environment"] = {"numerics": "pinned", "cpu": {"model": "another CPU"}}
        path.write_text(json.dumps(summary, indent=1))
    code, report, out = _check(clone, capsys)
    assert code == 0 and report["all_equal"]
    assert report["outputs"]["equal_apart_from_machine"] == 2 and report["outputs"]["left_out"] == ["environment"]
    assert "equal the committed ones (2 only after leaving out the machine record: environment)" in out

    summary["return"] += 1.0  # the rest differs too: not equal
    training.write_text(json.dumps(summary, indent=1))
    code, report, out = _check(clone, capsys)
    assert code == 1 and report["first_differing_stage"] == "train"
    assert report["outs"]["results/training/ppo_lsi/seed_1"]["files"] == {
        "summary.json": {"status": "differs", "what": "keys return"}}


def _rewrite_columns(path: Path, change: dict) -> None:
    """``path``'s CSV with each column of ``change`` mapped through its function, every other field as it was."""
    with path.open(newline="") as file:
        header, *rows = list(csv.reader(file))
    for column, function in change.items():
        i = header.index(column)
        for row in rows:
            row[i] = function(row[i])
    with path.open("w", newline="") as file:
        csv.writer(file).writerows([header, *rows])


def test_a_training_that_differs_only_in_its_wall_clock_times_counts_as_equal(clone, capsys):
    training = clone / "results/training/ppo_lsi/seed_0"  # the designated seed: designated.json copies its summary
    slower = {"wall_s": lambda v: repr(float(v) * 1.5), "env_steps_per_s": lambda v: repr(float(v) / 1.5)}
    _rewrite_columns(training / "metrics.csv", slower)
    designated = clone / "results/training/ppo_lsi/designated.json"
    for path in (training / "summary.json", designated):
        document = json.loads(path.read_text())
        summary = document.get("training_summary", document)
        summary["wall_s"] *= 1.5
        summary["environment"] = {"numerics": "native", "cpu": {"model": "another CPU"}}
        path.write_text(json.dumps(document, indent=2) + "\n")
    code, report, out = _check(clone, capsys)
    assert code == 0 and report["all_equal"] and report["first_differing_stage"] is None
    machine = ["environment", "wall_s", "env_steps_per_s"]
    assert report["outputs"]["equal_apart_from_machine"] == 2 and report["outputs"]["left_out"] == machine
    assert report["outs"]["results/training/ppo_lsi/seed_0"] == {"stage": "train", "status": "equal_apart_from_machine",
                                                                 "left_out": machine}
    assert report["outs"]["results/training/ppo_lsi/designated.json"]["left_out"] == ["environment", "wall_s"]
    assert ("equal the committed ones (2 only after leaving out wall-clock times and the machine record: environment, "
            "wall_s, env_steps_per_s)") in out

    _rewrite_columns(training / "metrics.csv", {"episode/return": lambda v: repr(float(v) + 1.0)})  # a result
    code, report, out = _check(clone, capsys)
    rows = len((training / "metrics.csv").read_text().splitlines()) - 1
    assert code == 1 and report["first_differing_stage"] == "train" and report["stages"]["differing"] == ["train"]
    assert report["outs"]["results/training/ppo_lsi/seed_0"]["files"] == {
        "metrics.csv": {"status": "differs", "what": f"columns episode/return in {rows} of {rows} rows"}}
    assert report["outputs"]["equal_apart_from_machine"] == 1  # designated.json

    policy = training / "policy.pt"
    policy.write_bytes(policy.read_bytes() + b"\0")  # a policy is compared byte for byte
    code, report, out = _check(clone, capsys)
    assert report["outs"]["results/training/ppo_lsi/seed_0"]["files"]["policy.pt"] == {"status": "differs",
                                                                                         "what": "bytes"}


def test_only_the_listed_wall_clock_fields_are_left_out():
    differing = reproduction_check.machine_fields_differing
    assert differing("results/a.json", b'{"x": {"wall_s": 1}}', b'{"x": {"wall_s": 2}}') == ["wall_s"]
    assert differing("results/a.json", b'{"response_time_ego_s": 1}', b'{"response_time_ego_s": 2}') is None
    assert differing("results/a.json", b'{"wall_s": 1}', b'{"wall_s":  1}') is None  # formatting: no field differs
    assert differing("results/a.csv", b"a,wall_s\n1,2\n", b"a,wall_s\n1,3\n") == ["wall_s"]
    assert differing("results/a.csv", b"a,wall_s\n1,2\n", b"a,wall_s\n1.0,3\n") is None  # fields as text
    assert differing("results/e/episodes.csv", b"a,wall_s\n1,2\n", b"a,wall_s\n1,3\n") is None
    assert differing("results/p.pt", b'{"wall_s": 1}', b'{"wall_s": 2}') is None


def test_bad_input_is_one_line_and_exit_2(clone, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))  # git looks for no repository above tmp_path
    for args, root, says in ((["--revision", "no-such-revision"], clone, "--revision no-such-revision: not a git "
                              "revision"),
                             (["--revision", "HEAD~1"], clone, "--revision HEAD~1: no dvc.lock there"),
                             ([], tmp_path / "empty", "not a git repository"),
                             (["--after", str(tmp_path / "nowhere")], clone, "no such directory")):
        (tmp_path / "empty").mkdir(exist_ok=True)
        assert reproduction_check.main(args, root=root) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.count("\n") == 1 and says in captured.err, captured.err
        assert captured.err.startswith("reproduction_check: ")


def test_a_verdict_of_the_table_that_moves_is_named(clone, capsys):
    table = json.loads((clone / "results/table.json").read_text())
    table["light"]["srmpc"]["paired_differences"]["ppo_lsi"]["mean_event_cost_ci95"] = [-0.1, 0.02]  # contains 0
    (clone / "results/table.json").write_text(json.dumps(table, indent=2) + "\n")
    code, report, out = _check(clone, capsys)
    assert code == 1 and report["first_differing_stage"] == "table" and not report["verdicts"]["all_agree"]
    (moved,) = report["verdicts"]["moved"]
    assert moved["traffic"] == "light" and moved["committed"].endswith(": lower.")
    assert moved["yours"].endswith(": not distinguishable.")
    assert 'light J_c, SRMPC vs PPO-L-SI: committed "lower", yours "not distinguishable"' in out
