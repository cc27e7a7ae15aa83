"""What every report of the pipeline shares: the table's methods and rows, the paper's published values, the
bootstrap settings, and how a report is written.

- :data:`METHODS`, :data:`PAIRED_AGAINST`: the table's rows (their names) and what SRMPC is paired against;
- :data:`EXPERIMENTS`: the experiment each row is;
- :func:`runs`, :func:`run_of`: every evaluation by (experiment, traffic), read from its ``config.yaml``, never
  from its folder's name or a guess from config values; :func:`planner_knobs`: a run's planner settings, as data;
- :data:`PAPER`: the paper's Table "Evaluation results";
- :func:`method_row`, :func:`row_with_intervals`, :func:`paper_row`, :func:`ci`: a method's row, read and printed;
- :func:`difference`, :func:`sign`: a paired difference printed, and which side of 0 its CI lies on;
- :func:`cut_with_ci`: a paired ratio printed as the reduction it makes;
- :func:`write_outputs`: each report file written atomically.

Every interval uses the bootstrap of ``srmpc.confidence_intervals`` (``BOOTSTRAP_RESAMPLES``,
``BOOTSTRAP_SEED``), the same one ``python -m srmpc`` prints its table with.

The table (``paper_table``), SRMPC's variants (``srmpc_variants``), the trade-off (``tradeoff``), the
cross-check (``crosscheck``) and ``table_vs_revision`` all read these from here.
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import pandas as pd
import yaml

from srmpc.confidence_intervals import table_metrics_with_intervals
from srmpc.controllers.srmpc import (
    OtherVehiclePrediction,
    ReferenceSelection,
    SrmpcSettings,
    TrackingTarget,
    variant_of,
)
from srmpc.output_folder import atomic_write_text

EVALUATION = Path("results/evaluation")
METHODS = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC", "ppo": "PPO",
           "ppo_sb3": "PPO (Stable-Baselines3)",
           "lane_keeping": "Lane keeping (baseline)",
           "srmpc_recommended": "SRMPC, recommended (ours: tracking the rollout, a 1 m safety margin)"}
EXPERIMENTS = {**{method: f"table/{method}" for method in METHODS},
               "srmpc_recommended": "confirmation/srmpc_recommended"}
"""The experiment each row of the table is (conf/experiment/<experiment>.yaml)."""
PAIRED_AGAINST = ("ltv_mpc", "ppo_lsi")
PAPER = {  # Table "Evaluation results" of the paper: J_r, J_r per step (= J_r / n_steps of the row), J_c, rho_c,
    # n_steps, v_x
    ("light", "ppo_lsi"): (-4669, -13.4, 0.308, 0.0009, 348, 23.11),
    ("light", "ltv_mpc"): (-1241, -5.1, 0.625, 0.0026, 244, 24.38),
    ("light", "srmpc"): (-1108, -3.1, 0.215, 0.0006, 357, 24.63),
    ("dense", "ppo_lsi"): (-4499, -16.4, 0.540, 0.002, 274, 22.47),
    ("dense", "ltv_mpc"): (-334, -2.4, 0.788, 0.0057, 139, 24.79),
    ("dense", "srmpc"): (-1211, -4.0, 0.353, 0.0012, 305, 24.47),
}
HEADER = ("| Algorithm | mean J_r (J_r per step = mean J_r / mean n_steps) | mean J_c | rho_c | mean n_steps "
          "| mean v_x [m/s] |\n|---|---|---|---|---|---|")


def ci(row: dict, key: str, digits: int) -> str:
    low, high = row[f"{key}_ci95"]
    return f"{row[key]:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def row_with_intervals(name: str, r: dict) -> str:
    return (f"| {name} | {ci(r, 'mean_return', 0)} ({ci(r, 'return_per_step', 1)}) | "
            f"{ci(r, 'mean_event_cost', 3)} | {ci(r, 'cost_rate', 4)} | {ci(r, 'mean_n_steps', 0)} | "
            f"{ci(r, 'mean_vx', 2)} |")


def paper_row(name: str, values: tuple) -> str:
    j_r, per_step, j_c, rho, steps, vx = values
    return f"| {name} | {j_r:.0f} ({per_step:.1f}) | {j_c:.3f} | {rho:.4f} | {steps:.0f} | {vx:.2f} |"


def read_config(directory: Path) -> dict:
    """The composed config an evaluation folder's episodes belong to (its ``config.yaml``)."""
    return yaml.safe_load((directory / "config.yaml").read_text())


