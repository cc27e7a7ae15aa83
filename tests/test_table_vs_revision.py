"""benchmarks/table_vs_revision.py: a regenerated table cell agrees with its old value when it moved less
than its noise, and is flagged when it moved more."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd

SPEC = importlib.util.spec_from_file_location(
    "table_vs_revision", Path(__file__).resolve().parents[1] / "benchmarks" / "table_vs_revision.py")
table_vs_revision = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(table_vs_revision)


def _episodes(rng: np.random.Generator, n: int = 300) -> pd.DataFrame:
    return pd.DataFrame({"seed": np.arange(n), "episode_return": rng.normal(-3000.0, 800.0, n),
                         "event_cost": (rng.random(n) < 0.05).astype(float), "n_steps": np.full(n, 400),
                         "mean_vx": rng.normal(21.5, 0.8, n)})


def test_identical_episodes_agree_and_a_shift_beyond_the_noise_does_not():
    before = _episodes(np.random.default_rng(0))
    same = table_vs_revision.compare_cells(before, before.copy())
    assert same["identical_episodes"] == 300 and all(c["agrees"] for c in same["cells"].values())
    jitter = before.copy()  # a few episodes change, as a floating-point change makes them
    jitter.loc[:9, "episode_return"] += np.random.default_rng(1).normal(0.0, 50.0, 10)
    small = table_vs_revision.compare_cells(before, jitter)
    assert small["identical_episodes"] == 290 and small["cells"]["mean_return"]["agrees"]
    faster = before.copy()
    faster["mean_vx"] += 0.5  # every episode 0.5 m/s faster: far outside the paired interval
    moved = table_vs_revision.compare_cells(before, faster)
    assert not moved["cells"]["mean_vx"]["agrees"] and moved["cells"]["mean_return"]["agrees"]
    assert abs(moved["cells"]["mean_vx"]["paired"] - 0.5) < 1e-12


def test_every_evaluation_is_found_by_experiment_and_traffic(tmp_path):
    for folder in ("nmpc/rollout_dense", "nmpc/rollout_paper_operating_point_light", "table/srmpc_light"):
        (tmp_path / "results" / "evaluation" / folder).mkdir(parents=True)
        (tmp_path / "results" / "evaluation" / folder / "episodes.csv").write_text("seed\n0\n")
    (tmp_path / "results" / "evaluation" / "table" / "notes").mkdir()  # no traffic suffix, no episodes
    assert table_vs_revision.evaluation_cells(tmp_path) == [
        ("nmpc/rollout", "dense", "results/evaluation/nmpc/rollout_dense/episodes.csv"),
        ("nmpc/rollout_paper_operating_point", "light",
         "results/evaluation/nmpc/rollout_paper_operating_point_light/episodes.csv"),
        ("table/srmpc", "light", "results/evaluation/table/srmpc_light/episodes.csv"),
    ]


def test_after_takes_the_evaluations_of_another_checkout(tmp_path, monkeypatch):
    """``--after DIR``: the table's cells regenerated elsewhere against the committed ones; a copy of the committed
    episodes agrees everywhere, and one cell whose episodes were all made faster is the one that moves."""
    from pipelines.reporting import EXPERIMENTS

    root = Path(table_vs_revision.ROOT)
    monkeypatch.chdir(root)  # the table's folders are found relative to the repository (pipelines.reporting)
    for experiment in EXPERIMENTS.values():
        for traffic in table_vs_revision.TRAFFIC:
            folder = Path("results/evaluation") / f"{experiment}_{traffic}"
            (tmp_path / folder).mkdir(parents=True)
            (tmp_path / folder / "episodes.csv").write_bytes((root / folder / "episodes.csv").read_bytes())
    faster = tmp_path / "results/evaluation/table/ltv_mpc_dense/episodes.csv"
    episodes = pd.read_csv(faster)
    episodes["mean_vx"] += 1.0
    episodes.to_csv(faster, index=False)
    out = tmp_path / "comparison.json"
    monkeypatch.setattr("sys.argv", ["table_vs_revision", "--revision", "HEAD", "--after", str(tmp_path),
                                     "--out", str(out)])
    table_vs_revision.main()
    result = json.loads(out.read_text())
    assert result["after"]["path"] == str(tmp_path) and result["after"]["commit"] is None  # not a checkout
    assert result["moved"] == ["table/ltv_mpc dense mean_vx"] and not result["all_agree"]
    assert result["traffic"]["light"]["srmpc"]["identical_episodes"] == 1000
    assert result["counts"] == {"evaluations": 14, "evaluations_identical": 13, "evaluations_moved": 1,
                                "metric_cells": 56, "metric_cells_moved": 1, "new": 0}
