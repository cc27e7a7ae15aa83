"""The paper's operating point: the common slack-price scale, the frozen option and the declared rule's probe,
the calibration script (pipelines/operating_point_calibration.py) on a 2-episode probe, how it tells the choice and
names probes in its figure, and the reproduction table (pipelines/operating_point.py) at both options."""

import sys

import pandas as pd
import pytest
import yaml

from pipelines import operating_point, reporting
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


@pytest.mark.parametrize(("option", "key"), [("paper_operating_point", "frozen"),
                                           ("declared_rule_probe", "declared_rule_option")])
def test_each_option_lists_only_what_differs_from_ltv_mpc(option, key):
    path = CONFIG_DIR / "planner" / f"{option}.yaml"
    values = yaml.safe_load(path.read_text())
    assert values["defaults"] == ["ltv_mpc", "_self_"]
    ltv_mpc = compose_config(["planner=ltv_mpc"]).planner  # the OCP's defaults (ltv_mpc.yaml repeats none)
    for name, value in values.items():
        if name != "defaults":
            assert list(ltv_mpc[name]) != value if isinstance(value, list) else ltv_mpc[name] != value, name
    assert 1 <= len(values) - 1 <= 3  # at most three knobs
    spec = yaml.safe_load(calibration.PROBES.read_text())
    assert spec[key] == option
    probe = spec["frozen_probe" if key == "frozen" else "declared_rule_probe"]
    assert probe in [p["name"] for p in spec["probes"]]


def test_the_declared_rule_probe_is_s0_01_wv2_m1_and_the_history_names_its_commits():
    spec = yaml.safe_load(calibration.PROBES.read_text())
    assert spec["declared_rule_probe"] == "s0.01_wv2_m1"
    overrides = next(p["overrides"] for p in spec["probes"] if p["name"] == "s0.01_wv2_m1")
    option = compose_config(["planner=declared_rule_probe"]).planner
    assert compose_config(overrides).planner == option
    rules = [entry["rule"] for entry in spec["selection"]]
    assert {"declared", "used", "predictions"} <= set(rules)
    assert rules.index("declared") < rules.index("used")
    assert all(len(str(e["commit"])) == 7 for e in spec["selection"] if e["commit"])


def _rows(*probes: tuple[str, float, float]) -> pd.DataFrame:
    rows = pd.DataFrame(probes, columns=["probe", "mean_event_cost", "mean_vx"])
    rows["episodes"] = 50
    rows["distance_to_target"] = [max(abs(j - calibration.TARGET_J_C) / calibration.BAND_J_C,
                                      abs(v - calibration.TARGET_VX) / calibration.BAND_VX) for _, j, v in probes]
    return rows


def test_the_declared_rule_and_the_rules_used_select_their_probes():
    rows = _rows(("near", 0.76, 23.46), ("banded_fast", 0.67, 23.45), ("banded_slow", 0.60, 22.8),
                 ("far", 0.2, 21.0))
    chosen = calibration.selections(rows)
    assert list(chosen.values()) == ["near", "banded_fast", "banded_fast"]
    assert list(chosen)[0].startswith("declared")


def test_the_figure_names_only_the_options_the_band_and_what_the_history_names():
    rows = _rows(("frozen", 0.66, 23.4), ("declared", 0.72, 23.4), ("in_band", 0.6, 22.8), ("told", 0.9, 24.0),
                 ("told_100ep", 0.2, 21.0), ("other", 0.3, 22.0))
    spec = {"frozen_probe": "frozen", "declared_rule_probe": "declared",
            "selection": [{"commit": None, "time": "t", "rule": "used", "text": "told was fast."}]}
    assert calibration.labelled_probes(rows, spec) == ["frozen", "declared", "in_band", "told"]


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
    for key in ("mean_event_cost", "mean_vx", "mean_n_steps", "return_per_step", "cost_rate"):
        assert rows.loc[0, f"{key}_ci95_low"] <= rows.loc[0, key] <= rows.loc[0, f"{key}_ci95_high"]
    episodes = pd.read_csv(tmp_path / "out" / "probes" / "tiny" / "episodes.csv")
    assert rows.loc[0, "return_per_step"] == pytest.approx(episodes["episode_return"].mean()
                                                           / episodes["n_steps"].mean(), rel=1e-5)
    text = (tmp_path / "out" / "calibration.md").read_text()
    assert "| tiny | 2 | 0.5 |" in text and "unnamed there: `tiny`" in text
    assert (tmp_path / "calibration.png").stat().st_size > 0
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


