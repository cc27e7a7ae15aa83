"""dvc.yaml reads in one pass: short commands, runs defined in conf/, and the committed results are theirs.

- every command, as written and as DVC renders it (``dvc.lock``), is at most 200 characters;
- the file is at most 250 lines (125 stages);
- every published experiment (conf/experiment/<question>/<name>.yaml) is a cell of stage ``evaluate`` in both
  traffic levels, and each cell's folder holds the config its experiment composes to, byte for byte;
- every stage of ``dvc.yaml`` is in ``dvc.lock`` with the command it renders to there, so the lock describes
  this pipeline, not an older one;
- each training directory's committed ``config.yaml`` is what its stage's run composes to today: a run
  defined in ``conf/experiment/training/multiplier_ablation/`` (or by agent and seed) resumes in its own directory
  instead of being refused there;
- ``dvc status`` finds every stage up to date: each dependency (code, config, upstream results) and each output
  has the hash ``dvc.lock`` records, so the committed results are those of the committed code (an edit to a
  stage's dependency, even a docstring, fails here until the stage is rerun, or ``dvc commit``-ed where the edit
  cannot change its outputs).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from omegaconf import OmegaConf

from srmpc.config.compose import compose_config
from srmpc.stages.train import training_identity_yaml

ROOT = Path(__file__).resolve().parents[1]
DVC_YAML = yaml.safe_load((ROOT / "dvc.yaml").read_text())
DVC_LOCK = yaml.safe_load((ROOT / "dvc.lock").read_text())
SPEC = importlib.util.spec_from_file_location("train_runs", ROOT / "pipelines" / "train_runs.py")
train_runs = importlib.util.module_from_spec(SPEC)
sys.modules["train_runs"] = train_runs  # its dataclass looks its module up
SPEC.loader.exec_module(train_runs)
MAX_CMD = 200
"""A stage's command as rendered, at most: one screen line and a bit."""


def _commands(stage: dict) -> str:
    return " ".join((stage.get("cmd") or stage["do"]["cmd"]).split())


def test_every_command_is_short_as_written_and_as_rendered():
    long = {name: len(_commands(stage)) for name, stage in DVC_YAML["stages"].items()
            if len(_commands(stage)) > MAX_CMD}
    long |= {name: len(stage["cmd"]) for name, stage in DVC_LOCK["stages"].items() if len(stage["cmd"]) > MAX_CMD}
    assert not long, f"commands over {MAX_CMD} characters: {long}"


def test_the_file_reads_in_one_pass():
    assert len((ROOT / "dvc.yaml").read_text().splitlines()) <= 250


def test_every_stage_is_locked_with_its_command():
    locked = DVC_LOCK["stages"]
    for name, stage in DVC_YAML["stages"].items():
        if "matrix" in stage or "foreach" in stage:  # name@<values>, one per combination
            instances = [key for key in locked if key.startswith(f"{name}@")]
            expected = len(stage["foreach"]) if "foreach" in stage else int(
                np.prod([len(values) for values in stage["matrix"].values()]))
            assert len(instances) == expected, f"{name}: {len(instances)} instances in dvc.lock, {expected} in dvc.yaml"
        else:
            assert name in locked, f"{name}: not in dvc.lock"
            assert " ".join(locked[name]["cmd"].split()) == _commands(stage), name


def _training_runs(cmd: str) -> list[list[str]]:
    """The runs one ``python -m pipelines.train_runs`` command names, each as its CLI overrides."""
    import shlex

    words = shlex.split(cmd)  # python -m pipelines.train_runs <arguments>
    runs, _ = train_runs.parse_arguments(words[words.index("pipelines.train_runs") + 1:])
    return [["stage=train", *shlex.split(run)] for run in runs]


@pytest.mark.parametrize("stage", ["train", "train_multiplier_ablation"])
def test_each_training_directory_holds_its_runs_config(stage):
    runs = _training_runs(DVC_YAML["stages"][stage]["cmd"])
    outs = [next(iter(out)) for out in DVC_YAML["stages"][stage]["outs"]]
    assert len(runs) == len(outs)
    for overrides in runs:
        container = OmegaConf.to_container(compose_config(overrides), resolve=True)
        agent = container["agent"]
        directory = agent["output_dir"] or f"results/training/{agent['name']}/seed_{agent['seed']}"
        assert directory in outs, f"{overrides}: writes {directory}, not an output of {stage}"
        committed = yaml.safe_load((ROOT / directory / "config.yaml").read_text())
        assert yaml.safe_load(training_identity_yaml(container)) == committed, (
            f"{overrides}: not the config of {directory}")


