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
(its ``summary.json`` counts the probe's episodes) is never rerun, an interrupted one resumes.

The distance of a probe to the paper's point, in units of the target band (1 or less: inside both bands):

    d = max(|J_c - 0.625| / 0.05, |v_x - 24.38| / 0.3 m/s).

The declared rule freezes the probe of least d. The frozen option was chosen by another rule, among the probes
with J_c inside its band (|J_c - 0.625| <= 0.05); the probes file's ``selection`` tells when each was written.
J_r per step is the paper's statistic, mean J_r / mean n_steps; rho_c = sum J_c / sum n_steps.

Writes, one row per probe in the file's order:

- ``results/operating_point/calibration.csv``: the probe's knobs (the effective planner values), J_c, v_x,
  n_steps, J_r per step, rho_c, each with its 95% CI (Wilson for J_c, bootstrap over episodes otherwise, as
  ``results/table.md``), and d;
- ``results/operating_point/calibration.md``: the same as a table, the target, how the frozen option was chosen
  (the declared rule, the rule used, their commits and what each selects on these rows), and the two options
  checked against their probes (``frozen`` / ``frozen_probe`` and ``declared_rule_option`` /
  ``declared_rule_probe`` of the probes file: ``conf/planner/<option>.yaml`` must compose to the probe's planner);
- ``results/figures/operating_point_calibration.png``: J_c against v_x of every probe, with the target; labelled
  are the frozen probe, the declared rule's probe and the probes with J_c in its band, the rest listed in the md.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
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
           ("return_per_step", "J_r per step", 2), ("cost_rate", "rho_c", 4))
"""CSV column, label, decimals. ``return_per_step`` is mean J_r / mean n_steps (the paper's statistic)."""


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
    return [f"scenario={spec.get('traffic', 'light')}", "controller=ltv_mpc",
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


def in_band(rows: pd.DataFrame) -> pd.DataFrame:
    """The probes with J_c inside its band (|J_c - 0.625| <= 0.05): those the rule used chose among."""
    return rows[(rows["mean_event_cost"] - TARGET_J_C).abs() <= BAND_J_C + 1e-9]


def selections(rows: pd.DataFrame) -> dict[str, str]:
    """Rule -> the probe it selects on ``rows``: the declared rule (the least distance) and the two restrictions
    to the probes with J_c in its band that the frozen option was chosen by (the closest, the fastest)."""
    chosen = {"declared: the closest by the distance": rows.loc[rows["distance_to_target"].idxmin(), "probe"]}
    band = in_band(rows)
    if len(band):
        chosen["used, written with the freeze: the closest with J_c in its band"] = \
            band.loc[band["distance_to_target"].idxmin(), "probe"]
        chosen["used, restated after the predictions: the fastest with J_c in its band"] = \
            band.loc[band["mean_vx"].idxmax(), "probe"]
    return chosen


def option_lines(spec: dict, rows: pd.DataFrame, directories: dict[str, Path], role: str) -> list[str]:
    """The line of the ``frozen`` or ``declared_rule`` option: its planner settings must equal its probe's."""
    option_key, probe_key = ("frozen", "frozen_probe") if role == "frozen" else ("declared_rule_option",
                                                                                  "declared_rule_probe")
    option, probe = spec.get(option_key), spec.get(probe_key)
    if not option or not probe:
        return [f"No `{option_key}` / `{probe_key}` in the probes file."]
    if probe not in directories:
        raise SystemExit(f"probes file: {probe_key}={probe}: no such probe")
    option_planner = OmegaConf.to_container(compose_config([f"planner={option}"]).planner, resolve=True)
    probe_planner = yaml.safe_load((directories[probe] / "config.yaml").read_text())["planner"]
    if option_planner != probe_planner:
        raise SystemExit(f"conf/planner/{option}.yaml composes to {option_planner}, not probe {probe}'s "
                         f"planner {probe_planner}")
    row = rows.set_index("probe").loc[probe]
    what = "Frozen" if role == "frozen" else "The declared rule's probe, run as its own option"
    return [f"{what}: `planner={option}` (`conf/planner/{option}.yaml`) is probe `{probe}`'s planner: "
            f"slack_price_scale {row['slack_price_scale']:g}, lateral weight {row['lateral_weight']:g}, "
            f"speed weight {row['speed_weight']:g}, safety margin {row['safety_margin_longitudinal_m']:g} m "
            f"(checked: the option composes to that probe's planner settings). On its {row['episodes']:.0f} "
            f"calibration episodes: J_c {row['mean_event_cost']:.3f}, v_x {row['mean_vx']:.2f} m/s, "
            f"n_steps {row['mean_n_steps']:.0f}, J_r per step {row['return_per_step']:.2f}, distance "
            f"{row['distance_to_target']:.2f}."]


def selection_lines(spec: dict, rows: pd.DataFrame, directories: dict[str, Path]) -> list[str]:
    """How the frozen option was chosen: the rules, when each was written (the probes file's ``selection``),
    what each selects on these rows, and the two options checked against their probes."""
    lines = ["## How the operating point was chosen", "",
             "The declared rule: freeze the probe closest to the paper's point by the distance. The rule used: "
             "the closest *with J_c in its band*, written with the freeze, restated as the fastest with J_c in its "
             "band after the predictions were committed. Both restrictions came after the probes were "
             "seen: the choice is post hoc, though it used the calibration seeds only. When the option was frozen "
             f"the declared rule selected `{spec.get('declared_rule_probe')}`, run as its own option "
             f"`planner={spec.get('declared_rule_option')}`; both options run through the same six cells "
             "(`results/operating_point.md`).", "",
             "| commit | time (UTC) | rule | what was written |", "|---|---|---|---|"]
    for entry in spec.get("selection", []):
        commit = f"`{entry['commit']}`" if entry.get("commit") else "–"
        text = " ".join(str(entry["text"]).split()).replace("|", "\\|")  # a table cell: | escaped
        lines.append(f"| {commit} | {entry['time']} | {entry['rule']} | {text} |")
    by_name = rows.set_index("probe")
    lines += ["", "On the rows above (the warm-started planner's, not the rows of the freeze):", ""]
    for rule, probe in selections(rows).items():
        r = by_name.loc[probe]
        lines.append(f"- {rule}: `{probe}` (distance {r['distance_to_target']:.2f}; J_c {r['mean_event_cost']:.3f}, "
                     f"v_x {r['mean_vx']:.2f} m/s, {r['episodes']:.0f} episodes)")
    band = in_band(rows)
    lines += ["", f"Probes with J_c in its band ({TARGET_J_C - BAND_J_C:.3f}-{TARGET_J_C + BAND_J_C:.3f}): "
              + (", ".join(f"`{p}`" for p in band["probe"]) or "none") + ".", ""]
    for role in ("frozen", "declared_rule"):
        lines += [*option_lines(spec, rows, directories, role), ""]
    return lines


def labelled_probes(rows: pd.DataFrame, spec: dict) -> list[str]:
    """The probes the figure names: the frozen one, the declared rule's, those with J_c in its band, and those the
    probes file's ``selection`` names."""
    told = " ".join(str(entry.get("text", "")) for entry in spec.get("selection", []))
    wanted = {spec.get("frozen_probe"), spec.get("declared_rule_probe"), *in_band(rows)["probe"]}
    wanted |= {p for p in rows["probe"] if re.search(rf"(?<![\w.-]){re.escape(p)}(?![\w.-])", told)}
    return [p for p in rows["probe"] if p in wanted]


def markdown(spec: dict, rows: pd.DataFrame, selection: list[str], labelled: list[str]) -> str:
    closest = rows.loc[rows["distance_to_target"].idxmin()]
    lines = ["# LTV-MPC calibrated to the paper's light-traffic row", "",
             f"Target (the paper's LTV-MPC, light): J_c {TARGET_J_C:.3f} ± {BAND_J_C}, v_x {TARGET_VX:.2f} ± "
             f"{BAND_VX} m/s; out of sample: n_steps {TARGET[4]:.0f}, J_r per step {TARGET[1]:.1f} (its mean J_r "
             f"/ mean n_steps); rho_c {TARGET[3]:.4f} is J_c / n_steps, no check of its own.", "",
             f"Every probe is LTV-MPC in {spec.get('traffic', 'light')} traffic, episode i from seed "
             f"{int(spec['seed'])} + i (the same scenes for every probe; never the table's or the "
             "confirmation's seeds). Knobs: `planner.slack_price_scale` (a common factor on the four slack "
             "prices), the lateral (`state_weights[1]`) and speed (`state_weights[3]`) weights, "
             "`planner.safety_margin_longitudinal_m`. J_r per step: mean J_r / mean n_steps; rho_c: sum J_c / "
             "sum n_steps. 95% CIs: Wilson for J_c, bootstrap over episodes otherwise. distance: max(|ΔJ_c| / "
             "0.05, |Δv_x| / 0.3), 1 or less inside both bands.", "",
             "| probe | episodes | slack scale | w_y | w_v | margin [m] | J_c | v_x [m/s] | n_steps | "
             "J_r per step | rho_c | distance |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in rows.iterrows():
        cells = [f"{r[k]:.{d}f} [{r[f'{k}_ci95_low']:.{d}f}, {r[f'{k}_ci95_high']:.{d}f}]" for k, _, d in METRICS]
        lines.append(f"| {r['probe']} | {r['episodes']:.0f} | {r['slack_price_scale']:g} | {r['lateral_weight']:g} "
                     f"| {r['speed_weight']:g} | {r['safety_margin_longitudinal_m']:g} | {' | '.join(cells)} | "
                     f"{r['distance_to_target']:.2f} |")
    inside = rows[rows["distance_to_target"] <= 1.0]
    unlabelled = [p for p in rows["probe"] if p not in labelled]
    lines += ["", f"Closest probe: `{closest['probe']}` (distance {closest['distance_to_target']:.2f}); "
              f"{len(inside)} of {len(rows)} probes inside both bands"
              + (f" ({', '.join(f'`{p}`' for p in inside['probe'])})." if len(inside) else "."), "",
              *selection,
              "The figure (`results/figures/operating_point_calibration.png`) names "
              + ", ".join(f"`{p}`" for p in labelled) + "; unnamed there: "
              + (", ".join(f"`{p}`" for p in unlabelled) or "none") + ".", ""]
    return "\n".join(lines)


def place_labels(fig, ax, points: list[tuple[str, float, float]], obstacles: list[tuple[float, float]]) -> None:
    """Name each point once, with a leader line, at the nearest offset whose text box stays inside the axes and
    overlaps no placed name, no probe marker and not the legend."""
    renderer = fig.canvas.get_renderer()
    pixels = ax.transData.transform(obstacles)
    taken: list = []
    offsets = [(r * math.cos(math.radians(a)), r * math.sin(math.radians(a)))
               for r in (22, 40, 60, 85, 110, 140, 170) for a in range(-30, 330, 20)]
    for name, x, y in points:
        for dx, dy in offsets:
            style = {"xytext": (dx, dy), "textcoords": "offset points", "fontsize": 7.5, "va": "center",
                     "ha": "left" if dx > 1 else "right" if dx < -1 else "center",
                     "bbox": {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.7", "lw": 0.5}}
            text = ax.annotate(name, (x, y), **style)  # without its leader line: the box of the text alone
            box = text.get_window_extent(renderer).expanded(1.08, 1.3)
            text.remove()
            clear = (ax.bbox.contains(box.x0, box.y0) and ax.bbox.contains(box.x1, box.y1)
                     and not any(box.overlaps(other) for other in taken)
                     and not any(box.contains(px, py) for px, py in pixels))
            if clear or (dx, dy) == offsets[-1]:
                ax.annotate(name, (x, y), **style, arrowprops={"arrowstyle": "-", "color": "0.4", "lw": 0.6,
                                                               "shrinkB": 3})
                taken.append(box)
                break


def draw_probes(ax, rows: pd.DataFrame, spec: dict) -> None:
    """The target, the bands, every probe with its 95% CIs, the frozen and the declared rule's probe marked."""
    import matplotlib.pyplot as plt

    ax.axhspan(TARGET_J_C - BAND_J_C, TARGET_J_C + BAND_J_C, color="tab:red", alpha=0.06,
               label="J_c band (the rule used chose among these)")
    ax.add_patch(plt.Rectangle((TARGET_VX - BAND_VX, TARGET_J_C - BAND_J_C), 2 * BAND_VX, 2 * BAND_J_C,
                               color="tab:red", alpha=0.18, label="target band (J_c and v_x)"))
    ax.plot(TARGET_VX, TARGET_J_C, "o", mfc="none", color="tab:red", ms=10, label="paper's LTV-MPC (light)")
    for _, r in rows.iterrows():
        ax.errorbar(r["mean_vx"], r["mean_event_cost"],
                    xerr=[[r["mean_vx"] - r["mean_vx_ci95_low"]], [r["mean_vx_ci95_high"] - r["mean_vx"]]],
                    yerr=[[r["mean_event_cost"] - r["mean_event_cost_ci95_low"]],
                          [r["mean_event_cost_ci95_high"] - r["mean_event_cost"]]],
                    fmt="o", ms=3.5, color="tab:blue", alpha=0.4, lw=0.6)
    by_name = rows.set_index("probe")
    for key, marker, colour, what in (("frozen_probe", "*", "tab:orange", "frozen (the rule used)"),
                                      ("declared_rule_probe", "D", "tab:green", "the declared rule's probe")):
        name = spec.get(key)
        if name in by_name.index:
            r = by_name.loc[name]
            ax.plot(r["mean_vx"], r["mean_event_cost"], marker, color=colour, ms=13 if marker == "*" else 8,
                    zorder=5, mec="black", mew=0.5, label=f"{what}: {name}")


def figure(rows: pd.DataFrame, path: Path, spec: dict, labelled: list[str]) -> None:
    """Left: every probe. Right: the J_c band's neighbourhood, where the labelled probes are named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (whole, zoom) = plt.subplots(1, 2, figsize=(13, 5.5), dpi=120, gridspec_kw={"width_ratios": [1, 1.15]})
    by_name = rows.set_index("probe")
    named = by_name.loc[labelled]
    vx = list(named["mean_vx"]) or [TARGET_VX]  # no probe named: the window around the target
    j_c = list(named["mean_event_cost"])
    x_range = (min(vx) - 0.3, max(vx) + 0.3)
    y_range = (min([*j_c, TARGET_J_C - BAND_J_C]) - 0.04, max([*j_c, TARGET_J_C + BAND_J_C]) + 0.05)
    for ax in (whole, zoom):
        draw_probes(ax, rows, spec)
        ax.set_xlabel("mean v_x [m/s]")
    whole.add_patch(plt.Rectangle((x_range[0], y_range[0]), x_range[1] - x_range[0], y_range[1] - y_range[0],
                                  fill=False, ec="0.3", lw=0.8, ls="--", label="the right panel"))
    whole.set_ylabel("J_c (share of episodes with a collision or road exit)")
    whole.set_title("LTV-MPC, light traffic: every calibration probe (seeds 200000 + i)", fontsize=10)
    whole.legend(loc="upper left", fontsize=7.5)
    zoom.set_ylabel("J_c")
    zoom.set_xlim(*x_range)
    zoom.set_ylim(*y_range)
    zoom.set_title("Near the J_c band: the probes the text names (95% CIs)", fontsize=10)
    fig.tight_layout()
    points = [(p, r["mean_vx"], r["mean_event_cost"]) for p, r in named.iterrows()]
    place_labels(fig, zoom, points, list(zip(rows["mean_vx"], rows["mean_event_cost"], strict=True)))
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
    labelled = labelled_probes(rows, spec)
    text = markdown(spec, rows, selection_lines(spec, rows, directories), labelled)
    args.output.mkdir(parents=True, exist_ok=True)
    write_outputs({args.output / "calibration.csv": rows.to_csv(index=False, float_format="%.6g"),
                   args.output / "calibration.md": text})
    figure(rows, args.figure, spec, labelled)
    print(text)


if __name__ == "__main__":
    main()
