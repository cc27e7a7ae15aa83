"""DVC stage: SRMPC's variants beside the paper's SRMPC and LTV-MPC at the same planner settings.

Reads the experiments of :data:`VARIANTS` (table/: SRMPC, LTV-MPC and PPO-L-SI at conf/planner/ltv_mpc.yaml;
variants/: SRMPC's variants; at a 4 m safety margin, SRMPC and LTV-MPC from tradeoff/), each found by the
experiment and traffic its config.yaml names; writes
- results/ablation.json: ``[traffic][variant]`` with the keys of table.json (metrics, ``_ci95`` intervals,
  ``outcomes``), plus ``meets_target`` and, for each SRMPC variant, ``paired_differences`` against
  the paper's SRMPC (same seeds);
- results/ablation.md: the same as a table, with where each variant lands against the target;
- for ``local_rollout`` (the rollout on the scene cut to the horizon, issue 40) also ``rollout_scope``: local - full
  on the same seeds (J_c, rho_c, v_x with 95% CIs, the collisions of each, and how many episodes are identical
  row for row), the only change between the two being ``controller.srmpc.rollout``.

Target (issue "SRMPC itself"): J_c <= 0.02 in light and <= 0.05 in dense traffic at a mean v_x >= 23.5 m/s,
beating the paper's SRMPC (0.215 / 0.353 at 24.6 / 24.5 m/s) on both axes at once.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from pipelines.reporting import method_row, row_with_intervals, runs, write_outputs
from srmpc.confidence_intervals import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    paired_cost_rate_difference,
    paired_differences,
)

VARIANTS = {
    "ltv_mpc": ("table/ltv_mpc", "LTV-MPC (same planner config)"),
    "ppo_lsi": ("table/ppo_lsi", "PPO-L-SI (the policy alone)"),
    "paper": ("table/srmpc", "SRMPC, paper (Algorithm 1)"),
    "best_of_two": ("variants/best_of_two", "(a) best of two references"),
    "rollout_prediction": ("variants/rollout_prediction", "(b) rollout's IDM prediction"),
    "sqp": ("variants/sqp", "(c) 2 SQP re-linearizations"),
    "track_rollout": ("variants/track_rollout", "(d) QP tracks the rollout"),
    "local_rollout": ("variants/local_rollout", "(f) rollout on the scene cut to the horizon"),
    "ltv_mpc_margin_4m": ("tradeoff/ltv_mpc_margin_4m", "LTV-MPC, planner=margin_4m"),
    "margin_4m": ("tradeoff/srmpc_margin_4m", "(e) SRMPC, planner=margin_4m"),
}
"""Row key -> (its experiment, label); the seeds are the table's."""
TARGET_EVENT_COST = {"light": 0.02, "dense": 0.05}
TARGET_MIN_VX_MPS = 23.5


