"""DVC stage ``operating_point_calibration``: LTV-MPC in light traffic calibrated to the paper's LTV-MPC row.

    python -m pipelines.operating_point_calibration [--probes pipelines/operating_point_probes.yaml]

The paper's LTV-MPC drives at 24.38 m/s and ends 62.5% of its light-traffic episodes in a crash or road exit
(``PAPER[("light", "ltv_mpc")]`` of ``pipelines/reporting.py``); ours at ``planner=ltv_mpc`` drives at
21 m/s with J_c 0.04. The probes file lists small LTV-MPC evaluations (``probes``: a name, a number of
episodes, Hydra overrides of at most three knobs: ``planner.slack_price_scale``, the lateral and speed
entries of ``planner.state_weights``, ``planner.safety_margin_longitudinal_m``), all in light traffic from
the same calibration seeds (episode i from ``seed`` + i, 200000 + i: never the table's 0 + i nor the
confirmation's 100000 + i), so any two probes are paired episode by episode. Each probe is an ordinary
evaluation (``python -m srmpc``, MLflow off) into ``results/operating_point/probes/<name>/``; a finished probe
is not rerun, an interrupted one resumes.

Writes, one row per probe in the file's order:

- ``results/operating_point/calibration.csv``: the probe's knobs (the effective planner values), J_c, v_x,
  n_steps, J_r per step, rho_c, each with its 95% CI (Wilson for J_c, bootstrap over episodes otherwise, as
  ``results/table.md``), and its distance to the paper's point in units of the target band
  (max(|J_c - 0.625| / 0.05, |v_x - 24.38| / 0.3): 1 or less is inside both bands);
- ``results/operating_point/calibration.md``: the same as a table, the target, the closest probe, and the
  frozen option (``frozen`` in the probes file: ``conf/planner/<frozen>.yaml``, whose composed planner settings
  must equal those of its ``frozen_probe``; checked here);
- ``results/figures/operating_point_calibration.png``: J_c against v_x of every probe, with the target.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import yaml
from omegaconf import OmegaConf

from pipelines.reporting import PAPER, write_outputs
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, table_metrics_with_intervals
from srmpc.config.compose import compose_config

ROOT = Path(__file__).resolve().parents[1]
PROBES = ROOT / "pipelines/operating_point_probes.yaml"
OUTPUT = ROOT / "results/operating_point"
FIGURE = ROOT / "results/figures/operating_point_calibration.png"
TARGET = PAPER[("light", "ltv_mpc")]
"""The paper's light LTV-MPC row: J_r, J_r per step, J_c, rho_c, n_steps, v_x."""
TARGET_J_C, TARGET_VX = TARGET[2], TARGET[5]
BAND_J_C, BAND_VX = 0.05, 0.3
"""The calibration's target band: |J_c - 0.625| <= 0.05 and |v_x - 24.38| <= 0.3 m/s."""
MAX_EPISODES = 200
"""At most this many episodes per probe."""
FIRST_CALIBRATION_SEED = 200000
"""Calibration seeds start here: the table runs seeds 0 + i, the confirmation 100000 + i (1000 each)."""
KNOB_KEYS = ("slack_price_scale", "lateral_weight", "speed_weight", "safety_margin_longitudinal_m")
METRICS = (("mean_event_cost", "J_c", 3), ("mean_vx", "v_x", 2), ("mean_n_steps", "n_steps", 0),
           ("mean_return_per_step", "J_r per step", 2), ("cost_rate", "rho_c", 4))


def read_probes(path: Path) -> dict:
    """The probes file, checked: calibration seeds, at most MAX_EPISODES per probe, unique names."""
    spec = yaml.safe_load(path.read_text())
    seed, probes = int(spec["seed"]), spec["probes"]
    if seed < FIRST_CALIBRATION_SEED:
        raise SystemExit(f"{path}: seed={seed}: calibration seeds must be >= {FIRST_CALIBRATION_SEED} "
                         "(0 + i are the table's, 100000 + i the confirmation's)")
    names = [p["name"] for p in probes]
    if len(set(names)) != len(names):
        raise SystemExit(f"{path}: probe names must be unique")
    for probe in probes:
        if not 1 <= int(probe["episodes"]) <= MAX_EPISODES:
            raise SystemExit(f"{path}: probe {probe['name']}: episodes={probe['episodes']}: must be in "
                             f"[1, {MAX_EPISODES}]")
    return spec


def probe_overrides(spec: dict, probe: dict) -> list[str]:
    """The Hydra overrides of a probe: LTV-MPC, the file's traffic and seed, the probe's knobs."""
    return [f"scenario={spec.get('traffic', 'light')}", "evaluation.controller=ltv_mpc",
            f"evaluation.seed={int(spec['seed'])}", f"evaluation.episodes={int(probe['episodes'])}",
            *probe.get("overrides", [])]


