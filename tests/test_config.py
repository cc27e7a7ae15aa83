"""Every experiment composes; bad input exits non-zero with one line naming the key and value."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from srmpc.config.compose import CONFIG_DIR, ConfigError, compose_config, to_objects
from srmpc.config.schema import Config
from srmpc.scenario.parameters import ScenarioParameters

EXPERIMENTS = sorted(p.relative_to(CONFIG_DIR / "experiment").with_suffix("").as_posix()
                     for p in (CONFIG_DIR / "experiment").rglob("*.yaml"))


def test_the_paper_experiments_exist():
    assert {"light_traffic", "dense_traffic", "smoke"} <= set(EXPERIMENTS)
    assert {"multiplier_ablation/ppo_lsi", "multiplier_ablation/ppo"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_composes_into_the_schema(experiment):
    config = to_objects(compose_config([f"+experiment={experiment}"]))
    assert isinstance(config, Config) and isinstance(config.scenario, ScenarioParameters)


@pytest.mark.parametrize("group", ["scenario", "agent", "planner", "srmpc", "evaluation", "tracking"])
def test_every_group_option_composes(group):
    for option in sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml")):
        to_objects(compose_config([f"{group}={option}"]))


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
        ("evaluation.controller=zzz", ["evaluation.controller", "'zzz'"]),
        ("scenario.mean_spawn_gap_m=-1", ["scenario.mean_spawn_gap_m=-1.0"]),
        ("scenario.safety_index.n=0", ["scenario.safety_index.n=0.0"]),
        ("srmpc.relinearizations=-1", ["srmpc.relinearizations=-1"]),
        ("evaluation.episodes=0", ["evaluation.episodes=0"]),
        ("evaluation.seed=-3", ["evaluation.seed=-3"]),
        ("srmpc.selection=zzz", ["srmpc.selection", "'zzz'"]),
        ("srmpc=nope", ["srmpc=nope", "best_of_two"]),
        ("srmpc.variant=track_rollout", ["srmpc.variant='track_rollout'", "tracking=lane_centre", "variant 'paper'"]),
        ("srmpc.tracking=policy_rollout", ["srmpc.variant='paper'", "variant 'track_rollout'"]),
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
    import yaml
    from omegaconf import OmegaConf

    paths = sorted((CONFIG_DIR.parent / "results").rglob("config.yaml"))
    assert paths
    for path in paths:
        stored = yaml.safe_load(path.read_text())
        stored.pop("policy_sha256", None)
        stored.pop("implementation", None)  # stage=train_sb3 records its library beside the config
        to_objects(OmegaConf.merge(OmegaConf.structured(Config), stored))


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


def test_each_srmpc_option_is_named_by_the_variant_its_settings_make():
    """conf/srmpc/<name>.yaml sets ``variant: <name>``, and that is what its settings make (variant_of)."""
    from srmpc.config.schema import variant_of

    for option in sorted(p.stem for p in (CONFIG_DIR / "srmpc").glob("*.yaml")):
        srmpc = to_objects(compose_config([f"srmpc={option}"])).srmpc
        assert srmpc.variant == variant_of(srmpc) == option
    both = to_objects(compose_config(["srmpc=sqp", "srmpc.tracking=policy_rollout", "srmpc.variant=sqp+track_rollout"]))
    assert both.srmpc.variant == "sqp+track_rollout"
