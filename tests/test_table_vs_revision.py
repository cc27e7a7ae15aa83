"""benchmarks/table_vs_revision.py: a regenerated table cell agrees with its old value when it moved less
than its noise, and is flagged when it moved more."""

import importlib.util
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