@pytest.mark.parametrize(("interval", "expected"), [
    ((0.58, 0.67), "within the band"), ((0.552, 0.613), "not shown within the band"),
    ((0.50, 0.57), "outside the band"), ((0.68, 0.75), "outside the band"), ((0.5, 0.7), "not shown within the band")])
def test_band_verdict_follows_the_ci(interval, expected):
    assert operating_point.band_verdict(0.625, 0.05, interval) == expected


def test_reproduction_table_at_both_options(tmp_path, monkeypatch):
    """pipelines/operating_point.py on hand-made evaluations (tests/test_tradeoff.py's writer)."""
    import json

    from omegaconf import OmegaConf

    def at(option: str):
        planner = OmegaConf.to_container(compose_config([f"planner={option}"]).planner, resolve=True)

        def write(*args, **kwargs) -> None:
            directory = write_evaluation(tmp_path, *args, **kwargs)
            config = yaml.safe_load((directory / "config.yaml").read_text())
            (directory / "config.yaml").write_text(yaml.safe_dump({**config, "planner": planner}))
        return write

    frozen, rule = at("paper_operating_point"), at("declared_rule_probe")
    for traffic in ("light", "dense"):  # SRMPC safer and faster than both, PPO-L-SI the most crashes
        write_evaluation(tmp_path, "table/ppo_lsi", "policy", traffic, 8, 23.0, 80)
        write_evaluation(tmp_path, "table/ltv_mpc", "ltv_mpc", traffic, 8, 21.0, 8)  # the default planner's
        frozen("operating_point/ltv_mpc", "ltv_mpc", traffic, 1, 23.4, 120)
        frozen("operating_point/srmpc", "srmpc", traffic, 1, 24.0, 10)
        frozen("operating_point/srmpc_track_rollout", "srmpc", traffic, 1, 24.7, 2, "policy_rollout")
        rule("operating_point/ltv_mpc_declared_rule_probe", "ltv_mpc", traffic, 1, 23.5, 140)
        rule("operating_point/srmpc_declared_rule_probe", "srmpc", traffic, 1, 24.1, 12)
        rule("operating_point/srmpc_track_rollout_declared_rule_probe", "srmpc", traffic, 1, 24.6, 3,
             "policy_rollout")
    monkeypatch.setattr(operating_point, "CALIBRATION", tmp_path / "none.csv")
    monkeypatch.chdir(tmp_path)
    reporting.runs.cache_clear()
    monkeypatch.setattr(sys, "argv", ["operating_point.py", "--resamples", "200"])
    operating_point.main()
    reporting.runs.cache_clear()
    result = json.loads((tmp_path / "results" / "operating_point.json").read_text())
    ltv = result["light"]["ltv_mpc"]
    assert ltv["directory"].endswith("operating_point/ltv_mpc_light") and result["declared_rule_probe"]["light"][
        "ltv_mpc"]["directory"].endswith("operating_point/ltv_mpc_declared_rule_probe_light")
    assert ltv["roles"]["mean_event_cost"].startswith("calibration target")
    assert ltv["roles"]["cost_rate"] == "follows from J_c and n_steps (rho_c = mean J_c / mean n_steps)"
    assert ltv["roles"]["mean_n_steps"] == "predicted (first out-of-sample check)"
    assert result["dense"]["ltv_mpc"]["roles"]["mean_vx"] == "predicted"
    assert ltv["verdicts"]["mean_event_cost"] == "inside"  # the paper's 0.625 against 120 / 200 = 0.6 [0.53, 0.66]
    assert ltv["calibration_band"]["mean_event_cost"]["verdict"] == "not shown within the band"
    assert ltv["calibration_band"]["mean_vx"]["verdict"] == "outside the band"  # 23.4 against 24.38 +- 0.3
    assert ltv["verdicts"]["mean_vx"] == "above"  # the paper's 24.38 m/s against ours near 23.4
    assert set(ltv["verdicts"]) == {"return_per_step", "mean_event_cost", "cost_rate", "mean_n_steps", "mean_vx"}
    assert ltv["return_per_step"] == pytest.approx(ltv["mean_return"] / ltv["mean_n_steps"])
    for part in (result, result["declared_rule_probe"]):
        verdicts = {(c["traffic"], c["claim"].split(" (")[0]): c["verdict"] for c in part["claims"]}
        assert verdicts[("light", "SRMPC has the lowest J_c")] == "holds"
        assert verdicts[("light", "SRMPC's J_c and rho_c more than 65% below LTV-MPC's")] == "holds"
        assert sum(part["verdict_counts"].values()) == 20
    text = (tmp_path / "results" / "operating_point.md").read_text()
    assert "Stretch" in text and "`planner=declared_rule_probe`" in text and "post hoc" in text
    assert " fits " not in text and "not shown within the band" in text