def run_probe(overrides: list[str], directory: Path, workers: int) -> None:
    """Evaluate one probe into ``directory`` (skipped when finished; resumed when interrupted)."""
    episodes = int(next(o for o in overrides if o.startswith("evaluation.episodes=")).split("=")[1])
    summary = directory / "summary.json"
    if summary.exists() and json.loads(summary.read_text()).get("episodes") == episodes:
        return
    shown = directory.relative_to(ROOT) if directory.is_relative_to(ROOT) else directory  # no machine's path
    command = [sys.executable, "-m", "srmpc", *overrides, f"evaluation.output_dir={shown}",
               f"evaluation.workers={workers}", "tracking.enabled=false",
               f"hydra.run.dir={ROOT / 'outputs/operating_point_calibration' / directory.name}"]
    print(f"probe {directory.name}: {' '.join(overrides)}", flush=True)
    environment = {**os.environ, "TQDM_DISABLE": "1"}  # no progress bars in the stage's log
    subprocess.run(command, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, env=environment)


def knobs(planner: dict) -> dict:
    """The calibrated knobs as the planner uses them."""
    return {"slack_price_scale": float(planner["slack_price_scale"]),
            "lateral_weight": float(planner["state_weights"][1]),
            "speed_weight": float(planner["state_weights"][3]),
            "safety_margin_longitudinal_m": float(planner["safety_margin_longitudinal_m"])}


def probe_row(name: str, directory: Path, resamples: int, seed: int) -> dict:
    """One CSV row: the probe's knobs (from its config.yaml), metrics with CIs, distance to the target."""
    config = yaml.safe_load((directory / "config.yaml").read_text())
    episodes = pd.read_csv(directory / "episodes.csv")
    metrics = table_metrics_with_intervals(episodes, resamples, seed)
    row = {"probe": name, "episodes": metrics["episodes"], "first_seed": int(config["evaluation"]["seed"]),
           **knobs(config["planner"])}
    for key, _, _ in METRICS:
        row[key] = metrics[key]
        row[f"{key}_ci95_low"], row[f"{key}_ci95_high"] = metrics[f"{key}_ci95"]
    row["distance_to_target"] = max(abs(row["mean_event_cost"] - TARGET_J_C) / BAND_J_C,
                                    abs(row["mean_vx"] - TARGET_VX) / BAND_VX)
    return row


def frozen_check(spec: dict, rows: pd.DataFrame, directories: dict[str, Path]) -> list[str]:
    """The frozen option's lines: its planner settings must equal its probe's."""
    frozen, probe = spec.get("frozen"), spec.get("frozen_probe")
    if not frozen or not probe:
        return ["No planner option is frozen yet (`frozen`, `frozen_probe` in the probes file)."]
    option = compose_config([f"planner={frozen}"]).planner
    probe_planner = yaml.safe_load((directories[probe] / "config.yaml").read_text())["planner"]
    option_planner = OmegaConf.to_container(option, resolve=True)
    if option_planner != probe_planner:
        raise SystemExit(f"conf/planner/{frozen}.yaml composes to {option_planner}, not probe {probe}'s "
                         f"planner {probe_planner}")
    row = rows.set_index("probe").loc[probe]
    reason = f" Why this probe: {spec['frozen_reason']}" if spec.get("frozen_reason") else ""
    return [f"Frozen: `planner={frozen}` (`conf/planner/{frozen}.yaml`) is probe `{probe}`'s planner: "
            f"slack_price_scale {row['slack_price_scale']:g}, lateral weight {row['lateral_weight']:g}, "
            f"speed weight {row['speed_weight']:g}, safety margin {row['safety_margin_longitudinal_m']:g} m "
            f"(checked: the option composes to that probe's planner settings). On its {row['episodes']:.0f} "
            f"calibration episodes: J_c {row['mean_event_cost']:.3f}, v_x {row['mean_vx']:.2f} m/s, "
            f"n_steps {row['mean_n_steps']:.0f}, J_r per step {row['mean_return_per_step']:.2f}.{reason}"]


