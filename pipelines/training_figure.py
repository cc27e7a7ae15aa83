"""The training figure (PPO, PPO-L-SI, PPO-L-RSS and Stable-Baselines3's PPO, over seeds) and
``results/training/summary.json``.

    python -m pipelines.training_figure [--training-dir results/training] [--seeds 0 1 2] [--window 0.05]

Reads each agent's ``<training-dir>/<agent>/seed_<seed>/metrics.csv`` (one row per iteration, written
by the trainer; DVC stage ``train``) and writes:
- ``results/figures/training.png``: episodic return J_r (sum of r'), episodic cost return J_c
  (collisions + road exits) and cost rate rho_c against environment steps, each smoothed per seed by
  a running mean over ``window`` x (number of iterations) iterations, as in the paper's figure; the
  line is the mean over seeds, the band their range (min to max);
- ``results/figures/training.csv``: the raw and smoothed series behind the plot, per seed;
- ``<training-dir>/summary.json``: per agent the mean over seeds of frames, wall_s, return,
  cost_return, cost_rate (and more) over the last 5% of training, ``per_seed`` (the same per seed),
  ``cost_rate_ci95``, ``cost_return_ci95``, ``return_ci95`` and ``vx_ci95`` (Student-t over seeds; null
  for one seed), the list ``seeds``, and the paper's claim (PPO-L-SI's final cost rate under half of PPO's,
  its return not worse) judged from CIs (``CLAIM_RULE``: ``verdict`` holds / fails / not shown, pooled over seeds
  and per seed, with the intervals it rests on) against our PPO (``paper_claim``) and against
  Stable-Baselines3's PPO (``paper_claim_vs_ppo_sb3``), the same claim for PPO-L-RSS against our PPO
  (``paper_claim_ppo_lsi_rss``, keys ``..._rss_over_ppo``), and ``flat_from_frames``: per series, the first
  frame after which the smoothed mean over seeds stays within 25% of its final value.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

import numpy as np

from srmpc.agents.report import final_window, read_metrics, summarize_training
from srmpc.confidence_intervals import rate_ratio_interval, t_interval

ROOT = Path(__file__).resolve().parents[1]

AGENTS = {"ppo": "PPO", "ppo_lsi": "PPO-L-SI", "ppo_sb3": "PPO (Stable-Baselines3)", "ppo_lsi_rss": "PPO-L-RSS",
          "ppo_lsi_rss_ad_rss_lib": "PPO-L-RSS, ad-rss-lib's parameters"}
"""ppo_sb3: the peer PPO (srmpc.sb3_ppo, DVC stage ``train_sb3``), PPO's settings in another implementation;
ppo_lsi_rss: PPO-L-SI with the RSS safety index (DVC stage ``train_rss``), ppo_lsi_rss_ad_rss_lib the same with
ad-rss-lib's RSS parameters (one seed)."""
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


FLAT_TOLERANCE = 0.25
"""A smoothed mean-over-seeds curve is flat from the first frame after which it stays within this
relative distance of its final value (the budget check of issue 9)."""


def flat_from(frames: list[float], curve: list[float], tolerance: float = FLAT_TOLERANCE) -> float | None:
    """The first frame after which ``curve`` stays within ``tolerance`` x |final| of its final value."""
    final = curve[-1]
    if not math.isfinite(final):
        return None
    start = len(curve) - 1
    while start > 0 and math.isfinite(curve[start - 1]) and abs(curve[start - 1] - final) <= tolerance * abs(final):
        start -= 1
    return frames[start]


def summarize_seeds(per_seed: dict[int, dict[str, float]]) -> dict:
    """Mean over seeds of every numeric summary key, t intervals of the claim's metrics, and per seed."""
    keys = [k for k, v in next(iter(per_seed.values())).items() if isinstance(v, int | float)]
    summary: dict = {k: sum(s[k] for s in per_seed.values()) / len(per_seed) for k in keys}
    for key in ("cost_rate", "cost_return", "return", "vx"):
        interval = t_interval([s[key] for s in per_seed.values()])
        summary[f"{key}_ci95"] = None if math.isnan(interval[0]) else list(interval)
    summary["seeds"] = sorted(per_seed)
    summary["per_seed"] = {str(seed): s for seed, s in sorted(per_seed.items())}
    return summary


CLAIM_RULE = ("holds when the 95% CI of the cost-rate ratio (constrained agent / PPO) lies below 0.5 and the CI of "
              "the return difference (constrained agent - PPO) lies above 0; fails when the ratio's CI lies above "
              "0.5 or the return difference's below 0; not shown otherwise. Per seed: the exact conditional interval "
              "of the ratio of the two runs' event rates over the last 5% of training and Welch's t interval of the "
              "difference of their per-iteration returns there; pooled over seeds: Student-t intervals over the "
              "seeds of the log ratio (reported as a ratio) and of the return difference (seed s against seed s)")
