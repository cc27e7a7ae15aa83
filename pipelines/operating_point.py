"""DVC stage ``operating_point``: the paper's table at the calibrated planner (``planner=paper_operating_point``).

    python -m pipelines.operating_point

``conf/planner/paper_operating_point.yaml`` was calibrated on LTV-MPC in light traffic only, on seeds 200000 + i
(``results/operating_point/calibration.md``), to the paper's light LTV-MPC row. At that planner, on the table's
episodes (episode i from seed i, 1000 per cell), this stage reads

- ``results/evaluation/twin/<method>_paper_operating_point_<traffic>/`` for LTV-MPC, SRMPC (Algorithm 1) and
  SRMPC tracking the rollout (DVC stage ``evaluate_planner_variant@paper_operating_point-*``), and
- ``results/evaluation/twin/ppo_lsi_<traffic>/``: PPO-L-SI, the table's own evaluation (it has no planner),

and writes

- ``results/operating_point.json``: ``[traffic][method]`` the table metrics with 95% CIs (as ``table.json``), the
  paper's value of each and its ``verdicts`` (the published number inside our CI, above it or below it), the
  ``paired_differences`` of SRMPC against LTV-MPC and PPO-L-SI; ``claims``: each claim of the paper's Results
  section as holds / fails / not shown, with its evidence; ``fitted``: which numbers the calibration fitted;
- ``results/operating_point.md``: the same as tables and sentences.

Verdict of a published number x against our 95% CI [low, high]: ``inside`` when low <= x <= high, ``above``
when x > high (the paper's number is higher than ours), ``below`` when x < low.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd
import yaml
from omegaconf import OmegaConf

from pipelines.reporting import (
    PAPER,
    by_method,
    ci,
    difference,
    evaluations,
    method_row,
    settings_of,
    sign,
    write_outputs,
)
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences
from srmpc.config.compose import compose_config

TWIN = Path("results/evaluation/twin")
TRADEOFF = Path("results/evaluation/tradeoff")
CALIBRATION = Path("results/operating_point/calibration.csv")
PROBES = Path("pipelines/operating_point_probes.yaml")
PLANNER = "paper_operating_point"
TRAFFIC = ("light", "dense")
METHODS = {"ppo_lsi": "PPO-L-SI (the table's own run)", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC (Algorithm 1)",
           "srmpc_track_rollout": "SRMPC, tracking the rollout (ours)"}
"""Method -> label. Each planner method's folder is found by its config.yaml: the table's seeds on the twin at
``planner=paper_operating_point``'s settings; PPO-L-SI's is the table's own run."""
SHORT = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC", "srmpc_track_rollout": "SRMPC (track)"}
PUBLISHED = {"mean_return_per_step": 1, "mean_event_cost": 2, "cost_rate": 3, "mean_n_steps": 4, "mean_vx": 5}
"""Table metric -> its index in ``paper_table.PAPER``'s rows."""
LABELS = {"mean_return_per_step": ("J_r per step", 2), "mean_event_cost": ("J_c", 3), "cost_rate": ("rho_c", 4),
          "mean_n_steps": ("n_steps", 0), "mean_vx": ("v_x [m/s]", 2)}
FITTED = {("light", "ltv_mpc", "mean_event_cost"), ("light", "ltv_mpc", "mean_vx")}
"""The numbers the calibration aimed at (on seeds 200000 + i); every other number here is a prediction."""
OUT_OF_SAMPLE_CHECKS = {("light", "ltv_mpc", k) for k in ("mean_n_steps", "mean_return_per_step", "cost_rate")}
"""Not fitted, named by the issue as the calibration's first out-of-sample checks."""
STRETCH = {"light": (0.215, 24.63), "dense": (0.353, 24.47)}
"""Beat the paper's SRMPC row on both axes: J_c below and v_x above these."""
CUTS = (("ppo_lsi", 0.30), ("ltv_mpc", 0.65))
"""The light-traffic claim: SRMPC's J_c and rho_c more than 30% below PPO-L-SI's and 65% below LTV-MPC's."""


