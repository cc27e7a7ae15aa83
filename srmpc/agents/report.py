"""Summaries of training runs from their ``metrics.csv`` (one row per iteration, written by the trainer)."""

from __future__ import annotations

import csv
import math
from pathlib import Path


def read_metrics(path: Path) -> list[dict[str, float]]:
    """Rows of a trainer ``metrics.csv`` as floats (empty cells -> NaN)."""
    with Path(path).open(newline="") as handle:
        return [{k: float(v) if v != "" else math.nan for k, v in row.items()} for row in csv.DictReader(handle)]


def final_window(rows: list[dict[str, float]], last_fraction: float) -> list[tuple[dict[str, float], float]]:
    """The iterations in the last ``last_fraction`` of the frames (at least the last one), each with the env steps
    of its batch (its frames minus the previous iteration's)."""
    final_frames = rows[-1]["frames"]
    batch_frames = [r["frames"] - p["frames"] for p, r in zip([{"frames": 0.0}, *rows[:-1]], rows, strict=True)]
    start = (1.0 - last_fraction) * final_frames
    window = [(r, f) for r, f in zip(rows, batch_frames, strict=True) if r["frames"] > start]
    return window or [(rows[-1], batch_frames[-1])]


def summarize_training(rows: list[dict[str, float]], last_fraction: float = 0.05) -> dict[str, float]:
    """Final performance over the last ``last_fraction`` of the frames (at least the last iteration).

    ``return`` / ``cost_return`` / ``steps`` / ``vx``: means over the episodes that ended there (each
    iteration's mean weighted by its number of finished episodes); ``cost_rate``: event costs per env
    step there; ``frames``, ``wall_s``: totals of the run.
    """
    if not rows:
        raise ValueError("no iterations in metrics")
    window = final_window(rows, last_fraction)
    tail, tail_frames = [r for r, _ in window], [f for _, f in window]
    summary = {"frames": int(rows[-1]["frames"]), "wall_s": rows[-1]["wall_s"], "iterations": len(rows),
               "last_fraction": last_fraction}
    episodes = sum(r["episodes"] for r in tail if r["episodes"] > 0)
    for key, column in (("return", "episode/return"), ("train_return", "episode/train_return"),
                        ("cost_return", "episode/cost_return"),
                        ("si_cost_return", "episode/si_cost_return"), ("steps", "episode/steps"),
                        ("vx", "episode/vx")):
        weighted = sum(r[column] * r["episodes"] for r in tail if r["episodes"] > 0)
        summary[key] = weighted / episodes if episodes else math.nan
    summary["cost_rate"] = sum(r["cost_rate"] * f for r, f in zip(tail, tail_frames, strict=True)) / sum(tail_frames)
    summary["episodes"] = int(episodes)
    return summary
