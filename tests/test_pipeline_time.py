"""benchmarks/pipeline_time.py on a three-stage DVC project: which stages train, which are downstream of
training, and the per-stage times parsed from `dvc repro -f` as it runs."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("pipeline_time", ROOT / "benchmarks" / "pipeline_time.py")
pipeline_time = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(pipeline_time)

DVC_YAML = """stages:
  scenario:
    cmd: python -c "open('scenario.txt', 'w').write('s')"
    outs: [scenario.txt]
  train:
    cmd: python -c "import time; time.sleep(1.5); open('policy.txt', 'w').write('p')"
    deps: [scenario.txt]
    outs: [policy.txt]
  evaluate:
    cmd: python -c "open('episodes.txt', 'w').write(open('policy.txt').read())"
    deps: [policy.txt]
    outs: [episodes.txt]
  table:
    cmd: python -c "open('table.txt', 'w').write(open('episodes.txt').read())"
    deps: [episodes.txt]
    outs: [table.txt]
"""


@pytest.fixture
def project(tmp_path):
    for command in (["git", "init", "-q"], [str(Path(sys.executable).parent / "dvc"), "init", "-q"]):
        subprocess.run(command, cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "dvc.yaml").write_text(DVC_YAML)
    return tmp_path


def test_stage_kinds_follow_the_graph(project):
    assert pipeline_time.training_stage_names(project / "dvc.yaml") == set()  # no srmpc training command
    kinds = pipeline_time.stage_kinds(project, {"train"})
    assert kinds == {"scenario": "other", "train": "training", "evaluate": "downstream", "table": "downstream"}


def test_training_stages_are_found_by_their_command(tmp_path):
    (tmp_path / "dvc.yaml").write_text(
        "stages:\n  a:\n    cmd: python -m srmpc stage=train agent=ppo\n"
        "  b:\n    cmd: python pipelines/train_runs.py 'agent=ppo'\n"
        "  c:\n    cmd: python -m srmpc +experiment=light_traffic\n")
    assert pipeline_time.training_stage_names(tmp_path / "dvc.yaml") == {"a", "b"}


def test_timed_repro_times_every_stage_in_order(project):
    wall, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent,
                                                         project / "repro.log", project / "partial.json")
    assert returncode == 0
    assert [s["name"] for s in stages] == ["scenario", "train", "evaluate", "table"]
    assert stages[1]["wall_s"] >= 1.5  # the stage that sleeps
    assert all(s["wall_s"] > 0 for s in stages)
    assert abs(sum(s["wall_s"] for s in stages) + stages[0]["started_s"] - wall) < 1e-6
    outputs = pipeline_time.locked_outputs(project / "dvc.lock")
    assert set(outputs) == {"scenario.txt", "policy.txt", "episodes.txt", "table.txt"}
    assert all(len(md5) == 32 for md5 in outputs.values())


def test_a_failing_stage_gives_its_exit_code(project):
    (project / "dvc.yaml").write_text(DVC_YAML.replace("open('table.txt', 'w')", "exit(3) or open('table.txt', 'w')"))
    wall, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent,
                                                         project / "repro.log", project / "partial.json")
    assert returncode != 0 and stages[-1]["name"] == "table"
