"""DVC stage: the paper's evaluation table from the evaluation summaries.

Reads results/evaluation/twin/<controller>_<traffic>/summary.json and writes results/table.md
(ours beside the paper's published values) and results/table.json (ours).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

EVALUATION = Path("results/evaluation/twin")
CONTROLLERS = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC", "lane_keeping": "Lane keeping (baseline)"}
PAPER = {  # Table "Evaluation results" of the paper: J_r, J_r per step, J_c, rho_c, n_steps, v_x
    ("light", "ppo_lsi"): (-4669, -13.4, 0.308, 0.0009, 348, 23.11),
    ("light", "ltv_mpc"): (-1241, -5.1, 0.625, 0.0026, 244, 24.38),
    ("light", "srmpc"): (-1108, -3.1, 0.215, 0.0006, 357, 24.63),
    ("dense", "ppo_lsi"): (-4499, -16.4, 0.540, 0.002, 274, 22.47),
    ("dense", "ltv_mpc"): (-334, -2.4, 0.788, 0.0057, 139, 24.79),
    ("dense", "srmpc"): (-1211, -4.0, 0.353, 0.0012, 305, 24.47),
}


def row(name: str, values: tuple) -> str:
    j_r, per_step, j_c, rho, steps, vx = values
    return f"| {name} | {j_r:.0f} ({per_step:.1f}) | {j_c:.3f} | {rho:.4f} | {steps:.0f} | {vx:.2f} |"


def main() -> None:
    table, lines = {}, []
    header = (
        "| Algorithm | mean J_r (per step) | mean J_c | rho_c | mean n_steps | mean v_x [m/s] |\n"
        "|---|---|---|---|---|---|"
    )
    for traffic in ("light", "dense"):
        lines += [f"### {traffic} traffic", "", "Ours (1000 episodes each, twin simulator):", "", header]
        for controller, name in CONTROLLERS.items():
            path = EVALUATION / f"{controller}_{traffic}" / "summary.json"
            if not path.exists():
                continue
            s = json.loads(path.read_text())
            values = (s["mean_return"], s["mean_return_per_step"], s["mean_event_cost"], s["cost_rate"],
                      s["mean_n_steps"], s["mean_vx"])
            table.setdefault(traffic, {})[controller] = dict(zip(
                ["mean_return", "mean_return_per_step", "mean_event_cost", "cost_rate", "mean_n_steps", "mean_vx"],
                values, strict=True)) | {"episodes": s["episodes"]}
            lines.append(row(name, values))
        lines += ["", "Paper (published values):", "", header]
        lines += [row(CONTROLLERS[c], v) for (t, c), v in PAPER.items() if t == traffic]
        lines.append("")
    outputs = {
        Path("results/table.md"): "\n".join(lines),
        Path("results/table.json"): json.dumps(table, indent=2) + "\n",
    }
    for path, text in outputs.items():
        temporary = path.with_name(path.name + ".tmp")
        temporary.write_text(text)
        os.replace(temporary, path)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