def folders(traffic: str) -> dict[str, Path]:
    """Method -> its evaluation folder in ``traffic``, read from each folder's config.yaml (never its name)."""
    planner = OmegaConf.to_container(compose_config([f"planner={PLANNER}"]).planner, resolve=True)
    wanted = settings_of({"planner": planner})
    found = {"ppo_lsi": by_method(TWIN)[("ppo_lsi", traffic)]}
    for directory, experiment in evaluations(TWIN, TRADEOFF):
        if (experiment["traffic"], experiment["seed"], experiment["simulator"]) == (traffic, 0, "twin") and \
                experiment["settings"] == wanted and experiment["method"] in METHODS:
            found[experiment["method"]] = directory
    return found


def verdict(value: float, interval: tuple[float, float]) -> str:
    low, high = interval
    return "inside" if low <= value <= high else "above" if value > high else "below"


def role(traffic: str, method: str, key: str) -> str:
    if (traffic, method, key) in FITTED:
        return "fitted"
    if (traffic, method, key) in OUT_OF_SAMPLE_CHECKS:
        return "predicted (first out-of-sample check)"
    return "predicted" if method != "ppo_lsi" else "no planner (the table's run)"


def three_way(signs: list[int], want: int) -> str:
    """holds when every CI is on the claimed side, fails when any is on the other, else not shown."""
    if all(s == want for s in signs):
        return "holds"
    return "fails" if any(s == -want for s in signs) else "not shown (a CI contains 0)"


def lower(cut: float) -> str:
    """A relative reduction in words: "80% lower", or "103% higher" for a negative one."""
    return f"{abs(cut):.0%} {'lower' if cut >= 0 else 'higher'}"


