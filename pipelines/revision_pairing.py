"""One evaluation's episodes now against the same evaluation's episodes at a git revision, paired on the seeds.

What ``benchmarks/table_vs_revision.py`` and ``pipelines/reproduction_check.py`` share:

- :func:`evaluation_cells`, :func:`evaluation_of`: every evaluation of a checkout, (experiment, traffic,
  ``episodes.csv`` path); the evaluation a path belongs to;
- :func:`show_at_revision`, :func:`episodes_at_revision`: a file (an ``episodes.csv``) as a git revision holds it;
- :func:`compare_cells`: the four paired metrics of one evaluation (J_r, J_c, n_steps, v_x), "before" against
  "after": each with its 95% interval (as the table computes it), the mean of after - before over the episodes run
  from the same seed with its 95% bootstrap interval (``srmpc.confidence_intervals.paired_differences``, the
  table's resamples and seed), and ``agrees``: the paired interval contains 0 and each value lies in the other's
  interval; ``identical_episodes``: how many episodes gave exactly the same row (all four metrics).
"""

from __future__ import annotations

import io
import subprocess
from pathlib import Path

import pandas as pd

from srmpc.confidence_intervals import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    PAIRED_METRICS,
    paired_differences,
    table_metrics_with_intervals,
)

TRAFFIC = ("light", "dense")
INTERVAL_SLACK = 1e-12
"""Relative slack on "lies in the interval": Wilson's lower bound for 0 events comes out as ~2e-19, not 0."""


def path_before_experiments(path: str) -> str:
    """Where ``path`` (results/evaluation/table/<method>_<traffic>/...) lived before the evaluations were named by
    their experiments: the table's under results/evaluation/twin/, the confirmation's where they are now."""
    return path.replace("results/evaluation/table/", "results/evaluation/twin/")


def evaluation_of(path: str) -> tuple[str, str] | None:
    """(experiment, traffic) of an evaluation's file, ``results/evaluation/<question>/<name>_<traffic>/<file>``;
    None for any other path."""
    parts = path.split("/")
    if len(parts) != 5 or parts[:2] != ["results", "evaluation"]:
        return None
    name, _, traffic = parts[3].rpartition("_")
    return (f"{parts[2]}/{name}", traffic) if name and traffic in TRAFFIC else None


def evaluation_cells(root: Path) -> list[tuple[str, str, str]]:
    """(experiment, traffic, episodes path) of every evaluation in ``root``'s working tree, sorted."""
    cells = []
    for path in sorted((root / "results" / "evaluation").glob("*/*/episodes.csv")):
        relative = path.relative_to(root).as_posix()
        if cell := evaluation_of(relative):
            cells.append((*cell, relative))
    return cells


def show_at_revision(root: Path, revision: str, path: str) -> subprocess.CompletedProcess:
    """``git show <revision>:<path>`` in ``root`` (text), at :func:`path_before_experiments` where ``path`` is not
    there (a revision before the experiment folders)."""
    shown = subprocess.run(["git", "show", f"{revision}:{path}"], cwd=root, capture_output=True, text=True)
    if shown.returncode != 0:
        shown = subprocess.run(["git", "show", f"{revision}:{path_before_experiments(path)}"], cwd=root,
                               capture_output=True, text=True)
    return shown


def episodes_at_revision(root: Path, revision: str, path: str) -> pd.DataFrame | None:
    """``path``'s episodes at ``revision`` (:func:`show_at_revision`); None where the revision has none."""
    shown = show_at_revision(root, revision, path)
    return pd.read_csv(io.StringIO(shown.stdout)) if shown.returncode == 0 else None


def _inside(value: float, low: float, high: float) -> bool:
    slack = INTERVAL_SLACK * (1.0 + abs(value))
    return low - slack <= value <= high + slack


def compare_cells(before: pd.DataFrame, after: pd.DataFrame) -> dict:
    """The four paired metrics of one evaluation: before, after, paired difference, agreement (module doc)."""
    row_before = table_metrics_with_intervals(before, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
    row_after = table_metrics_with_intervals(after, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
    paired = paired_differences(after, before, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
    columns = list(PAIRED_METRICS)
    merged = after.merge(before, on="seed", suffixes=("_a", "_b"))
    identical = int((merged[[f"{c}_a" for c in columns]].to_numpy()
                     == merged[[f"{c}_b" for c in columns]].to_numpy()).all(axis=1).sum())
    cells = {}
    for metric in PAIRED_METRICS.values():
        low, high = paired[f"{metric}_ci95"]
        b, a = row_before[metric], row_after[metric]
        b_low, b_high = row_before[f"{metric}_ci95"]
        a_low, a_high = row_after[f"{metric}_ci95"]
        cells[metric] = {
            "before": b, "before_ci95": [b_low, b_high], "after": a, "after_ci95": [a_low, a_high],
            "paired": paired[metric], "paired_ci95": [low, high],
            "agrees": bool(low <= 0.0 <= high and _inside(a, b_low, b_high) and _inside(b, a_low, a_high)),
        }
    return {"episodes_paired": paired["episodes"], "identical_episodes": identical, "cells": cells}
