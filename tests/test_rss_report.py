"""pipelines/rss.py: its verdict and recommendation rules, and the committed results/rss.json against them."""

import json
from pathlib import Path

import pytest

from pipelines.rss import AGENTS, METHODS, SPEED_TOLERANCE_MPS, TRAFFIC, difference_verdicts, recommendation
from pipelines.training_figure import claim_verdict

ROOT = Path(__file__).resolve().parents[1]


def test_verdicts_follow_the_sign_of_the_whole_interval():
    d = {"mean_event_cost_ci95": [-0.05, -0.01], "mean_vx_ci95": [0.1, 0.4]}
    assert difference_verdicts(d) == {"J_c": "safer", "v_x": "faster"}
    d = {"mean_event_cost_ci95": [0.01, 0.05], "mean_vx_ci95": [-0.4, -0.1]}
    assert difference_verdicts(d) == {"J_c": "less safe", "v_x": "slower"}
    d = {"mean_event_cost_ci95": [-0.01, 0.01], "mean_vx_ci95": [-0.1, 0.1]}
    assert difference_verdicts(d) == {"J_c": "no difference resolved", "v_x": "no difference resolved"}


def _rows(cost: dict, vx: dict, safety: dict | None = None) -> dict:
    safety = safety or {}
    return {t: {f"ppo_lsi/{a}": {"mean_event_cost": cost[a], "mean_vx": vx[a],
                                 "verdicts": {"J_c": safety.get(a, "safer"), "v_x": "slower"}} for a in AGENTS}
            for t in TRAFFIC}


def test_recommendation_prefers_the_lower_cost_unless_it_is_too_slow_or_less_safe_than_ppo_lsi():
    a, b = AGENTS
    assert recommendation(_rows({a: 0.01, b: 0.02}, {a: 22.0, b: 22.0}))["agent"] == a
    assert recommendation(_rows({a: 0.03, b: 0.02}, {a: 22.0, b: 22.0}))["agent"] == b
    too_slow = _rows({a: 0.01, b: 0.02}, {a: 22.0 - 2 * SPEED_TOLERANCE_MPS, b: 22.0})
    assert recommendation(too_slow)["agent"] == b
    assert recommendation(_rows({a: 0.01, b: 0.02}, {a: 22.0, b: 22.0}, {a: "less safe"}))["agent"] == b
    assert recommendation(_rows({a: 0.01, b: 0.02}, {a: 22.0, b: 22.0}, {a: "less safe", b: "less safe"}))[
        "agent"] is None


@pytest.mark.skipif(not (ROOT / "results/rss.json").is_file(), reason="results/rss.json not generated")
def test_committed_report_follows_its_rules():
    report = json.loads((ROOT / "results/rss.json").read_text())
    for traffic in TRAFFIC:
        rows = report["evaluation"][traffic]
        for method in METHODS:
            assert rows[f"{method}/ppo_lsi"]["episodes"] == 1000
            for agent in AGENTS:
                row = rows[f"{method}/{agent}"]
                assert row["episodes"] == 1000
                assert row["verdicts"] == difference_verdicts(row["minus_ppo_lsi"])
                assert row["minus_ppo_lsi"]["mean_event_cost"] == pytest.approx(
                    row["mean_event_cost"] - rows[f"{method}/ppo_lsi"]["mean_event_cost"], abs=1e-12)
    for traffic in TRAFFIC:
        row = report["confirmation"][traffic]["ppo_lsi_rss"]
        assert row["episodes"] == 1000 and row["verdicts"] == difference_verdicts(row["minus_ppo_lsi"])
    claim = report["training_claim"]  # judged from its CIs, as pipelines.training_figure's CLAIM_RULE says
    assert claim["verdict"] == claim_verdict(claim["cost_rate_ratio_rss_over_ppo_ci95"],
                                             claim["return_difference_rss_minus_ppo_ci95"])
    assert claim["holds"] == (claim["verdict"] == "holds")
    for seed in claim["per_seed"].values():
        assert seed["verdict"] == claim_verdict(seed["cost_rate_ratio_rss_over_ppo_ci95"],
                                                seed["return_difference_rss_minus_ppo_ci95"])
    assert report["recommendation"] == recommendation(report["evaluation"])
    assert len(report["training"]["ppo_lsi_rss"]["seeds"]) == 3