def claims(rows: dict, traffic: str) -> list[dict]:
    """The Results section's claims at this planner, from the paired differences (same seeds)."""
    s, out = rows["srmpc"], []
    d = s["paired_differences"]
    signs = [sign(d[m]["mean_event_cost_ci95"]) for m in ("ltv_mpc", "ppo_lsi")]
    out.append({"traffic": traffic, "claim": "SRMPC has the lowest J_c (below LTV-MPC and PPO-L-SI)",
                "verdict": three_way(signs, -1),
                "evidence": "; ".join(f"SRMPC - {SHORT[m]}: ΔJ_c {difference(d[m], 'mean_event_cost', 3)}"
                                      for m in ("ltv_mpc", "ppo_lsi"))})
    ltv = rows["ltv_mpc"]["mean_event_cost"]
    out.append({"traffic": traffic, "claim": f"SRMPC cuts J_c against LTV-MPC by "
                f"{1 - PAPER[(traffic, 'srmpc')][2] / PAPER[(traffic, 'ltv_mpc')][2]:.0%} (the paper's table)",
                "verdict": "ours: " + (f"{1 - s['mean_event_cost'] / ltv:.0%}" if ltv else "n/a (LTV-MPC J_c 0)"),
                "evidence": f"J_c {s['mean_event_cost']:.3f} vs {ltv:.3f}"})
    if traffic == "light":
        signs, parts = [], []
        for m in ("ppo_lsi", "ltv_mpc"):
            for key, name, digits in (("mean_return", "J_r", 0), ("mean_vx", "v_x", 2)):
                signs.append(sign(d[m][f"{key}_ci95"]))
                parts.append(f"{name} SRMPC - {SHORT[m]}: {difference(d[m], key, digits)}")
        out.append({"traffic": traffic, "claim": "SRMPC reaches a higher return and a higher average velocity than "
                    "PPO-L-SI and LTV-MPC", "verdict": three_way(signs, +1), "evidence": "; ".join(parts)})
        for m, threshold in CUTS:
            cuts = {k: (1 - s[k] / rows[m][k]) if rows[m][k] else float("nan")
                    for k in ("mean_event_cost", "cost_rate")}
            holds = all(c > threshold for c in cuts.values())
            out.append({"traffic": traffic, "claim": f"SRMPC's J_c and rho_c more than {threshold:.0%} below "
                        f"{SHORT[m]}'s",
                        "verdict": "holds" if holds else "fails",
                        "evidence": f"J_c {lower(cuts['mean_event_cost'])} ({s['mean_event_cost']:.3f} vs "
                                    f"{rows[m]['mean_event_cost']:.3f}; paired ΔJ_c "
                                    f"{difference(d[m], 'mean_event_cost', 3)}), rho_c {lower(cuts['cost_rate'])} "
                                    f"({s['cost_rate']:.4f} vs {rows[m]['cost_rate']:.4f})"})
    else:
        dl = d["ltv_mpc"]
        vx_sign = sign(dl["mean_vx_ci95"])  # SRMPC - LTV-MPC; the claim: LTV-MPC slightly better or comparable
        holds = vx_sign <= 0 and -dl["mean_vx"] < 1.0
        out.append({"traffic": traffic, "claim": "LTV-MPC is slightly better in performance (return per step, speed), "
                    "but comparable", "verdict": "holds" if holds else "fails",
                    "evidence": f"LTV-MPC - SRMPC: v_x {difference(dl, 'mean_vx', 2, negate=True)} m/s, J_r "
                                f"{difference(dl, 'mean_return', 0, negate=True)}; J_r per step "
                                f"{rows['ltv_mpc']['mean_return_per_step']:.2f} vs {s['mean_return_per_step']:.2f} "
                                "(rule: holds when LTV-MPC is not shown slower and is at most 1 m/s faster)"})
    for m in ("srmpc", "srmpc_track_rollout"):
        j_c, vx = STRETCH[traffic]
        r = rows[m]
        met = r["mean_event_cost"] < j_c and r["mean_vx"] > vx
        out.append({"traffic": traffic, "claim": f"Stretch: {METHODS[m]} beats the paper's SRMPC row on both axes "
                    f"(J_c < {j_c}, v_x > {vx})", "verdict": "met" if met else "not met",
                    "evidence": f"J_c {r['mean_event_cost']:.3f}, v_x {r['mean_vx']:.2f}"})
    return out


def frozen_probe() -> dict | None:
    """The calibration's row of the frozen probe (``frozen_probe`` of the probes file)."""
    if not CALIBRATION.exists():
        return None
    name = yaml.safe_load(PROBES.read_text()).get("frozen_probe")
    rows = pd.read_csv(CALIBRATION).set_index("probe")
    if name not in rows.index:
        return None
    return {"probe": name, **{k: (v.item() if hasattr(v, "item") else v) for k, v in rows.loc[name].items()}}


