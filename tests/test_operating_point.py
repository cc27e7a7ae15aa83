"""The paper's operating point: the common slack-price scale, the frozen planner option and the
calibration script (pipelines/operating_point_calibration.py) on a 2-episode probe."""

import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from pipelines import operating_point
from pipelines import operating_point_calibration as calibration
from srmpc.config.compose import CONFIG_DIR, ConfigError, compose_config, to_objects
from srmpc.controller_factory import planner_ocp
from tests.test_tradeoff import write_evaluation

PRICES = ("collision_slack_linear", "collision_slack_quadratic", "safety_slack_linear", "safety_slack_quadratic")


def test_slack_price_scale_multiplies_the_four_slack_prices():
    default = planner_ocp(to_objects(compose_config([])))[0].weights
    scaled = planner_ocp(to_objects(compose_config(["planner.slack_price_scale=0.01"])))[0].weights
    for name in PRICES:
        assert getattr(scaled, name) == pytest.approx(0.01 * getattr(default, name), rel=1e-12)
    assert (scaled.state, scaled.input, scaled.input_rate) == (default.state, default.input, default.input_rate)


@pytest.mark.parametrize("value", ["0", "-0.1", "1.5", "nan"])
def test_slack_price_scale_outside_its_range_is_one_line_naming_the_key(value):
    with pytest.raises(ConfigError) as error:
        compose_config([f"planner.slack_price_scale={value}"])
    assert "planner.slack_price_scale=" in str(error.value) and "\n" not in str(error.value)
    assert "(0, 1]" in str(error.value)


def test_the_frozen_option_lists_only_what_differs_from_ltv_mpc():
    path = CONFIG_DIR / "planner" / "paper_operating_point.yaml"
    option = yaml.safe_load(path.read_text())
    assert option["defaults"] == ["ltv_mpc", "_self_"]
    ltv_mpc = compose_config(["planner=ltv_mpc"]).planner  # the OCP's defaults (ltv_mpc.yaml repeats none)
    for key, value in option.items():
        if key != "defaults":
            assert list(ltv_mpc[key]) != value if isinstance(value, list) else ltv_mpc[key] != value, key
    assert 1 <= len(option) - 1 <= 3  # at most three knobs
    spec = yaml.safe_load(calibration.PROBES.read_text())
    assert spec["frozen"] == "paper_operating_point"
    assert spec["frozen_probe"] in [p["name"] for p in spec["probes"]]


def test_calibration_script_on_a_two_episode_probe(tmp_path):
    probes = tmp_path / "probes.yaml"
    probes.write_text(yaml.safe_dump({"seed": 200000, "traffic": "light", "probes": [
        {"name": "tiny", "episodes": 2, "overrides": ["planner.slack_price_scale=0.5",
                                                      "scenario.episode_steps=20"]}]}))
    calibration.main(["--probes", str(probes), "--output", str(tmp_path / "out"),
                      "--figure", str(tmp_path / "calibration.png"), "--resamples", "50"])
    rows = pd.read_csv(tmp_path / "out" / "calibration.csv")
    assert list(rows["probe"]) == ["tiny"] and rows.loc[0, "episodes"] == 2
    assert rows.loc[0, "slack_price_scale"] == 0.5 and rows.loc[0, "first_seed"] == 200000
    for key in ("mean_event_cost", "mean_vx", "mean_n_steps", "mean_return_per_step", "cost_rate"):
        assert rows.loc[0, f"{key}_ci95_low"] <= rows.loc[0, key] <= rows.loc[0, f"{key}_ci95_high"]
    assert "| tiny | 2 | 0.5 |" in (tmp_path / "out" / "calibration.md").read_text()
    assert (tmp_path / "calibration.png").stat().st_size > 0
    episodes = pd.read_csv(tmp_path / "out" / "probes" / "tiny" / "episodes.csv")
    assert list(episodes["seed"]) == [200000, 200001]


