"""Every experiment composes; bad input exits non-zero with one line naming the key and value."""

import re
import subprocess
import sys
from enum import Enum
from pathlib import Path
from typing import Any

import pytest
import yaml
from omegaconf import DictConfig, ListConfig, OmegaConf

from srmpc.config.compose import CONFIG_DIR, ConfigError, compose_config, to_objects
from srmpc.config.schema import Config
from srmpc.scenario.parameters import ScenarioParameters

EXPERIMENTS = sorted(p.relative_to(CONFIG_DIR / "experiment").with_suffix("").as_posix()
                     for p in (CONFIG_DIR / "experiment").rglob("*.yaml"))
COMPOSITION_CHECKED = [e for e in EXPERIMENTS if e.startswith("training/") or "/" not in e
                       or e == min(x for x in EXPERIMENTS if x.split("/")[0] == e.split("/")[0])]
"""The experiments whose values are checked here: every training and top-level one, and the first of each question
folder; every published cell's composed config is checked byte for byte against its folder's config.yaml by
tests/test_dvc_pipeline.py, which composes each anyway."""
GROUPS = ("scenario", "agent", "planner", "controller", "evaluation", "tracking")


def _flat(values: dict, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}; lists and null are leaves."""
    flat = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat |= _flat(value, f"{prefix}{key}.")
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def file_values(path: Path, group: str | None = None) -> dict[str, Any]:
    """What the conf/ file ``path`` sets, read from its YAML alone (not through Hydra): {dotted key: value},
    its defaults list first (``/experiment/<name>``, ``override /<group>: <option>``, a same-group option),
    then its own values. ``group``: the group the file is an option of (None: an experiment, @package _global_)."""
    data = yaml.safe_load(path.read_text()) or {}
    values: dict[str, Any] = {}
    for entry in data.pop("defaults", []):
        if entry == "_self_":
            continue
        if isinstance(entry, str) and entry.startswith("/experiment/"):
            values |= file_values(CONFIG_DIR / f"{entry[1:]}.yaml")
        elif isinstance(entry, str):  # another option of the same group
            values |= file_values(path.with_name(f"{entry}.yaml"), group)
        else:
            ((key, option),) = entry.items()
            other = key.removeprefix("override ").strip("/")
            values |= file_values(CONFIG_DIR / other / f"{option}.yaml", other)
    return values | _flat(data, f"{group}." if group else "")


def plain(value: Any) -> Any:
    """A composed or typed value as YAML writes it: enums by value, tuples and ListConfigs as lists."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, DictConfig | ListConfig):
        value = OmegaConf.to_container(value, resolve=True)
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


def attribute(obj: Any, key: str) -> Any:
    for name in key.split("."):
        obj = getattr(obj, name)
    return obj


def assert_holds(cfg: DictConfig, values: dict[str, Any], where: str) -> None:
    """Each of ``values`` is in the composed ``cfg`` and in its typed objects, unchanged."""
    config = to_objects(cfg)
    assert isinstance(config, Config)
    for key, value in values.items():
        assert plain(OmegaConf.select(cfg, key)) == value, f"{where}: composed {key}"
        assert plain(attribute(config, key)) == value, f"{where}: typed {key}"


def test_the_paper_experiments_exist():
    assert {"light_traffic", "dense_traffic", "smoke"} <= set(EXPERIMENTS)
    assert {"training/multiplier_ablation/ppo_lsi", "training/multiplier_ablation/ppo"} <= set(EXPERIMENTS)
    assert {"table/srmpc", "table/ltv_mpc", "operating_point/ltv_mpc", "nmpc/rollout"} <= set(EXPERIMENTS)


def test_file_values_reads_defaults_then_own_values():
    """The reader the two tests below check the composition against, on files whose values are written here."""
    assert file_values(CONFIG_DIR / "experiment" / "confirmation" / "srmpc_recommended.yaml") == {
        "controller.srmpc.tracking": "policy_rollout", "planner.safety_margin_longitudinal_m": 1.0,
        "evaluation.seed": 100000}
    assert file_values(CONFIG_DIR / "planner" / "paper_operating_point.yaml", "planner") == {
        "planner.slack_price_scale": 0.05, "planner.state_weights": [0.0, 0.5, 20.0, 10.0],
        "planner.safety_margin_longitudinal_m": 1.0}


