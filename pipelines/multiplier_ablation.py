"""Issue 9's ablation of the multiplier: the end of each reduced-budget run, and lambda(s) vs v_c(s).

    python -m pipelines.multiplier_ablation [--ablation-dir results/training/ablation]

Reads every run directory under ``--ablation-dir`` (DVC stage ``train_multiplier_ablation``):
``summary.json`` (last 5% of training), ``config.yaml`` (the agent settings that differ are listed),
and for PPO-L-SI runs ``multiplier.json`` / ``multiplier_samples.csv`` (srmpc.agents.multiplier_diagnostic).
Writes:
- ``<ablation-dir>/summary.json``: per variant the end-of-training metrics, the cost-rate ratio to the
  PPO run of the same budget, and the multiplier statistics;
- ``<ablation-dir>/summary.md``: the same as a table;
- ``results/figures/multiplier_ablation.png``: per PPO-L-SI variant, lambda(s) against v_c(s) on the
  final policy's states, states followed by a collision or road exit within 2 s in red.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import yaml

from srmpc.agents.hyperparameters import PPOHyperparameters

ROOT = Path(__file__).resolve().parents[1]

REFERENCE = "ppo"
"""The PPO run of the same budget that the cost-rate ratios refer to."""
SETTINGS = ("cost_gamma", "multiplier_lr", "multiplier_lr_final", "multiplier_steps", "multiplier_update_every",
            "multiplier_max_grad_norm", "violation_normalization", "multiplier_loss_on_logit", "cost_threshold")
"""Agent fields reported per variant (where they differ from the PPO-L-SI defaults)."""
MULTIPLIER_COLUMNS = ("corr_lambda_cost_value", "spearman_lambda_cost_value", "corr_lambda_event_ahead",
                      "corr_cost_value_event_ahead", "lambda_mean_violated", "lambda_mean_satisfied",
                      "lambda_mean_event_ahead", "lambda_mean_no_event_ahead", "share_violated", "share_at_max")


def read_run(directory: Path) -> dict:
    agent = yaml.safe_load((directory / "config.yaml").read_text())["agent"]
    defaults = PPOHyperparameters()
    differs = {k: agent.get(k) for k in SETTINGS if agent.get(k) != getattr(defaults, k)}
    run = {"constrained": bool(agent["constrained"]), "settings": differs,
           "training": json.loads((directory / "summary.json").read_text())}
    if (directory / "multiplier.json").exists():
        run["multiplier"] = json.loads((directory / "multiplier.json").read_text())
    return run


def fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


def markdown(runs: dict[str, dict]) -> str:
    lines = [
        "# Multiplier ablation (PPO-L-SI, seed 0, light traffic, reduced budget)",
        "",
        "End of training = the last 5% of the frames. `rate / PPO`: cost rate over the PPO run of the same",
        "budget (the paper's claim needs < 0.5). lambda vs v_c on the final policy's last batch: Pearson r,",
        "Spearman rho, r with a collision/road exit within 2 s, and mean lambda where v_c > d vs v_c <= d.",
        "`settings`: what differs from the multiplier before issue 9 (`ppo_lsi`: cost_gamma 0.9, multiplier_lr",
        "1e-3, 4 multiplier steps per iteration, no violation normalization). `ma`: Ma et al.'s Safety_Index_Synthesis",
        "as published; `ma_discounted`: the same with cost_gamma 0.9; `*_fast`: with multiplier_lr 1e-3; `fac`:",
        "Feasible Actor-Critic's multiplier schedule; `per_step`: only cost_gamma 0.",
        "",
        "| variant | settings | frames | cost rate | rate / PPO | J_c | J_r | v_x | r(l, v_c) | rho(l, v_c) "
        "| r(l, event) | r(v_c, event) | l where v_c>d / <=d | share v_c>d |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, run in runs.items():
        t, m = run["training"], run.get("multiplier", {})
        settings = ", ".join(f"{k}={v}" for k, v in run["settings"].items()) or ("PPO" if not run["constrained"] else
                                                                                "before issue 9")
        lines.append(
            f"| {name} | {settings} | {t['frames']:,} | {t['cost_rate']:.2e} | {fmt(run.get('cost_rate_over_ppo'))} "
            f"| {t['cost_return']:.3f} | {t['return']:.0f} | {t['vx']:.2f} | {fmt(m.get('corr_lambda_cost_value'))} "
            f"| {fmt(m.get('spearman_lambda_cost_value'))} | {fmt(m.get('corr_lambda_event_ahead'))} "
            f"| {fmt(m.get('corr_cost_value_event_ahead'))} | {fmt(m.get('lambda_mean_violated'))} / "
            f"{fmt(m.get('lambda_mean_satisfied'))} | {fmt(m.get('share_violated'))} |")
    return "\n".join(lines) + "\n"


def figure(runs: dict[str, dict], directory: Path, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    constrained = [name for name, run in runs.items() if "multiplier" in run]
    columns = min(3, len(constrained))
    rows = math.ceil(len(constrained) / columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for ax, name in zip(axes.flat, constrained, strict=False):
        with (directory / name / "multiplier_samples.csv").open(newline="") as handle:
            samples = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]
        for event, colour, label in ((0.0, "tab:blue", "no event within 2 s"), (1.0, "tab:red", "event within 2 s")):
            chosen = [s for s in samples if s["event_ahead"] == event]
            ax.scatter([s["cost_value"] for s in chosen], [s["lambda"] for s in chosen], s=3, alpha=0.35,
                       color=colour, label=label, rasterized=True)
        m = runs[name]["multiplier"]
        ax.axvline(0.0, color="grey", lw=0.8, ls=":")
        ax.set_title(f"{name}: r = {m['corr_lambda_cost_value']:.2f}, rho = {m['spearman_lambda_cost_value']:.2f}",
                     fontsize=9)
        ax.set_xlabel(r"cost critic $v_c(s)$")
        ax.set_ylabel(r"$\lambda(s)$")
        ax.ticklabel_format(axis="y", style="plain", useOffset=False)
    for ax in list(axes.flat)[len(constrained):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, markerscale=3, loc="best")
    fig.suptitle("lambda(s) vs v_c(s) on the final policy's states (multiplier ablation)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ablation-dir", type=Path, default=ROOT / "results/training/ablation")
    parser.add_argument("--figure", type=Path, default=ROOT / "results/figures/multiplier_ablation.png")
    args = parser.parse_args()
    names = sorted(p.name for p in args.ablation_dir.iterdir() if (p / "summary.json").exists())
    if REFERENCE not in names:
        raise SystemExit(f"{args.ablation_dir / REFERENCE}: missing (the PPO run the ratios refer to)")
    first = [n for n in (REFERENCE, "ppo_lsi") if n in names]
    runs = {name: read_run(args.ablation_dir / name) for name in [*first, *(n for n in names if n not in first)]}
    reference = runs[REFERENCE]["training"]
    for run in runs.values():
        run["cost_rate_over_ppo"] = run["training"]["cost_rate"] / reference["cost_rate"]
        run["return_minus_ppo"] = run["training"]["return"] - reference["return"]
    (args.ablation_dir / "summary.json").write_text(json.dumps(runs, indent=2) + "\n")
    (args.ablation_dir / "summary.md").write_text(markdown(runs))
    figure(runs, args.ablation_dir, args.figure)
    print(markdown(runs))


if __name__ == "__main__":
    main()