def markdown(result: dict) -> str:
    lines = ["# The paper's table at the calibrated planner (`planner=paper_operating_point`)", "",
             "`conf/planner/paper_operating_point.yaml` (slack prices x0.05, speed weight 10, 1 m safety margin) was "
             "calibrated on LTV-MPC in light traffic only, on seeds 200000 + i "
             "(`results/operating_point/calibration.md`), aiming at the paper's light LTV-MPC row (J_c 0.625, v_x "
             "24.38 m/s). It fits J_c, not v_x: no setting of the three knobs reached the paper's point. "
             "Fitted: LTV-MPC light J_c and v_x; first out-of-sample checks: its n_steps, J_r per step and rho_c; "
             "every other planner cell is a prediction. Below: 1000 episodes per cell on the table's seeds (episode "
             "i from seed i, every method the same scenes); 95% CIs (Wilson for J_c, bootstrap over episodes "
             "otherwise); verdict: where the paper's number lies against our CI.", ""]
    probe = result.get("calibration_probe")
    if probe:
        lines += [f"On the calibration seeds (probe `{probe['probe']}`, {probe['episodes']:.0f} episodes): LTV-MPC "
                  f"light J_c {probe['mean_event_cost']:.3f}, v_x {probe['mean_vx']:.2f} m/s, n_steps "
                  f"{probe['mean_n_steps']:.0f}, J_r per step {probe['mean_return_per_step']:.2f}.", ""]
    for traffic in TRAFFIC:
        rows = result[traffic]
        lines += [f"## {traffic} traffic", "",
                  "| method | " + " | ".join(f"{LABELS[k][0]} ours | paper | verdict" for k in PUBLISHED) + " |",
                  "|---|" + "---|---|---|" * len(PUBLISHED)]
        for method, r in rows.items():
            cells = []
            for key in PUBLISHED:
                published = r.get("paper", {}).get(key)
                mark = " (fitted)" if (traffic, method, key) in FITTED else ""
                cells += [ci(r, key, LABELS[key][1]) + mark, "–" if published is None else f"{published:g}",
                          r.get("verdicts", {}).get(key, "–")]
            lines.append(f"| {METHODS[method]} | " + " | ".join(cells) + " |")
        lines += ["", "Paired differences on the same seeds (mean [95% CI]):", "",
                  "| difference | J_r | J_c | n_steps | v_x [m/s] |", "|---|---|---|---|---|"]
        for other, d in rows["srmpc"]["paired_differences"].items():
            lines.append(f"| SRMPC - {SHORT[other]} | {difference(d, 'mean_return', 0)} | "
                         f"{difference(d, 'mean_event_cost', 3)} | {difference(d, 'mean_n_steps', 0)} | "
                         f"{difference(d, 'mean_vx', 2)} |")
        lines += ["", "The paper's claims at this planner:", ""]
        lines += [f"- {c['claim']}: **{c['verdict']}**. {c['evidence']}." for c in result["claims"]
                  if c["traffic"] == traffic]
        lines.append("")
    counts = {v: 0 for v in ("inside", "above", "below")}
    for traffic in TRAFFIC:
        for method in ("ltv_mpc", "srmpc"):
            for v in result[traffic][method]["verdicts"].values():
                counts[v] += 1
    lines += [f"Of the 20 published numbers of the four planner cells, {counts['inside']} lie inside our 95% CI, "
              f"{counts['above']} above it and {counts['below']} below it.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    result: dict = {"planner": PLANNER, "fitted": sorted("/".join(f) for f in FITTED), "claims": []}
    for traffic in TRAFFIC:
        rows, frames = {}, {}
        found = folders(traffic)
        for method in METHODS:
            if method not in found:
                raise SystemExit(f"operating_point: no finished {method} evaluation in {traffic} traffic at "
                                 f"planner={PLANNER} under {TRADEOFF} (run its DVC stage first)")
            directory = found[method]
            rows[method], frames[method] = method_row(directory, args.resamples, args.seed)
            rows[method]["directory"] = str(directory)
            if (traffic, method) in PAPER:
                published = PAPER[(traffic, method)]
                rows[method]["paper"] = {k: published[i] for k, i in PUBLISHED.items()}
                rows[method]["verdicts"] = {k: verdict(published[i], rows[method][f"{k}_ci95"])
                                            for k, i in PUBLISHED.items()}
                rows[method]["roles"] = {k: role(traffic, method, k) for k in PUBLISHED}
        for method in ("srmpc", "srmpc_track_rollout"):
            rows[method]["paired_differences"] = {
                other: paired_differences(frames[method], frames[other], args.resamples, args.seed)
                for other in ("ltv_mpc", "ppo_lsi")}
        result[traffic] = rows
        result["claims"] += claims(rows, traffic)
    result["calibration_probe"] = frozen_probe()
    text = markdown(result)
    write_outputs({Path("results/operating_point.md"): text,
                   Path("results/operating_point.json"): json.dumps(result, indent=2) + "\n"})
    print(text)


if __name__ == "__main__":
    main()
