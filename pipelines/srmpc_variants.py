"""DVC stage: SRMPC's variants beside the paper's SRMPC and LTV-MPC at the same planner settings.

Reads the table's evaluations (results/evaluation/twin/: SRMPC, its variants, LTV-MPC and PPO-L-SI at
conf/planner/ltv_mpc.yaml) and, at a 4 m safety margin (planner=margin_4m), SRMPC and LTV-MPC from the
trade-off (results/evaluation/tradeoff/), each picked by what its folder's config.yaml says it is; writes
- results/ablation.json: ``[traffic][variant]`` with the keys of table.json (metrics, ``_ci95`` intervals,
  ``outcomes``), plus ``meets_target`` and, for each SRMPC variant, ``paired_differences`` against
  the paper's SRMPC (same seeds);
- results/ablation.md: the same as a table, with where each variant lands against the target.

Target (issue "SRMPC itself"): J_c <= 0.02 in light and <= 0.05 in dense traffic at a mean v_x >= 23.5 m/s,
beating the paper's SRMPC (0.215 / 0.353 at 24.6 / 24.5 m/s) on both axes at once.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipelines.reporting import DEFAULT_SETTINGS, EVALUATION, evaluations, method_row, row_with_intervals, write_outputs
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences

TRADEOFF = Path("results/evaluation/tradeoff")
VARIANTS = {
    "ltv_mpc": (("ltv_mpc", 8.0), "LTV-MPC (same planner config)"),
    "ppo_lsi": (("ppo_lsi", 8.0), "PPO-L-SI (the policy alone)"),
    "paper": (("srmpc", 8.0), "SRMPC, paper (Algorithm 1)"),
    "best_of_two": (("srmpc_best_of_two", 8.0), "(a) best of two references"),
    "rollout_prediction": (("srmpc_rollout_prediction", 8.0), "(b) rollout's IDM prediction"),
    "sqp": (("srmpc_sqp", 8.0), "(c) 2 SQP re-linearizations"),
    "track_rollout": (("srmpc_track_rollout", 8.0), "(d) QP tracks the rollout"),
    "ltv_mpc_margin_4m": (("ltv_mpc", 4.0), "LTV-MPC, planner=margin_4m"),
    "margin_4m": (("srmpc", 4.0), "(e) SRMPC, planner=margin_4m"),
}
"""Row key -> ((method, safety margin [m]) of its evaluation's config.yaml, label); the other planner settings are
conf/planner/ltv_mpc.yaml's, the seeds the table's."""


def rows_by_experiment() -> dict[tuple[str, str, float], Path]:
    """(method, traffic, margin [m]) -> the folder, over the table's seeds with the default speed weights."""
    found = {}
    for directory, x in evaluations(EVALUATION, TRADEOFF):
        s = x["settings"]
        weights_default = all(s[k] == DEFAULT_SETTINGS[k] for k in ("speed_weight", "x_weight"))
        if x["seed"] == 0 and x["simulator"] == "twin" and weights_default:
            found[(x["method"], x["traffic"], s["safety_margin_longitudinal_m"])] = directory
    return found
TARGET_EVENT_COST = {"light": 0.02, "dense": 0.05}
TARGET_MIN_VX_MPS = 23.5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    ablation, lines, found = {}, [], rows_by_experiment()
    for traffic in ("light", "dense"):
        rows, frames = {}, {}
        for variant, ((method, margin), _) in VARIANTS.items():
            directory = found.get((method, traffic, margin))
            if directory is None:
                continue
            rows[variant], frames[variant] = method_row(directory, args.resamples, args.seed)
            rows[variant]["meets_target"] = bool(rows[variant]["mean_event_cost"] <= TARGET_EVENT_COST[traffic]
                                                 and rows[variant]["mean_vx"] >= TARGET_MIN_VX_MPS)
        for variant in rows:
            if variant not in ("ltv_mpc", "ppo_lsi", "paper", "ltv_mpc_margin_4m") and "paper" in frames:
                rows[variant]["paired_differences"] = {
                    "paper": paired_differences(frames[variant], frames["paper"], args.resamples, args.seed)}
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
    write_outputs({Path("results/ablation.md"): "\n".join(lines),
                   Path("results/ablation.json"): json.dumps(ablation, indent=2) + "\n"})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