"""The paper's training claim, judged from CIs as every other verdict is."""


def tail_counts(rows: list[dict[str, float]], last_fraction: float) -> dict:
    """Over ``summarize_training``'s final window: the event count, the env steps, and each iteration's mean return
    of the episodes that ended in it (iterations with none left out)."""
    window = final_window(rows, last_fraction)
    return {"events": int(round(sum(r["cost_rate"] * frames for r, frames in window))),
            "steps": float(sum(frames for _, frames in window)),
            "returns": [r["episode/return"] for r, _ in window if r["episodes"] > 0]}


def welch_interval(a: list[float], b: list[float], confidence: float = 0.95) -> tuple[float, float]:
    """Welch's t interval of mean(a) - mean(b)."""
    from scipy.stats import t

    x, y = np.asarray(a, float), np.asarray(b, float)
    if min(x.size, y.size) < 2:
        return (math.nan, math.nan)
    va, vb = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    if va + vb == 0.0:
        return (float(x.mean() - y.mean()), float(x.mean() - y.mean()))
    dof = (va + vb) ** 2 / (va**2 / (x.size - 1) + vb**2 / (y.size - 1))
    half = t.ppf(0.5 + confidence / 2.0, dof) * math.sqrt(va + vb)
    return (float(x.mean() - y.mean() - half), float(x.mean() - y.mean() + half))


def claim_verdict(ratio_ci: tuple[float, float] | None, difference_ci: tuple[float, float] | None) -> str:
    """:data:`CLAIM_RULE` on the two intervals: ``holds``, ``fails`` or ``not shown``."""
    if ratio_ci is None or difference_ci is None:
        return "not shown"
    if ratio_ci[0] > 0.5 or difference_ci[1] < 0:
        return "fails"
    return "holds" if ratio_ci[1] < 0.5 and difference_ci[0] > 0 else "not shown"


