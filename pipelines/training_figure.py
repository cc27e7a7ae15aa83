"""The paper's training figure (PPO vs PPO-L-SI) and ``results/training/summary.json``.

    python pipelines/training_figure.py [--training-dir results/training] [--window 0.05]

Reads each agent's ``<training-dir>/<agent>/metrics.csv`` (one row per iteration, written by the
trainer) and writes:
- ``results/figures/training.png``: episodic return J_r (sum of r'), episodic cost return J_c
  (collisions + road exits) and cost rate rho_c against environment steps, each smoothed by a
  running mean over ``window`` x (number of iterations) iterations, as in the paper's figure;
- ``results/figures/training.csv``: the raw and smoothed series behind the plot;
- ``<training-dir>/summary.json``: per agent frames, wall_s, return, cost_return, cost_rate (and
  more) over the last 5% of training, plus the paper's claim (PPO-L-SI's final cost rate under half
  of PPO's, its return not worse) evaluated on these numbers.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from srmpc.agents.report import read_metrics, summarize_training  # noqa: E402

AGENTS = {"ppo": "PPO", "ppo_lsi": "PPO-L-SI"}
SERIES = (("return", "episode/return", "episodic return $J_r$"),
          ("cost_return", "episode/cost_return", "episodic cost return $J_c$"),
          ("cost_rate", "cost_rate", r"cost rate $\rho_c$"))


def running_mean(values: list[float], window: int) -> list[float]:
    """Mean of the last ``window`` finite values at each index (NaN until one is seen)."""
    out, buffer = [], []
    for value in values:
        if math.isfinite(value):
            buffer.append(value)
            buffer = buffer[-window:]
        out.append(sum(buffer) / len(buffer) if buffer else math.nan)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--training-dir", type=Path, default=ROOT / "results/training")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "results/figures")
    parser.add_argument("--window", type=float, default=0.05, help="running-mean window, fraction of iterations")
    parser.add_argument("--last-fraction", type=float, default=0.05, help="summary over this final share of frames")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {a: read_metrics(args.training_dir / a / "metrics.csv") for a in AGENTS
            if (args.training_dir / a / "metrics.csv").exists()}
    if not runs:
        raise SystemExit(f"no metrics.csv under {args.training_dir}/{{{','.join(AGENTS)}}}")
    args.figure_dir.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    table = []
    for agent, rows in runs.items():
        window = max(1, round(args.window * len(rows)))
        frames = [r["frames"] for r in rows]
        smoothed = {}
        for (name, column, label), axis in zip(SERIES, axes, strict=True):
            raw = [r[column] for r in rows]
            smoothed[name] = running_mean(raw, window)
            axis.plot(frames, smoothed[name], label=AGENTS[agent])
            axis.set_xlabel("environment steps")
            axis.set_ylabel(label)
        for i, r in enumerate(rows):
            table.append({"agent": agent, "frames": int(r["frames"]), "wall_s": r["wall_s"],
                          **{name: r[column] for name, column, _ in SERIES},
                          **{f"{name}_running_mean": smoothed[name][i] for name, _, _ in SERIES}})
    for axis in axes:
        axis.grid(alpha=0.3)
        axis.legend()
    fig.suptitle(f"PPO vs PPO-L-SI in training (running mean over {args.window:.0%} of the iterations)")
    fig.tight_layout()
    fig.savefig(args.figure_dir / "training.png", dpi=120)
    with (args.figure_dir / "training.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)

    summary = {agent: summarize_training(rows, args.last_fraction) for agent, rows in runs.items()}
    if {"ppo", "ppo_lsi"} <= summary.keys():
        ppo, lsi = summary["ppo"], summary["ppo_lsi"]
        summary["paper_claim"] = {
            "statement": "at the end of training PPO-L-SI's cost rate is under half of PPO's "
                         "and its return is not worse",
            "cost_rate_ratio_lsi_over_ppo": lsi["cost_rate"] / ppo["cost_rate"] if ppo["cost_rate"] > 0 else None,
            "return_difference_lsi_minus_ppo": lsi["return"] - ppo["return"],
            "holds": bool(lsi["cost_rate"] < 0.5 * ppo["cost_rate"] and lsi["return"] >= ppo["return"]),
        }
    (args.training_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
