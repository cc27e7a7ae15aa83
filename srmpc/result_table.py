"""The compact table that ``python -m srmpc`` ends with.

Evaluation: the paper's table metrics of the run (J_r, J_r per step, J_c, rho_c, n_steps, v_x) with their
95% confidence intervals, computed from the run's ``episodes.csv`` as in ``results/table.md``
(:func:`srmpc.confidence_intervals.table_metrics_with_intervals`: Wilson for J_c, the bootstrap over
episodes otherwise), how the episodes ended, the output directory and the MLflow run id.
Training: the end-of-training summary (means over the last 5% of training), the output directory and
the MLflow run id.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd
from rich import box
from rich.console import Console, Group
from rich.table import Table
from rich.text import Text

from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, table_metrics_with_intervals

EVALUATION_ROWS = (  # (summary key, label, digits)
    ("mean_return", "J_r    return (sum of r')", 0),
    ("return_per_step", "J_r / step  (mean J_r / mean n_steps)", 2),
    ("mean_event_cost", "J_c    collision or road exit", 3),
    ("cost_rate", "rho_c  events per step", 5),
    ("mean_n_steps", "n_steps", 1),
    ("mean_vx", "v_x [m/s]", 2),
)
TRAINING_ROWS = (  # (summary key, label, digits)
    ("frames", "env steps", 0),
    ("iterations", "iterations", 0),
    ("wall_s", "wall time [s]", 0),
    ("episodes", "episodes (last 5%)", 0),
    ("return", "J_r    return (sum of r')", 1),
    ("train_return", "training return (sum of r)", 1),
    ("cost_return", "J_c    collision or road exit", 3),
    ("cost_rate", "rho_c  events per step", 5),
    ("si_cost_return", "safety-index cost return", 2),
    ("steps", "episode length [steps]", 1),
    ("vx", "v_x [m/s]", 2),
)


def _number(value: Any, digits: int) -> str:
    if isinstance(value, int | float):
        return f"{value:,.{digits}f}" if digits == 0 else f"{value:.{digits}f}"
    return "-"


def intervals_from_episodes(episodes_csv: Path) -> dict | None:
    """The table row with ``<metric>_ci95`` of ``episodes_csv``; None if it is missing or empty."""
    try:
        episodes = pd.read_csv(episodes_csv)
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return None
    if episodes.empty:
        return None
    return table_metrics_with_intervals(episodes, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)


def evaluation_table(summary: Mapping[str, Any], intervals: Mapping[str, Any] | None) -> Table:
    """Metric | value | 95% CI for an evaluation summary (``summary.json``)."""
    title = (f"{summary.get('experiment') or summary.get('controller', '?')}, {summary.get('traffic', '?')} traffic, "
             f"{summary.get('episodes', '?')} episodes on {summary.get('simulator', '?')}")
    table = Table(title=Text(title), box=box.SIMPLE_HEAD, title_justify="left", pad_edge=False)
    table.add_column("metric")
    table.add_column("value", justify="right")
    table.add_column("95% CI", justify="right")
    for key, label, digits in EVALUATION_ROWS:
        interval = (intervals or {}).get(f"{key}_ci95")
        ci = f"[{_number(interval[0], digits)}, {_number(interval[1], digits)}]" if interval else "-"
        value = summary.get(key, (intervals or {}).get(key))  # return_per_step: from the episodes
        table.add_row(Text(label), _number(value, digits), ci)
    return table


def training_table(summary: Mapping[str, Any]) -> Table:
    """Metric | value for a training summary (``summary.json``, means over the last 5% of training)."""
    table = Table(title=Text(f"training {summary.get('name', '?')}: last 5% of training"), box=box.SIMPLE_HEAD,
                  title_justify="left", pad_edge=False)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for key, label, digits in TRAINING_ROWS:
        if key in summary:
            table.add_row(Text(label), _number(summary[key], digits))
    return table


def last_run_id() -> str | None:
    """The id of this process's last MLflow run, if MLflow was used."""
    mlflow = sys.modules.get("mlflow")
    if mlflow is None:
        return None
    try:
        run = mlflow.last_active_run()
    except Exception:  # noqa: BLE001  (the store went away): the table prints without the id
        return None
    return run.info.run_id if run is not None else None


def result_view(summary: Mapping[str, Any], output_dir: Path, run_id: str | None, training: bool) -> Group:
    """The table and its footer (how episodes ended, output directory, MLflow run)."""
    parts: list = []
    if training:
        parts.append(training_table(summary))
    else:
        parts.append(evaluation_table(summary, intervals_from_episodes(output_dir / "episodes.csv")))
        ends = summary.get("terminations") or {}
        if ends:
            parts.append(Text("episodes ended by: " + ", ".join(f"{k} {v}" for k, v in ends.items())))
    parts.append(Text(f"output:     {output_dir}"))
    parts.append(Text(f"MLflow run: {run_id or '- (tracking disabled)'}"))
    return Group(*parts)


def print_result(cfg: Any, summary: Mapping[str, Any], hydra_output_dir: Path, console: Console | None = None) -> None:
    """Print the run's result table (``cfg``: the composed DictConfig of ``python -m srmpc``)."""
    training = getattr(cfg.stage, "value", cfg.stage) in ("train", "train_sb3")
    if training:
        output_dir = (Path(cfg.agent.output_dir) if cfg.agent.output_dir
                      else Path("results/training") / cfg.agent.name / f"seed_{cfg.agent.seed}")
    else:
        output_dir = Path(cfg.evaluation.output_dir) if cfg.evaluation.output_dir else hydra_output_dir
    run_id = last_run_id() if cfg.tracking.enabled else None
    (console or Console()).print(result_view(summary, output_dir, run_id, training))