def markdown(spec: dict, rows: pd.DataFrame, frozen_lines: list[str]) -> str:
    closest = rows.loc[rows["distance_to_target"].idxmin()]
    lines = ["# LTV-MPC calibrated to the paper's light-traffic row", "",
             f"Target (the paper's LTV-MPC, light): J_c {TARGET_J_C:.3f} ± {BAND_J_C}, v_x {TARGET_VX:.2f} ± "
             f"{BAND_VX} m/s; out of sample: n_steps {TARGET[4]:.0f}, J_r per step {TARGET[1]:.1f}, rho_c "
             f"{TARGET[3]:.4f}.", "",
             f"Every probe is LTV-MPC in {spec.get('traffic', 'light')} traffic, episode i from seed "
             f"{int(spec['seed'])} + i (the same scenes for every probe; never the table's or the "
             "confirmation's seeds). Knobs: `planner.slack_price_scale` (a common factor on the four slack "
             "prices), the lateral (`state_weights[1]`) and speed (`state_weights[3]`) weights, "
             "`planner.safety_margin_longitudinal_m`. 95% CIs: Wilson for J_c, bootstrap over episodes "
             "otherwise. distance: max(|ΔJ_c| / 0.05, |Δv_x| / 0.3), 1 or less inside both bands.", "",
             "| probe | episodes | slack scale | w_y | w_v | margin [m] | J_c | v_x [m/s] | n_steps | "
             "J_r per step | rho_c | distance |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in rows.iterrows():
        cells = [f"{r[k]:.{d}f} [{r[f'{k}_ci95_low']:.{d}f}, {r[f'{k}_ci95_high']:.{d}f}]" for k, _, d in METRICS]
        lines.append(f"| {r['probe']} | {r['episodes']:.0f} | {r['slack_price_scale']:g} | {r['lateral_weight']:g} "
                     f"| {r['speed_weight']:g} | {r['safety_margin_longitudinal_m']:g} | {' | '.join(cells)} | "
                     f"{r['distance_to_target']:.2f} |")
    inside = rows[rows["distance_to_target"] <= 1.0]
    lines += ["", f"Closest probe: `{closest['probe']}` (distance {closest['distance_to_target']:.2f}); "
              f"{len(inside)} of {len(rows)} probes inside both bands"
              + (f" ({', '.join(f'`{p}`' for p in inside['probe'])})." if len(inside) else "."), "",
              *frozen_lines, ""]
    return "\n".join(lines)


def figure(rows: pd.DataFrame, path: Path, frozen_probe: str | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    ax.add_patch(plt.Rectangle((TARGET_VX - BAND_VX, TARGET_J_C - BAND_J_C), 2 * BAND_VX, 2 * BAND_J_C,
                               color="tab:red", alpha=0.15, label="target band"))
    ax.plot(TARGET_VX, TARGET_J_C, "o", mfc="none", color="tab:red", ms=10, label="paper's LTV-MPC (light)")
    for _, r in rows.iterrows():
        ax.errorbar(r["mean_vx"], r["mean_event_cost"],
                    xerr=[[r["mean_vx"] - r["mean_vx_ci95_low"]], [r["mean_vx_ci95_high"] - r["mean_vx"]]],
                    yerr=[[r["mean_event_cost"] - r["mean_event_cost_ci95_low"]],
                          [r["mean_event_cost_ci95_high"] - r["mean_event_cost"]]],
                    fmt="o", ms=4, color="tab:blue", alpha=0.7, lw=0.8)
        ax.annotate(r["probe"], (r["mean_vx"], r["mean_event_cost"]), fontsize=6, xytext=(3, 3),
                    textcoords="offset points")
    if frozen_probe in set(rows["probe"]):
        r = rows.set_index("probe").loc[frozen_probe]
        ax.plot(r["mean_vx"], r["mean_event_cost"], "*", color="tab:orange", ms=14, zorder=5,
                label=f"frozen: {frozen_probe}")
    ax.set_xlabel("mean v_x [m/s]")
    ax.set_ylabel("J_c (share of episodes with a collision or road exit)")
    ax.set_title("LTV-MPC, light traffic: calibration probes (seeds 200000 + i)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--probes", type=Path, default=PROBES, help="the probes file (YAML)")
    parser.add_argument("--output", type=Path, default=OUTPUT, help="where calibration.{csv,md} and probes/ go")
    parser.add_argument("--figure", type=Path, default=FIGURE, help="the probes' J_c against v_x (PNG)")
    parser.add_argument("--workers", type=int, default=1, help="evaluation.workers of each probe")
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args(argv)
    spec = read_probes(args.probes)
    directories = {p["name"]: args.output / "probes" / p["name"] for p in spec["probes"]}
    for probe in spec["probes"]:
        run_probe(probe_overrides(spec, probe), directories[probe["name"]], args.workers)
    rows = pd.DataFrame([probe_row(p["name"], directories[p["name"]], args.resamples, args.seed)
                         for p in spec["probes"]])
    text = markdown(spec, rows, frozen_check(spec, rows, directories))
    args.output.mkdir(parents=True, exist_ok=True)
    write_outputs({args.output / "calibration.csv": rows.to_csv(index=False, float_format="%.6g"),
                   args.output / "calibration.md": text})
    figure(rows, args.figure, spec.get("frozen_probe"))
    print(text)


if __name__ == "__main__":
    main()
