"""A run's output folder: the names of its files, the schema of ``episodes.csv``, and the one atomic write.

An evaluation's folder holds ``config.yaml`` (the config its episodes belong to), ``episodes.csv`` (one row per
finished episode, :data:`EPISODE_COLUMNS`) and ``summary.json``; a training's holds ``config.yaml`` and
``summary.json`` beside its checkpoints. Text that replaces a file (a config, a summary) goes through
:func:`atomic_write_text`, so a reader never sees half a file; ``episodes.csv`` is appended one row at a time
(:func:`episode_row`) and read back by :func:`read_finished_episodes`, which drops a torn last line.

One schema: the columns, the row written and the row read all follow :class:`~srmpc.metrics.EpisodeMetrics`'
fields and :data:`~srmpc.controllers.outcomes.OUTCOME_KEYS`. The lock that makes the folder one run's at a
time is ``srmpc.output_lock``.
"""

from __future__ import annotations

import csv
import os
from dataclasses import fields
from pathlib import Path
from typing import get_type_hints

from srmpc.controllers.outcomes import OUTCOME_KEYS
from srmpc.episode_loop import EpisodeRecord
from srmpc.metrics import EpisodeMetrics

CONFIG_NAME = "config.yaml"
"""The composed config a folder's results belong to."""
SUMMARY_NAME = "summary.json"
"""The run's summary, written once at its end."""
EPISODES_NAME = "episodes.csv"
"""An evaluation's episodes, one row each (:data:`EPISODE_COLUMNS`)."""

METRIC_COLUMNS = [f.name for f in fields(EpisodeMetrics)]
"""The per-episode metrics (srmpc.metrics.EpisodeMetrics), in field order."""
_METRIC_TYPES = get_type_hints(EpisodeMetrics)  # name -> int or float: how a column is read back
OUTCOME_COLUMNS = [f"steps_{key}" for key in OUTCOME_KEYS]
"""Per-episode planner outcome counts (0 for controllers without outcomes): which link of the fallback
chain produced the applied input (solved, shifted_previous, emergency_brake), which linearization
reference a solved plan came from (solved_from_policy / _shifted / _lane_following) and the steps whose
policy rollout failed (SRMPC only)."""
EPISODE_COLUMNS = ["episode", "seed", *METRIC_COLUMNS, "termination", *OUTCOME_COLUMNS]
"""The header of ``episodes.csv``."""


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and rename, so readers never see half a file."""
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def episode_row(record: EpisodeRecord) -> list:
    """``record`` as a row of ``episodes.csv`` (:data:`EPISODE_COLUMNS`)."""
    metrics = [getattr(record.metrics, name) for name in METRIC_COLUMNS]
    outcomes = [record.outcomes.get(key, 0) for key in OUTCOME_KEYS]
    return [record.episode, record.seed, *metrics, record.termination, *outcomes]


def episode_from_row(row: dict[str, str]) -> EpisodeRecord:
    """A row of ``episodes.csv`` read back (``csv.DictReader``); raises on a missing or malformed value."""
    metrics = EpisodeMetrics(**{name: _METRIC_TYPES[name](row[name]) for name in METRIC_COLUMNS})
    outcomes = {key: int(row[f"steps_{key}"]) for key in OUTCOME_KEYS if int(row[f"steps_{key}"])}
    return EpisodeRecord(int(row["episode"]), int(row["seed"]), metrics, row["termination"], outcomes)


def read_finished_episodes(path: Path) -> list[EpisodeRecord]:
    """Rows of ``episodes.csv``; a torn last line (a crash mid-write) is dropped."""
    if not path.exists():
        return []
    records = []
    with path.open(newline="") as handle:
        for row in csv.DictReader(handle):
            try:
                records.append(episode_from_row(row))
            except (TypeError, ValueError, KeyError):
                break
    return records


def write_episodes(path: Path, records: list[EpisodeRecord]) -> None:
    """``episodes.csv`` with the header and ``records`` (a resumed run rewrites it without a torn tail)."""
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(EPISODE_COLUMNS)
        for record in records:
            writer.writerow(episode_row(record))