def test_runs_expand_per_seed_then_per_experiment_file():
    runs = train_runs.expand_runs(["agent=ppo_lsi", "agent=ppo"], [0, 1], "training/multiplier_ablation")
    assert runs[:4] == ["agent=ppo_lsi agent.seed=0", "agent=ppo_lsi agent.seed=1",
                        "agent=ppo agent.seed=0", "agent=ppo agent.seed=1"]
    assert runs[4:] == [f"+experiment=training/multiplier_ablation/{name}" for name in
                        ["fac", "ma", "ma_discounted", "ma_discounted_fast", "ma_fast", "per_step", "ppo", "ppo_lsi"]]
    with pytest.raises(SystemExit, match="--experiments nope: no experiment files"):
        train_runs.expand_runs([], [], "nope")


def _evaluation_runs() -> list[tuple[str, list[str], list[str]]]:
    """(stage instance, the ``python -m srmpc`` overrides, its deps) of every evaluation stage, matrices expanded."""
    import itertools
    import re
    import shlex

    runs = []
    for name, stage in DVC_YAML["stages"].items():
        if "python -m srmpc " not in _commands(stage) or "matrix" not in stage:
            continue
        keys = list(stage["matrix"])
        for values in itertools.product(*stage["matrix"].values()):
            item = dict(zip(keys, values, strict=True))

            def render(text: str, item=item) -> str:
                return re.sub(r"\$\{item\.(\w+)\}", lambda m: item[m.group(1)], text)

            words = shlex.split(render(_commands(stage)))
            runs.append((f"{name}@{'-'.join(values)}", words[words.index("srmpc") + 1:],
                         [render(dep) for dep in stage["deps"]]))
    return runs


EVALUATION_RUNS = _evaluation_runs()


def test_each_evaluation_directory_holds_its_runs_config():
    """Byte for byte, the committed ``config.yaml`` of every evaluation is what its stage composes today (output
    folder included): a moved folder resumes there, and the stage would rewrite none of its files."""
    from srmpc.config.compose import recorded_yaml, to_objects
    from srmpc.stages.evaluate import identity_yaml

    assert EVALUATION_RUNS
    for instance, overrides, _ in EVALUATION_RUNS:
        cfg = compose_config(overrides)
        composed = identity_yaml(to_objects(cfg), recorded_yaml(cfg))
        named = dict(o.lstrip("+").split("=", 1) for o in overrides)  # its own folder, by its name
        assert cfg.evaluation.output_dir == f"results/evaluation/{named['experiment']}_{named['scenario']}", instance
        directory = ROOT / cfg.evaluation.output_dir
        assert (directory / "config.yaml").read_text() == composed, f"{instance}: not the config of {directory}"


def test_every_published_experiment_is_a_cell_in_its_own_folder():
    """Stage ``evaluate`` runs every published experiment (pipelines/experiments.py) in both traffic levels (each
    into its own folder: the test above); its conf/ dependence is its composed identity (params)."""
    from pipelines.experiments import TRAFFIC, published_experiments

    stage = DVC_YAML["stages"]["evaluate"]
    assert sorted(stage["matrix"]["experiment"]) == published_experiments()
    assert stage["matrix"]["traffic"] == list(TRAFFIC)
    assert not any(dep.startswith("conf") for dep in stage["deps"])


def test_every_stage_is_up_to_date_with_the_committed_code():
    status = subprocess.run([str(Path(sys.executable).parent / "dvc"), "status", "--json"], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert status.returncode == 0, status.stderr[-2000:]
    stale = json.loads(status.stdout or "{}")
    assert not stale, f"{len(stale)} stage(s) not up to date (dvc status): " + "; ".join(
        f"{name}: {changes}" for name, changes in list(stale.items())[:5])