@functools.cache
def runs(root: Path = EVALUATION) -> dict[tuple[str, str], Path]:
    """Every finished evaluation (a folder with a ``summary.json``) under ``root``, keyed by (experiment, traffic)
    as its ``config.yaml`` names them; two folders of one key are an error."""
    found: dict[tuple[str, str], Path] = {}
    for summary in sorted(root.glob("**/summary.json")):
        config = read_config(summary.parent)
        if not config.get("experiment"):
            continue
        key = (config["experiment"], config["scenario"]["traffic"])
        if key in found:
            raise SystemExit(f"{summary.parent} and {found[key]}: both hold experiment {key[0]} in {key[1]} traffic")
        found[key] = summary.parent
    return found


def run_of(experiment: str, traffic: str) -> Path:
    """The folder of ``experiment``'s evaluation in ``traffic`` (:func:`runs`)."""
    directory = runs().get((experiment, traffic))
    if directory is None:
        raise SystemExit(f"no evaluation of experiment {experiment} in {traffic} traffic under {EVALUATION} "
                         f"(run it: dvc repro evaluate@{experiment}-{traffic})")
    return directory


def variant_name(config: dict) -> str:
    """The SRMPC variant a config runs, as ``srmpc.controllers.srmpc.variant_of`` names it (a display name)."""
    settings = config["controller"]["srmpc"]
    return variant_of(SrmpcSettings(ReferenceSelection(settings["selection"]),
                                    OtherVehiclePrediction(settings["prediction"]), int(settings["relinearizations"]),
                                    TrackingTarget(settings["tracking"])))


def planner_knobs(config: dict) -> dict:
    """The planner settings a trade-off point is drawn at (data, not identity): margin [m], the speed (and x)
    weight of state_weights and the common scale on the slack prices."""
    planner = config["planner"]
    return {"safety_margin_longitudinal_m": float(planner["safety_margin_longitudinal_m"]),
            "speed_weight": float(planner["state_weights"][3]),
            "x_weight": float(planner["state_weights"][0]),
            "slack_price_scale": float(planner["slack_price_scale"])}


def sign(interval: tuple[float, float]) -> int:
    """+1 / -1 when a 95% CI lies above / below 0, 0 when it contains 0."""
    return 1 if interval[0] > 0 else -1 if interval[1] < 0 else 0


def difference(d: dict, key: str, digits: int, negate: bool = False) -> str:
    """A paired difference ``d`` (``confidence_intervals.paired_differences``) as "+0.012 [+0.003, +0.021]";
    ``negate`` prints b - a."""
    f = -1.0 if negate else 1.0
    low, high = sorted((f * d[f"{key}_ci95"][0], f * d[f"{key}_ci95"][1]))
    return f"{f * d[key]:+.{digits}f} [{low:+.{digits}f}, {high:+.{digits}f}]"


def cut_with_ci(ratio: dict, word: str = "") -> str:
    """The reduction 1 - a / b of a paired ratio (an entry of ``confidence_intervals.paired_ratios``) with its 95% CI
    in percent, "80% [76%, 83%]" (``word`` after the point estimate: "96% lower [88%, 100%]"); "n/a" when there is no
    finite ratio, "unbounded" at the end where the ratio has no upper bound."""
    def percent(value: float) -> str:
        return "unbounded" if math.isinf(value) else f"{value:.0%}"

    low, high = ratio["ratio_ci95"]
    point = "n/a" if ratio["ratio"] is None else percent(1 - ratio["ratio"])
    return f"{point}{' ' + word if word else ''} [{percent(1 - high)}, {percent(1 - low)}]"


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
