"""The paper's claims, checked per trained policy (pipelines/paper_table.py): verdicts agree with the table's text."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipelines.paper_table import POLICY_SEEDS, claim_verdicts, claims, over_policies

ROOT = Path(__file__).resolve().parents[1]
TABLE = json.loads((ROOT / "results" / "table.json").read_text())
PER_POLICY = json.loads((ROOT / "results" / "per_policy.json").read_text())


@pytest.mark.parametrize(("verdicts", "overall"), [
    (["holds", "holds", "holds"], "holds for all"),
    (["does not hold"] * 3, "fails for all"),
    (["not shown"] * 3, "not shown for any"),
    (["holds", "does not hold", "holds"], "mixed"),
    (["holds", "not shown", "holds"], "mixed"),
])
def test_one_verdict_over_the_policies(verdicts, overall):
    assert over_policies(verdicts) == overall


@pytest.mark.parametrize("level", ["light", "dense"])
def test_verdicts_are_the_ones_the_table_states(level):
    """Each verdict of claim_verdicts is the word the table's claim line prints (the same tests, one place)."""
    rows = TABLE[level]
    text = "\n".join(claims(rows, level))
    verdicts = claim_verdicts(rows, level)
    assert f"\"SRMPC has the lowest J_c\": {verdicts['SRMPC has the lowest J_c']} here" in text
    if level == "light":
        faster = verdicts["SRMPC has a higher return and speed than PPO-L-SI and LTV-MPC"]
        assert f"than PPO-L-SI and LTV-MPC\": {faster}" in text
        slower = verdicts["SRMPC is slower than PPO-L-SI"]
        vx = next(line for line in text.splitlines() if "v_x, SRMPC - PPO-L-SI" in line)
        assert (slower == "holds") == vx.endswith("lower.")
        for claim, share in (("PPO-L-SI", "30%"), ("LTV-MPC", "65%")):
            verdict = verdicts[f"J_c and rho_c more than {share} below {claim}'s"]
            line = next(line for line in text.splitlines() if f"more than {share} better than {claim}" in line)
            assert f": {verdict}" in line
    else:
        verdict = verdicts["LTV-MPC is slightly better, comparable in speed"]
        assert f"({verdict} as \"slightly better or comparable\"" in text


@pytest.mark.parametrize("level", ["light", "dense"])
def test_seed_0_is_the_table(level):
    """The per-policy report's seed 0 is the headline table: the same rows, the same verdicts."""
    seed_0 = PER_POLICY[level]["policies"]["0"]
    assert seed_0["verdicts"] == claim_verdicts(TABLE[level], level)
    for method in ("ppo_lsi", "srmpc"):
        assert seed_0[method]["mean_vx"] == TABLE[level][method]["mean_vx"]
        assert seed_0[method]["mean_event_cost_ci95"] == TABLE[level][method]["mean_event_cost_ci95"]
    assert seed_0["srmpc_recommended"]["mean_vx"] == TABLE[level]["srmpc_recommended"]["mean_vx"]


@pytest.mark.parametrize("level", ["light", "dense"])
def test_every_claim_has_a_verdict_per_policy_and_one_over_them(level):
    claims_over = PER_POLICY[level]["claims"]
    assert claims_over
    for claim in claims_over.values():
        assert len(claim["verdicts"]) == len(POLICY_SEEDS)
        assert claim["over_policies"] == over_policies(claim["verdicts"])