def rollout_scope(local: pd.DataFrame, full: pd.DataFrame, local_row: dict, full_row: dict, resamples: int,
                  seed: int) -> dict:
    """Local minus full rollout on the same seeds: rho_c with its CI (J_c and v_x are in ``paired_differences``),
    each run's collisions, the episodes equal in every metric column, those with the same termination and J_c,
    and the largest per-episode |v_x difference| [m/s]."""
    merged = local.merge(full, on="seed", suffixes=("_local", "_full"))
    columns = ["episode_return", "event_cost", "n_steps", "mean_vx", "si_cost_return", "termination"]
    same = pd.concat([merged[f"{c}_local"] == merged[f"{c}_full"] for c in columns], axis=1)
    same_outcome = (merged["termination_local"] == merged["termination_full"]) & (
        merged["event_cost_local"] == merged["event_cost_full"])
    return {**paired_cost_rate_difference(local, full, resamples, seed),
            "collisions": {"local": local_row["terminations"].get("collision", 0),
                           "full": full_row["terminations"].get("collision", 0)},
            "identical_episodes": int(same.all(axis=1).sum()),
            "same_outcome_episodes": int(same_outcome.sum()),
            "max_abs_episode_vx_difference_mps": float((merged["mean_vx_local"] - merged["mean_vx_full"]).abs().max())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    ablation, lines, found = {}, [], runs()
    for traffic in ("light", "dense"):
        rows, frames = {}, {}
        for variant, (experiment, _) in VARIANTS.items():
            directory = found.get((experiment, traffic))
            if directory is None:
                continue
            rows[variant], frames[variant] = method_row(directory, args.resamples, args.seed)
            rows[variant]["meets_target"] = bool(rows[variant]["mean_event_cost"] <= TARGET_EVENT_COST[traffic]
                                                 and rows[variant]["mean_vx"] >= TARGET_MIN_VX_MPS)
        for variant in rows:
            if variant not in ("ltv_mpc", "ppo_lsi", "paper", "ltv_mpc_margin_4m") and "paper" in frames:
                rows[variant]["paired_differences"] = {
                    "paper": paired_differences(frames[variant], frames["paper"], args.resamples, args.seed)}
        if "local_rollout" in frames and "paper" in frames:
            rows["local_rollout"]["rollout_scope"] = rollout_scope(
                frames["local_rollout"], frames["paper"], rows["local_rollout"], rows["paper"], args.resamples,
                args.seed)
        ablation[traffic] = rows
        target = f"J_c <= {TARGET_EVENT_COST[traffic]} at v_x >= {TARGET_MIN_VX_MPS} m/s"
        lines += [f"### {traffic} traffic", "", f"1000 episodes each, the same seeds; target: {target}.", "",
                  "| Variant | mean J_r (mean J_r / mean n_steps) | mean J_c | rho_c | mean n_steps "
                  "| mean v_x [m/s] |\n|---|---|---|---|---|---|"]
        lines += [row_with_intervals(VARIANTS[v][1], r) for v, r in rows.items()]
        lines += ["", "| Variant | meets target | J_c - SRMPC (Algorithm 1) | v_x - SRMPC (Algorithm 1) [m/s] | "
                      "steps from policy / shifted / unsolved fallback / brake |", "|---|---|---|---|---|"]
        for variant, row in rows.items():
            d = row.get("paired_differences", {}).get("paper")
            delta_jc = (f"{d['mean_event_cost']:+.3f} [{d['mean_event_cost_ci95'][0]:+.3f}, "
                        f"{d['mean_event_cost_ci95'][1]:+.3f}]") if d else "-"
            delta_vx = (f"{d['mean_vx']:+.2f} [{d['mean_vx_ci95'][0]:+.2f}, {d['mean_vx_ci95'][1]:+.2f}]") if d else "-"
            o = row["outcomes"]
            steps = sum(o.get(k, 0) for k in ("solved", "shifted_previous", "emergency_brake"))
            shares = (" / ".join(f"{o.get(k, 0) / steps:.1%}" for k in
                                 ("solved_from_policy", "solved_from_shifted", "shifted_previous", "emergency_brake"))
                      if steps else "-")
            lines.append(f"| {VARIANTS[variant][1]} | {'yes' if row['meets_target'] else 'no'} | {delta_jc} | "
                         f"{delta_vx} | {shares} |")
        lines.append("")
        if "rollout_scope" in rows.get("local_rollout", {}):
            d, s = rows["local_rollout"]["paired_differences"]["paper"], rows["local_rollout"]["rollout_scope"]
            lines += ["Rollout scope: local - full, the same seeds, the only change `controller.srmpc.rollout`.", "",
                      "| episodes | J_c local - full | rho_c local - full | v_x local - full [m/s] | largest episode "
                      "\\|v_x difference\\| [m/s] | collisions local / full | same termination and J_c | identical |",
                      "|---|---|---|---|---|---|---|---|",
                      f"| {s['episodes']} | {d['mean_event_cost']:+.3f} [{d['mean_event_cost_ci95'][0]:+.3f}, "
                      f"{d['mean_event_cost_ci95'][1]:+.3f}] | {s['cost_rate']:+.2e} [{s['cost_rate_ci95'][0]:+.2e}, "
                      f"{s['cost_rate_ci95'][1]:+.2e}] | {d['mean_vx']:+.2e} [{d['mean_vx_ci95'][0]:+.2e}, "
                      f"{d['mean_vx_ci95'][1]:+.2e}] | {s['max_abs_episode_vx_difference_mps']:.2e} | "
                      f"{s['collisions']['local']} / {s['collisions']['full']} | {s['same_outcome_episodes']} | "
                      f"{s['identical_episodes']} |", ""]
    write_outputs({Path("results/ablation.md"): "\n".join(lines),
                   Path("results/ablation.json"): json.dumps(ablation, indent=2) + "\n"})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
