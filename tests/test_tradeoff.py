"""pipelines/tradeoff.py on hand-made evaluations: points read from their own config, dominance from paired
differences, J_c at the policy's speed, the paper's operating point, and the confirmation's verdicts."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pipelines import reporting, tradeoff

EPISODES = 200


def write_evaluation(root: Path, experiment: str, controller: str, traffic: str, margin: float, vx: float,
                     crashes: int, tracking: str = "lane_centre", seed: int = 0) -> Path:
    """An evaluation of ``experiment`` as the CLI writes it (config.yaml, episodes.csv, summary.json) into
    ``root``/results/evaluation/<experiment>_<traffic>; returns the folder."""
    directory = root / "results" / "evaluation" / f"{experiment}_{traffic}"
    directory.mkdir(parents=True)
    rng = np.random.default_rng(int(vx * 100) + crashes)
    event = np.zeros(EPISODES)
    event[:crashes] = 1.0
    episodes = pd.DataFrame({"episode": range(EPISODES), "seed": range(seed, seed + EPISODES),
                             "episode_return": -1000.0 + 50 * (vx - 22) + rng.normal(0, 10, EPISODES),
                             "event_cost": event, "n_steps": np.where(event > 0, 200, 400),
                             "mean_vx": vx + rng.normal(0, 0.3, EPISODES), "termination": "truncated"})
    episodes.to_csv(directory / "episodes.csv", index=False)
    srmpc = {"selection": "policy_first", "prediction": "constant_velocity", "relinearizations": 0,
             "tracking": tracking} if controller == "srmpc" else None
    config = {"experiment": experiment, "scenario": {"traffic": traffic}, "evaluation": {"seed": seed},
              "controller": {"name": controller, "srmpc": srmpc},
              "planner": {"safety_margin_longitudinal_m": margin, "state_weights": [0.0, 0.5, 20.0, 0.5],
                          "slack_price_scale": 1.0}}
    (directory / "config.yaml").write_text(yaml.safe_dump(config))
    (directory / "summary.json").write_text(json.dumps({"episodes": EPISODES}))
    return directory


@pytest.fixture
def project(tmp_path, monkeypatch):
    """Two margins per curve, light and dense: SRMPC faster and safer than LTV-MPC at 1 m, not at 8 m."""
    monkeypatch.chdir(tmp_path)
    reporting.runs.cache_clear()
    for traffic in ("light", "dense"):
        write_evaluation(tmp_path, "table/ltv_mpc", "ltv_mpc", traffic, 8, 21.0, 8)
        write_evaluation(tmp_path, "table/srmpc", "srmpc", traffic, 8, 20.5, 1)
        write_evaluation(tmp_path, "variants/track_rollout", "srmpc", traffic, 8, 21.5, 0, "policy_rollout")
        write_evaluation(tmp_path, "tradeoff/ltv_mpc_margin_1m", "ltv_mpc", traffic, 1, 22.0, 30)
        write_evaluation(tmp_path, "tradeoff/srmpc_margin_1m", "srmpc", traffic, 1, 23.0, 2)
        write_evaluation(tmp_path, "tradeoff/srmpc_track_rollout_margin_1m", "srmpc", traffic, 1, 24.0, 0,
                         "policy_rollout")
        for name, vx, crashes in (("ppo_lsi", 24.0, 40), ("ppo", 20.0, 5), ("lane_keeping", 19.0, 60)):
            write_evaluation(tmp_path, f"table/{name}", "policy" if "ppo" in name else name, traffic, 8, vx,
                             crashes)
    yield tmp_path
    reporting.runs.cache_clear()


def test_points_are_sorted_by_speed_and_carry_their_settings(project):
    points, episodes = tradeoff.collect(resamples=200, seed=0)
    curve = points["light"]["srmpc"]
    assert [p["settings"]["safety_margin_longitudinal_m"] for p in curve] == [8.0, 1.0]  # 20.5 then 23.0 m/s
    assert curve[0]["mean_event_cost"] == pytest.approx(1 / EPISODES)
    low, high = curve[0]["mean_event_cost_ci95"]
    assert low < curve[0]["mean_event_cost"] < high
    assert len(points["dense"]["ppo_lsi"]) == 1 and "settings" not in points["dense"]["ppo_lsi"][0]
    assert len(episodes) == 2 * 9


def test_dominance_is_paired_and_names_the_points_that_do_not_dominate(project):
    points, episodes = tradeoff.collect(resamples=500, seed=0)
    verdicts = tradeoff.dominance(points["light"], episodes, resamples=500, seed=0)
    by_margin = {v["ltv_mpc"]["settings"]["safety_margin_longitudinal_m"]: v for v in verdicts}
    # LTV-MPC at 1 m (22.0 m/s, 30 crashes): SRMPC at 1 m (23.0, 2) and the track variant (24.0, 0) dominate it
    assert by_margin[1.0]["dominance_shown"]
    dominating = {(c["method"], c["settings"]["safety_margin_longitudinal_m"])
                  for c in by_margin[1.0]["srmpc_points"] if c["dominance_shown"]}
    assert dominating == {("srmpc", 1.0), ("srmpc_track_rollout", 1.0)}
    # LTV-MPC at 8 m (21.0, 8): SRMPC at 8 m is slower (20.5): not dominated by it, but by the others
    at_8 = {(c["method"], c["settings"]["safety_margin_longitudinal_m"]): c for c in by_margin[8.0]["srmpc_points"]}
    assert not at_8[("srmpc", 8.0)]["dominates_by_point_estimate"]
    assert at_8[("srmpc", 8.0)]["paired_difference"]["mean_vx"] == pytest.approx(-0.5, abs=0.1)


def test_j_c_at_the_policys_speed_is_interpolated_inside_the_curve_else_the_nearest_point():
    curve = [{"settings": {"m": 8}, "mean_vx": 20.0, "mean_event_cost": 0.0, "mean_event_cost_ci95": [0, 0.01]},
             {"settings": {"m": 1}, "mean_vx": 24.0, "mean_event_cost": 0.04, "mean_event_cost_ci95": [0.02, 0.06]}]
    inside = tradeoff.at_speed(curve, 23.0)
    assert inside["how"] == "interpolated" and inside["mean_event_cost"] == pytest.approx(0.03)
    outside = tradeoff.at_speed(curve, 25.0)
    assert outside["how"].startswith("nearest") and outside["settings"] == {"m": 1}


def test_the_paper_operating_point_is_the_ltv_mpc_point_nearest_its_speed(project):
    points, episodes = tradeoff.collect(resamples=200, seed=0)
    o = tradeoff.paper_operating_point("light", points["light"], episodes, resamples=200, seed=0)
    assert o["ltv_mpc"]["settings"]["safety_margin_longitudinal_m"] == 1.0  # 22.0 m/s is nearest 24.38
    assert o["srmpc"]["settings"] == o["ltv_mpc"]["settings"]
    assert o["reduction"] == pytest.approx(1 - 2 / 30)
    assert o["paper_reduction"] == pytest.approx(1 - 0.215 / 0.625)


def test_outputs_are_written_and_the_confirmation_is_judged_against_target_and_stretch(project, monkeypatch):
    for traffic in ("light", "dense"):
        write_evaluation(project, "confirmation/srmpc_recommended", "srmpc", traffic, 1, 24.2, 1, "policy_rollout",
                         seed=100000)
        write_evaluation(project, "confirmation/ltv_mpc_margin_1m", "ltv_mpc", traffic, 1, 22.0, 30, seed=100000)
        write_evaluation(project, "confirmation/ppo_lsi", "policy", traffic, 8, 24.0, 40, seed=100000)
    reporting.runs.cache_clear()
    monkeypatch.setattr(sys, "argv", ["tradeoff.py", "--resamples", "200"])
    tradeoff.main()
    report = json.loads((project / "results" / "tradeoff.json").read_text())
    c = report["light"]["confirmation"]
    assert c["target"]["meets"]  # 24.2 >= 24.1 at J_c 0.005 <= 0.006
    assert c["target_on_these_seeds"]["max_event_cost"] == pytest.approx(40 / EPISODES / 10)
    assert not c["stretch"]["meets"]  # 24.2 is not above the paper's 24.63
    assert report["dense"]["confirmation"]["target"]["meets"]  # 24.2 >= 22.3 at 0.005 <= 0.036
    text = (project / "results" / "tradeoff.md").read_text()
    assert "dominated, shown by the paired CIs: by" in text and "confirmed on fresh seeds" in text
    assert (project / "results" / "figures" / "tradeoff.png").stat().st_size > 10_000


def test_points_come_from_each_folders_config_not_its_name(project):
    """Renamed folders give the same points; a second folder of one experiment and traffic is an error."""
    before, _ = tradeoff.collect(resamples=200, seed=0)
    for i, directory in enumerate(sorted((project / "results/evaluation/table").iterdir())):
        directory.rename(directory.with_name(f"run_{i}"))
    reporting.runs.cache_clear()
    after, _ = tradeoff.collect(resamples=200, seed=0)
    assert {(t, m): [p["mean_vx"] for p in c] for t, ms in after.items() for m, c in ms.items()} == {
        (t, m): [p["mean_vx"] for p in c] for t, ms in before.items() for m, c in ms.items()}
    write_evaluation(project / "elsewhere", "table/srmpc", "srmpc", "light", 8, 20.0, 0).rename(
        project / "results/evaluation/table/another_srmpc_light")
    reporting.runs.cache_clear()
    with pytest.raises(SystemExit, match="both hold experiment table/srmpc in light traffic"):
        tradeoff.collect(resamples=200, seed=0)


def _candidate(method: str, margin: float, dvx: float, shown: bool) -> dict:
    return {"method": method, "settings": {"safety_margin_longitudinal_m": margin},
            "paired_difference": {"mean_vx": dvx}, "dominates_by_point_estimate": dvx > 0, "dominance_shown": shown}


def test_dominance_examples_are_only_pairs_shown_by_both_cis_when_any_is():
    verdict = {"ltv_mpc": {"settings": {"safety_margin_longitudinal_m": 1.0}},
               "srmpc_points": [_candidate("srmpc", 1.0, 0.11, False),  # faster by point estimate, CI crosses 0
                                _candidate("srmpc_track_rollout", 1.0, 0.63, True),
                                _candidate("srmpc", 4.0, 0.90, False),  # the fastest, but not shown
                                _candidate("srmpc_track_rollout", 4.0, 0.74, True),
                                _candidate("srmpc", 8.0, -0.2, False)]}
    examples = tradeoff.dominance_examples(verdict)
    assert [(c["method"], c["settings"]["safety_margin_longitudinal_m"]) for c in examples] == [
        ("srmpc_track_rollout", 1.0), ("srmpc_track_rollout", 4.0)]  # own setting first, then the fastest shown
    for c in verdict["srmpc_points"]:
        c["dominance_shown"] = False  # none shown: the fastest point-estimate dominator, which the text labels
    assert [c["paired_difference"]["mean_vx"] for c in tradeoff.dominance_examples(verdict)] == [0.90]
