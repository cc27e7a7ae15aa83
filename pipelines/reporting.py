"""What every report of the pipeline shares: the table's methods and rows, the paper's published values, the
bootstrap settings, and how a report is written.

- :data:`METHODS`, :data:`PAIRED_AGAINST`: the table's rows (their names) and what SRMPC is paired against;
- :data:`EVALUATION`, :data:`CONFIRMATION`: where their episodes live;
- :data:`PAPER`: the paper's Table "Evaluation results";
- :func:`method_row`, :func:`row_with_intervals`, :func:`paper_row`, :func:`ci`: a method's row, read and printed;
- :func:`write_outputs`: each report file written atomically.

Every interval uses the bootstrap of ``srmpc.confidence_intervals`` (``BOOTSTRAP_RESAMPLES``,
``BOOTSTRAP_SEED``), the same one ``python -m srmpc`` prints its table with.

The table (``paper_table``), SRMPC's variants (``srmpc_variants``), the trade-off (``tradeoff``), the
cross-check (``crosscheck``) and ``table_vs_revision`` all read these from here.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from srmpc.confidence_intervals import table_metrics_with_intervals
from srmpc.output_folder import atomic_write_text

EVALUATION = Path("results/evaluation/twin")
METHODS = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC", "ppo": "PPO",
           "ppo_sb3": "PPO (Stable-Baselines3)",
           "lane_keeping": "Lane keeping (baseline)",
           "srmpc_recommended": "SRMPC, recommended (ours: srmpc=track_rollout planner=margin_1m)"}
CONFIRMATION = Path("results/evaluation/confirmation")
PAIRED_AGAINST = ("ltv_mpc", "ppo_lsi")
PAPER = {  # Table "Evaluation results" of the paper: J_r, J_r per step, J_c, rho_c, n_steps, v_x
    ("light", "ppo_lsi"): (-4669, -13.4, 0.308, 0.0009, 348, 23.11),
    ("light", "ltv_mpc"): (-1241, -5.1, 0.625, 0.0026, 244, 24.38),
    ("light", "srmpc"): (-1108, -3.1, 0.215, 0.0006, 357, 24.63),
    ("dense", "ppo_lsi"): (-4499, -16.4, 0.540, 0.002, 274, 22.47),
    ("dense", "ltv_mpc"): (-334, -2.4, 0.788, 0.0057, 139, 24.79),
    ("dense", "srmpc"): (-1211, -4.0, 0.353, 0.0012, 305, 24.47),
}
HEADER = ("| Algorithm | mean J_r (per step) | mean J_c | rho_c | mean n_steps | mean v_x [m/s] |\n"
          "|---|---|---|---|---|---|")


def ci(row: dict, key: str, digits: int) -> str:
    low, high = row[f"{key}_ci95"]
    return f"{row[key]:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def row_with_intervals(name: str, r: dict) -> str:
    return (f"| {name} | {ci(r, 'mean_return', 0)} ({ci(r, 'mean_return_per_step', 1)}) | "
            f"{ci(r, 'mean_event_cost', 3)} | {ci(r, 'cost_rate', 4)} | {ci(r, 'mean_n_steps', 0)} | "
            f"{ci(r, 'mean_vx', 2)} |")


def paper_row(name: str, values: tuple) -> str:
    j_r, per_step, j_c, rho, steps, vx = values
    return f"| {name} | {j_r:.0f} ({per_step:.1f}) | {j_c:.3f} | {rho:.4f} | {steps:.0f} | {vx:.2f} |"


def method_row(directory: Path, resamples: int, seed: int) -> tuple[dict, pd.DataFrame]:
    episodes = pd.read_csv(directory / "episodes.csv")
    summary = json.loads((directory / "summary.json").read_text())
    if len(episodes) != summary["episodes"]:
        raise SystemExit(f"{directory}: episodes.csv has {len(episodes)} rows, summary.json {summary['episodes']}")
    row = table_metrics_with_intervals(episodes, resamples, seed)
    row["outcomes"] = summary.get("outcomes", {})
    row["terminations"] = summary.get("terminations", {})
    return row, episodes


def write_outputs(outputs: dict[Path, str]) -> None:
    """Write each text through a temporary file and a rename, so a crash never leaves half a file."""
    for path, text in outputs.items():
        atomic_write_text(path, text)