@pytest.mark.parametrize(("spec", "fragment"), [
    ({"seed": 0, "probes": [{"name": "a", "episodes": 2}]}, "seed=0: calibration seeds must be >= 200000"),
    ({"seed": 200000, "probes": [{"name": "a", "episodes": 201}]}, "episodes=201: must be in [1, 200]"),
    ({"seed": 200000, "probes": [{"name": "a", "episodes": 2}, {"name": "a", "episodes": 3}]}, "unique"),
])
def test_calibration_refuses_the_table_seeds_and_large_probes(tmp_path, spec, fragment):
    probes = tmp_path / "probes.yaml"
    probes.write_text(yaml.safe_dump(spec))
    with pytest.raises(SystemExit, match=fragment.replace("[", r"\[").replace("]", r"\]")):
        calibration.read_probes(probes)


def test_reproduction_table_gives_verdicts_claims_and_what_was_fitted(tmp_path, monkeypatch):
    """pipelines/operating_point.py on hand-made evaluations (tests/test_tradeoff.py's writer)."""
    import json

    from omegaconf import OmegaConf

    planner = OmegaConf.to_container(compose_config(["planner=paper_operating_point"]).planner, resolve=True)
    twin, sweep = tmp_path / "twin", tmp_path / "tradeoff"

    def at_the_operating_point(directory: Path, *args, **kwargs) -> None:
        write_evaluation(directory, *args, **kwargs)
        config = yaml.safe_load((directory / "config.yaml").read_text())
        (directory / "config.yaml").write_text(yaml.safe_dump({**config, "planner": planner}))

    for traffic in ("light", "dense"):  # SRMPC safer and faster than both, PPO-L-SI the most crashes
        write_evaluation(twin / f"ppo_lsi_{traffic}", "ppo_lsi", traffic, 8, 23.0, 80)
        write_evaluation(twin / f"ltv_mpc_{traffic}", "ltv_mpc", traffic, 8, 21.0, 8)  # the default planner's
        at_the_operating_point(sweep / f"a_{traffic}", "ltv_mpc", traffic, 1, 23.4, 120)  # names don't matter
        at_the_operating_point(sweep / f"b_{traffic}", "srmpc", traffic, 1, 24.0, 10)
        at_the_operating_point(sweep / f"c_{traffic}", "srmpc", traffic, 1, 24.7, 2, "track_rollout")
    monkeypatch.setattr(operating_point, "TWIN", twin)
    monkeypatch.setattr(operating_point, "TRADEOFF", sweep)
    monkeypatch.setattr(operating_point, "CALIBRATION", tmp_path / "none.csv")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").mkdir()
    monkeypatch.setattr(sys, "argv", ["operating_point.py", "--resamples", "200"])
    operating_point.main()
    result = json.loads((tmp_path / "results" / "operating_point.json").read_text())
    ltv = result["light"]["ltv_mpc"]
    assert ltv["roles"]["mean_event_cost"] == "fitted" and ltv["roles"]["mean_vx"] == "fitted"
    assert result["dense"]["ltv_mpc"]["roles"]["mean_vx"] == "predicted"
    assert ltv["verdicts"]["mean_event_cost"] == "inside"  # the paper's 0.625 against 120 / 200 = 0.6 [0.53, 0.66]
    assert ltv["verdicts"]["mean_vx"] == "above"  # the paper's 24.38 m/s against ours near 23.4
    assert set(ltv["verdicts"]) == {"mean_return_per_step", "mean_event_cost", "cost_rate", "mean_n_steps", "mean_vx"}
    verdicts = {(c["traffic"], c["claim"].split(" (")[0]): c["verdict"] for c in result["claims"]}
    assert verdicts[("light", "SRMPC has the lowest J_c")] == "holds"
    assert verdicts[("light", "SRMPC's J_c and rho_c more than 65% below LTV-MPC's")] == "holds"
    assert "Stretch" in (tmp_path / "results" / "operating_point.md").read_text()
