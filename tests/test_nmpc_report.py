"""pipelines/nmpc.py: its verdict rule, its folder search, and the committed results/nmpc.json against them."""

import json
import shutil
from pathlib import Path

import pytest
import yaml

from pipelines import nmpc, reporting
from pipelines.reporting import sign

ROOT = Path(__file__).resolve().parents[1]


def test_a_metric_changes_only_when_its_paired_interval_excludes_zero():
    d = {"mean_event_cost_ci95": [-0.05, -0.01], "mean_vx_ci95": [0.1, 0.4], "mean_return_ci95": [-3.0, 2.0]}
    assert nmpc.verdicts(d) == {"J_c": "safer", "v_x": "faster", "J_r": "no difference resolved"}
    d = {"mean_event_cost_ci95": [0.0, 0.05], "mean_vx_ci95": [-0.4, -0.1], "mean_return_ci95": [1.0, 2.0]}
    assert nmpc.verdicts(d) == {"J_c": "no difference resolved", "v_x": "slower", "J_r": "higher return"}
    assert sign((0.001, 0.002)) == 1 and sign((-0.002, -0.001)) == -1 and sign((-0.001, 0.001)) == 0


def test_converged_share_counts_the_fallback_steps():
    assert nmpc.converged_share({"solved": 90, "shifted_previous": 8, "emergency_brake": 2}) == pytest.approx(0.9)


def test_runs_are_found_by_the_experiment_their_config_names_not_by_their_folder(tmp_path):
    """reporting.runs keys every evaluation by the experiment and traffic its config.yaml names: a copy under any
    folder name is found; two folders of one experiment and traffic are an error."""
    source = ROOT / "results/evaluation/nmpc/rollout_light"
    for name in ("anything", "else"):
        shutil.copytree(source, tmp_path / "q" / name)
    with pytest.raises(SystemExit, match="both hold experiment nmpc/rollout in light traffic"):
        reporting.runs(tmp_path)
    shutil.rmtree(tmp_path / "q" / "else")
    assert reporting.runs(tmp_path) == {("nmpc/rollout", "light"): tmp_path / "q" / "anything"}


def test_each_nmpc_row_is_its_experiment():
    found = nmpc.folders("paper_operating_point", "dense")
    assert set(found) == set(nmpc.METHODS)
    for method, directory in found.items():
        config = yaml.safe_load((directory / "config.yaml").read_text())
        assert (config["experiment"], config["scenario"]["traffic"]) == (
            nmpc.EXPERIMENTS[method]["paper_operating_point"], "dense")


@pytest.mark.skipif(not (ROOT / "results/nmpc.json").is_file(), reason="results/nmpc.json not generated")
def test_committed_report_follows_its_rules():
    report = json.loads((ROOT / "results/nmpc.json").read_text())
    for planner in nmpc.PLANNERS:
        for traffic in nmpc.TRAFFIC:
            rows = report[planner][traffic]
            assert set(rows) == set(nmpc.METHODS)
            for method, row in rows.items():
                assert row["episodes"] == 1000, (planner, traffic, method)
                if method not in nmpc.COMPARATORS:
                    for other in nmpc.COMPARATORS:
                        assert row["paired"][other]["mean_vx"] == pytest.approx(
                            row["mean_vx"] - rows[other]["mean_vx"], abs=1e-9)
    assert len(report["verdicts"]) == len(nmpc.PLANNERS) * len(nmpc.TRAFFIC) * (
        len(nmpc.CONVERGENCE_PAIRS) + len(nmpc.GUESS_PAIRS))
    for v in report["verdicts"]:
        assert v["verdicts"] == nmpc.verdicts(v["paired"])


@pytest.mark.skipif(not (ROOT / nmpc.STUDY).is_file(), reason="the NMPC initial-guess study is not generated")
def test_committed_study_counts_every_state_and_every_converged_plan():
    """Shares of all states (a failure is not at the lowest optimum); every converged plan certified or listed."""
    study = json.loads((ROOT / nmpc.STUDY).read_text())
    guesses = ("constant_velocity", "shifted_previous", "policy_rollout")
    for g in study["per_guess"].values():
        assert g["states_at_lowest_optimum"] + g["converged_not_at_lowest_optimum"] + g["failures"] == g["states"]
        assert g["share_of_states_at_lowest_optimum"] == pytest.approx(g["states_at_lowest_optimum"] / g["states"])
    converged = sum(study["per_guess"][g]["states"] - study["per_guess"][g]["failures"] for g in guesses)
    certification = study["kkt_certification_by_ipopt"]
    total = certification["all_guesses"]
    assert total["converged_plans"] == converged == study["kkt_residual"]["converged_plans"]
    assert total["certified"] + total["not_certified"] == converged
    assert len(certification["not_certified"]) == total["not_certified"] == len(
        study["kkt_residual"]["error_not_certified"])
    agreement = study["agreement_with_ipopt"]["all_guesses"]
    assert (agreement["agree"] + agreement["different_local_optima"] + agreement["disagree_nmpc_not_certified"]
            == agreement["both_converged"])
    assert agreement["nmpc_lower"] + agreement["ipopt_lower"] == agreement["different_local_optima"]