@pytest.mark.parametrize("experiment", COMPOSITION_CHECKED)
def test_every_experiment_composes_into_the_schema_with_the_values_its_file_sets(experiment):
    """Every value the experiment file sets (through its defaults list too: included experiments, group
    options) is in the composed config and in its typed objects; a group it names nothing of is the default's."""
    cfg = compose_config([f"+experiment={experiment}"])
    values = file_values(CONFIG_DIR / "experiment" / f"{experiment}.yaml")
    assert values or experiment == "table/srmpc", experiment  # the table's SRMPC is conf/config.yaml itself
    published = "/" in experiment and not experiment.startswith("training/")
    if published:  # it evaluates into its own folder (srmpc.config.compose.with_experiment_name)
        values.pop("evaluation.output_dir", None)
        assert cfg.evaluation.output_dir == f"results/evaluation/{experiment}_light"
        cfg.evaluation.output_dir = None
    else:
        assert cfg.evaluation.output_dir is None
    assert_holds(cfg, values, experiment)
    assert cfg.experiment == experiment
    assert isinstance(to_objects(cfg).scenario, ScenarioParameters)
    groups = {key.split(".")[0] for key in values}
    base = compose_config([])
    for group in GROUPS:
        if group not in groups:
            assert cfg[group] == base[group], f"{experiment} changed {group}, which its file does not name"


@pytest.mark.parametrize("group", GROUPS)
def test_every_group_option_composes_to_its_values_and_changes_only_its_group(group):
    base = compose_config([])
    for option in sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml")):
        cfg = compose_config([f"{group}={option}"])
        values = file_values(CONFIG_DIR / group / f"{option}.yaml", group)
        assert_holds(cfg, values, f"{group}={option}")
        for other in GROUPS:
            if other != group:
                assert cfg[other] == base[other], f"{group}={option} changed {other}"


def test_dense_traffic_differs_from_light_only_in_traffic():
    light = to_objects(compose_config(["+experiment=light_traffic"])).scenario
    dense = to_objects(compose_config(["+experiment=dense_traffic"])).scenario
    assert (light.mean_spawn_gap_m, dense.mean_spawn_gap_m) == (25.0, 15.0)
    assert light.vehicles_count == dense.vehicles_count and light.episode_steps == dense.episode_steps == 400


