"""DVC stage ``crosscheck``: the twin's own resets against highway-env's resets, per method and traffic.

    python -m pipelines.crosscheck

For each method (PPO-L-SI, LTV-MPC, SRMPC) and traffic level, compares (each folder found by the experiment and
traffic its ``config.yaml`` names)
- experiment ``table/<method>``: 1000 episodes from the twin's own resets (the table's runs), and
- experiment ``crosscheck/resets_<method>``: 1000 episodes that start from
  highway-env's own reset for the same seed, copied into the twin (``evaluation.simulator=
  twin_highway_env_resets``), so the start states are highway-env's and every step equals highway-env's.

Writes ``results/evaluation/crosscheck.json`` as ``[traffic][method]`` with ``episodes``, J_c (share of
episodes with a collision or road exit) and its Wilson 95% CI and mean v_x for both start sources
(``twin``, ``highway_env_resets``), and ``p_value``: the two-sided pooled two-proportion z-test of
equal J_c (1.0 when neither source has an event; Fisher's exact test beside it as ``p_value_fisher``).
``pipelines/paper_table.py`` prints it as a short table in results/table.md.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
from scipy.stats import fisher_exact, norm

from pipelines.reporting import run_of, write_outputs
from srmpc.confidence_intervals import wilson_interval

ROOT = Path(__file__).resolve().parents[1]

METHODS = ("ppo_lsi", "ltv_mpc", "srmpc")
SOURCES = {"twin": "table/{method}", "highway_env_resets": "crosscheck/resets_{method}"}
"""The experiment of each method's evaluation from each source of resets."""
OUTPUT = ROOT / "results/evaluation/crosscheck.json"


def two_proportion_p_value(events_a: int, n_a: int, events_b: int, n_b: int) -> float:
    """Two-sided p-value of the pooled two-proportion z-test of equal rates (1.0 if the pooled rate is 0 or 1)."""
    pooled = (events_a + events_b) / (n_a + n_b)
    if pooled in (0.0, 1.0):
        return 1.0
    z = (events_a / n_a - events_b / n_b) / math.sqrt(pooled * (1.0 - pooled) * (1.0 / n_a + 1.0 / n_b))
    return float(2.0 * norm.sf(abs(z)))


def source_metrics(directory: Path) -> dict:
    episodes = pd.read_csv(directory / "episodes.csv")
    events = int((episodes["event_cost"] > 0).sum())
    return {"episodes": len(episodes), "events": events, "mean_event_cost": events / len(episodes),
            "mean_event_cost_ci95": list(wilson_interval(events, len(episodes))),
            "mean_vx": float(episodes["mean_vx"].mean())}


def main() -> None:
    result: dict = {}
    for traffic in ("light", "dense"):
        for method in METHODS:
            directories = {source: run_of(experiment.format(method=method), traffic)
                           for source, experiment in SOURCES.items()}
            metrics = {source: source_metrics(d) for source, d in directories.items()}
            a, b = metrics["twin"], metrics["highway_env_resets"]
            table = [[a["events"], a["episodes"] - a["events"]], [b["events"], b["episodes"] - b["events"]]]
            result.setdefault(traffic, {})[method] = {
                "episodes": min(a["episodes"], b["episodes"]), **metrics,
                "p_value": two_proportion_p_value(a["events"], a["episodes"], b["events"], b["episodes"]),
                "p_value_fisher": float(fisher_exact(table).pvalue),
            }
    write_outputs({OUTPUT: json.dumps(result, indent=2) + "\n"})
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