def paper_claim(ppo: dict, lsi: dict, counts: dict, baseline: str = "our PPO (srmpc.agents, constraint off)",
                agent: str = "PPO-L-SI", short: str = "lsi") -> dict:
    """The paper's training claim for the constrained ``agent`` (keys named by ``short``) against ``ppo``, pooled
    over seeds and seed by seed (same seed, same resets), by :data:`CLAIM_RULE`; ``counts[(agent or ppo)][seed]``
    is :func:`tail_counts` of that run."""
    common = sorted(set(ppo["per_seed"]) & set(lsi["per_seed"]), key=int)
    ratio, difference = f"cost_rate_ratio_{short}_over_ppo", f"return_difference_{short}_minus_ppo"
    per_seed = {}
    for seed in common:
        a, b = counts["agent"][int(seed)], counts["ppo"][int(seed)]
        ratio_ci = rate_ratio_interval(a["events"], a["steps"], b["events"], b["steps"])
        difference_ci = welch_interval(a["returns"], b["returns"])
        per_seed[seed] = {ratio: lsi["per_seed"][seed]["cost_rate"] / ppo["per_seed"][seed]["cost_rate"]
                          if ppo["per_seed"][seed]["cost_rate"] > 0 else None,
                          f"{ratio}_ci95": list(ratio_ci), "events": [a["events"], b["events"]],
                          difference: lsi["per_seed"][seed]["return"] - ppo["per_seed"][seed]["return"],
                          f"{difference}_ci95": list(difference_ci), "verdict": claim_verdict(ratio_ci, difference_ci)}
        per_seed[seed]["holds"] = per_seed[seed]["verdict"] == "holds"
    logs = [math.log(v[ratio]) for v in per_seed.values() if v[ratio]]
    log_ci = t_interval(logs) if len(logs) == len(common) else (math.nan, math.nan)
    pooled_ratio_ci = None if math.isnan(log_ci[0]) else (math.exp(log_ci[0]), math.exp(log_ci[1]))
    difference_ci = t_interval([v[difference] for v in per_seed.values()])
    pooled_difference_ci = None if math.isnan(difference_ci[0]) else difference_ci
    verdict = claim_verdict(pooled_ratio_ci, pooled_difference_ci)
    return {
        "statement": f"at the end of training {agent}'s cost rate is under half of PPO's and its return is not worse",
        "rule": CLAIM_RULE,
        "ppo": baseline,
        ratio: lsi["cost_rate"] / ppo["cost_rate"] if ppo["cost_rate"] > 0 else None,
        f"{ratio}_ci95": list(pooled_ratio_ci) if pooled_ratio_ci else None,
        difference: lsi["return"] - ppo["return"],
        f"{difference}_ci95": list(pooled_difference_ci) if pooled_difference_ci else None,
        "verdict": verdict,
        "holds": verdict == "holds",
        "cost_rate_ci95_disjoint": None if None in (lsi["cost_rate_ci95"], ppo["cost_rate_ci95"]) else
        bool(lsi["cost_rate_ci95"][1] < ppo["cost_rate_ci95"][0]
             or ppo["cost_rate_ci95"][1] < lsi["cost_rate_ci95"][0]),
        "per_seed": per_seed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--training-dir", type=Path, default=ROOT / "results/training")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "results/figures")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--window", type=float, default=0.05, help="running-mean window, fraction of iterations")
    parser.add_argument("--last-fraction", type=float, default=0.05, help="summary over this final share of frames")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs: dict[str, dict[int, list[dict[str, float]]]] = {}
    for agent in AGENTS:
        for seed in args.seeds:
            path = args.training_dir / agent / f"seed_{seed}" / "metrics.csv"
            if path.exists():
                runs.setdefault(agent, {})[seed] = read_metrics(path)
    if not runs:
        raise SystemExit(f"no metrics.csv under {args.training_dir}/{{{','.join(AGENTS)}}}/seed_*")
    args.figure_dir.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6))
    table = []
    flat: dict[str, dict[str, float | None]] = {}
    for agent, seeds in runs.items():
        length = min(len(rows) for rows in seeds.values())
        frames = [r["frames"] for r in next(iter(seeds.values()))[:length]]
        for (name, column, label), axis in zip(SERIES, axes, strict=True):
            curves = []
            for seed, rows in seeds.items():
                window = max(1, round(args.window * len(rows)))
                smoothed = running_mean([r[column] for r in rows], window)
                curves.append(smoothed[:length])
                for i, r in enumerate(rows):
                    table.append({"agent": agent, "seed": seed, "frames": int(r["frames"]), "wall_s": r["wall_s"],
                                  "series": name, "value": r[column], "running_mean": smoothed[i]})
            mean = [sum(c[i] for c in curves) / len(curves) for i in range(length)]
            low = [min(c[i] for c in curves) for i in range(length)]
            high = [max(c[i] for c in curves) for i in range(length)]
            flat.setdefault(agent, {})[name] = flat_from(frames, mean)
            runs_label = f"mean of {len(seeds)} seeds" if len(seeds) > 1 else f"seed {next(iter(seeds))}"
            line, = axis.plot(frames, mean, label=f"{AGENTS[agent]} ({runs_label})")
            axis.fill_between(frames, low, high, color=line.get_color(), alpha=0.2, lw=0)
            axis.set_xlabel("environment steps")
            axis.set_ylabel(label)
    axes[2].set_yscale("log")
    for axis in axes:
        axis.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()  # one legend below the panels: it covers no curve
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9, frameon=False)
    fig.suptitle(f"PPO (ours and Stable-Baselines3's) vs PPO-L-SI and PPO-L-RSS in training: mean over seeds, band = "
                 f"range over seeds (running mean over {args.window:.0%} of the iterations)")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(args.figure_dir / "training.png", dpi=120)
    with (args.figure_dir / "training.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(table[0]))
        writer.writeheader()
        writer.writerows(table)

    summary = {agent: summarize_seeds({seed: summarize_training(rows, args.last_fraction)
                                       for seed, rows in seeds.items()})
               for agent, seeds in runs.items()}
    for agent, frames_by_series in flat.items():
        summary[agent]["flat_from_frames"] = {**frames_by_series, "tolerance": FLAT_TOLERANCE}
    counts = {agent: {seed: tail_counts(rows, args.last_fraction) for seed, rows in seeds.items()}
              for agent, seeds in runs.items()}
    if {"ppo", "ppo_lsi"} <= summary.keys():
        summary["paper_claim"] = paper_claim(summary["ppo"], summary["ppo_lsi"],
                                             {"ppo": counts["ppo"], "agent": counts["ppo_lsi"]})
    if {"ppo_sb3", "ppo_lsi"} <= summary.keys():
        summary["paper_claim_vs_ppo_sb3"] = paper_claim(summary["ppo_sb3"], summary["ppo_lsi"],
                                                        {"ppo": counts["ppo_sb3"], "agent": counts["ppo_lsi"]},
                                                        "Stable-Baselines3's PPO with our PPO's settings")
    if {"ppo", "ppo_lsi_rss"} <= summary.keys():
        summary["paper_claim_ppo_lsi_rss"] = paper_claim(summary["ppo"], summary["ppo_lsi_rss"],
                                                         {"ppo": counts["ppo"], "agent": counts["ppo_lsi_rss"]},
                                                         agent="PPO-L-RSS", short="rss")
    (args.training_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items()}, indent=2)[:4000])


if __name__ == "__main__":
    main()