@pytest.mark.parametrize(
    ("override", "fragments"),
    [
        ("scenario.episode_steps=abc", ["scenario.episode_steps", "'abc'"]),
        ("scenario.typo=1", ["scenario.typo", "'typo'"]),
        ("scenario=foo", ["scenario=foo", "dense, light"]),
        ("+experiment=nope", ["experiment=nope", "smoke"]),
        ("controller=zzz", ["controller=zzz", "ltv_mpc"]),
        ("evaluation.controller=nmpc_rollout", ["evaluation.controller is gone", "controller.initial_guess=rollout"]),
        ("controller.initial_guess=rollout", ["controller.initial_guess=rollout", "controller=nmpc only"]),
        ("scenario.mean_spawn_gap_m=-1", ["scenario.mean_spawn_gap_m=-1.0"]),
        ("scenario.safety_index.n=0", ["scenario.safety_index.n=0.0"]),
        ("controller.srmpc.relinearizations=-1", ["relinearizations=-1"]),
        ("evaluation.episodes=0", ["evaluation.episodes=0"]),
        ("evaluation.seed=-3", ["evaluation.seed=-3"]),
        ("controller.srmpc.selection=zzz", ["controller.srmpc.selection", "'zzz'"]),
        ("controller.srmpc.rollout=nearby", ["controller.srmpc.rollout", "'nearby'"]),
        ("srmpc=nope", ["srmpc=nope", "srmpc is gone", "controller.srmpc"]),
        ("srmpc.variant=track_rollout", ["srmpc.variant is gone"]),
        ("+policy=ppo_lsi_rss", ["policy is gone", "controller.policy=<agent>"]),
    ],
)
def test_bad_config_is_one_clear_error(override, fragments):
    with pytest.raises(ConfigError) as error:
        compose_config([override])
    message = str(error.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message


@pytest.mark.parametrize(
    ("override", "line"),
    [
        ("scenario.episode_steps=abc",
         "scenario.episode_steps: Value 'abc' of type 'str' could not be converted to Integer"),
        ("agent.actor_lr=nan", "agent.actor_lr=nan: must be a finite number > 0"),
    ],
)
def test_cli_bad_value_exits_non_zero_with_one_line(tmp_path, override, line):
    result = subprocess.run(
        [sys.executable, "-m", "srmpc", "stage=train", override],
        capture_output=True, text=True, cwd=tmp_path, timeout=600,
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [f"srmpc: config error: {line}"]
    assert "Traceback" not in result.stderr and not Path(tmp_path, "mlflow.db").exists()
    assert not Path(tmp_path, "results").exists() and not Path(tmp_path, "outputs").exists()


@pytest.mark.parametrize(
    ("override", "fragment"),
    [
        ("agent.actor_lr=-1", "agent.actor_lr=-1.0: must be a finite number > 0"),
        ("scenario.reward.scale=inf", "scenario.reward.scale=inf: must be a finite number > 0"),
        ("agent.gamma=0", "agent.gamma=0.0: must be a finite number in (0, 1]"),
        ("agent.hidden_sizes=[]", "agent.hidden_sizes=[]: must be a non-empty list of integers, each in [1, 4096]"),
        ("planner.state_weights=[1,1,1]", "planner.state_weights=[1.0, 1.0, 1.0]: must be a list of 4 finite"),
        ("tracking.experiment_name=''", "tracking.experiment_name='': must be a non-empty string"),
    ],
)
def test_values_the_issue_names_are_refused(override, fragment):
    with pytest.raises(ConfigError, match=re.escape(fragment)):
        compose_config([override])


def test_every_committed_config_still_validates():
    """Validation only narrowed what is accepted: every config a committed result was made with passes."""
    paths = sorted((CONFIG_DIR.parent / "results").rglob("config.yaml"))
    assert len(paths) >= 100  # the evaluation and training folders of results/, not a few
    for path in paths:
        stored = yaml.safe_load(path.read_text())
        stored.pop("policy_sha256", None)
        stored.pop("implementation", None)  # stage=train_sb3 records its library beside the config
        config = to_objects(OmegaConf.merge(OmegaConf.structured(Config), stored))
        for key, value in _flat(stored).items():  # validated, the result's config is the one it was made with
            assert plain(attribute(config, key)) == value, f"{path.relative_to(CONFIG_DIR.parent)}: {key}"


@pytest.mark.parametrize(
    ("override", "fragment"),
    [
        ("planner.horizon_steps=100000", "planner.horizon_steps=100000: must be an integer in [2, 400]"),
        ("planner.max_vehicles=1000000", "planner.max_vehicles=1000000: must be an integer in [6, 40]"),
        ("planner.n_ego_circles=1000000", "planner.n_ego_circles=1000000: must be an integer in [2, 16]"),
        ("scenario.vehicles_count=1000000", "scenario.vehicles_count=1000000: must be an integer in [1, 6000]"),
        ("scenario.episode_steps=1000000000", "scenario.episode_steps=1000000000: must be an integer in [1, 10000]"),
        ("agent.hidden_sizes=[64,1000000000]", "agent.hidden_sizes=[64, 1000000000]: must be a non-empty list of "
                                               "integers, each in [1, 4096]"),
        ("agent.num_envs=1000000000", "agent.num_envs=1000000000: must be an integer in [1, 65536]"),
        ("agent.frames_per_batch=10000000000", "agent.frames_per_batch=10000000000: must be an integer in "
                                               "[1, 4194304]"),
    ],
)
def test_sizes_are_bounded_by_what_the_planner_and_the_twin_hold(override, fragment):
    """Each of these once hung for minutes or died in an allocator (MemoryError, torch's RuntimeError)."""
    with pytest.raises(ConfigError, match=re.escape(fragment)):
        compose_config([override])


def test_cli_refuses_an_unbounded_horizon_in_seconds(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "srmpc", "+experiment=smoke", "planner.horizon_steps=100000"],
        capture_output=True, text=True, cwd=tmp_path, timeout=120,
    )
    assert result.returncode == 2
    assert [line for line in result.stderr.splitlines() if line.strip()] == [
        "srmpc: config error: planner.horizon_steps=100000: must be an integer in [2, 400]"]


def test_each_variant_experiment_is_named_by_the_variant_its_settings_make():
    """conf/experiment/variants/<name>.yaml is SRMPC's variant ``<name>`` (srmpc.controllers.srmpc.variant_of)."""
    from srmpc.controllers.srmpc import variant_of

    names = sorted(p.stem for p in (CONFIG_DIR / "experiment" / "variants").glob("*.yaml"))
    assert names == ["best_of_two", "local_rollout", "rollout_prediction", "sqp", "track_rollout"]
    for name in names:
        assert variant_of(to_objects(compose_config([f"+experiment=variants/{name}"])).controller.srmpc) == name
    both = to_objects(compose_config(["controller.srmpc.relinearizations=2",
                                      "controller.srmpc.tracking=policy_rollout"]))
    assert variant_of(both.controller.srmpc) == "sqp+track_rollout"
