"""DVC stage ``operating_point``: the paper's table at the two calibrated planners, the frozen one and the declared
rule's probe.

    python -m pipelines.operating_point

Both options come from the calibration on LTV-MPC in light traffic, seeds 200000 + i
(``results/operating_point/calibration.md``, stage ``operating_point_calibration``), aimed at the paper's light
LTV-MPC row (J_c 0.625 +- 0.05, v_x 24.38 +- 0.3 m/s):

- ``planner=paper_operating_point``, the frozen option: the closest probe with J_c in its band, a rule written with
  the freeze, after the probes were seen;
- ``planner=declared_rule_probe``: the probe the rule declared before (the closest by the distance) selected then.

At each, on the table's episodes (episode i from seed i, 1000 per cell), this stage reads

- LTV-MPC, SRMPC (Algorithm 1) and SRMPC tracking the rollout: at the frozen option experiment
  ``operating_point/<method>``, at the declared rule's probe ``operating_point/<method>_declared_rule_probe``
  (``results/evaluation/<experiment>_<traffic>/``, DVC stage ``evaluate@<experiment>-<traffic>``), each folder
  found by the experiment its config.yaml names, never its name;
- experiment ``table/ppo_lsi``: PPO-L-SI, the table's own evaluation (it has no planner),

and writes

- ``results/operating_point.json``: for the frozen option, ``[traffic][method]`` the table metrics with 95% CIs
  (as ``table.json``), the paper's value of each, its ``verdicts`` and ``roles``, the ``paired_differences`` of
  SRMPC against LTV-MPC and PPO-L-SI and, for LTV-MPC in light traffic, ``calibration_band``; ``claims``: each
  claim of the paper's Results section as holds / fails / not shown, with its evidence; ``verdict_counts``;
  ``calibration_probe``: the option's row on the calibration seeds. ``declared_rule_probe`` holds the same for
  the declared rule's probe;
- ``results/operating_point.md``: the same as tables and sentences.

Statistics. J_r per step is the paper's: ``return_per_step`` = mean J_r / mean n_steps (light LTV-MPC: -1241 / 244
= -5.1), its CI the bootstrap of the ratio of means; the mean of per-episode ratios (``mean_return_per_step``) is
kept in the JSON and named as such. rho_c = sum J_c / sum n_steps = mean J_c / mean n_steps follows from J_c and
n_steps, so it is counted as no check of its own.

Verdict of a published number x against our 95% CI [low, high]: ``inside`` when low <= x <= high, ``above`` when
x > high (the paper's number is higher than ours), ``below`` when x < low. A calibration target t with band
half-width h against our CI: ``within the band`` when t - h <= low and high <= t + h, ``outside the band`` when
the CI misses [t - h, t + h], ``not shown within the band`` when the CI crosses one of its edges.

Claims rest on CIs over the same seeds: a paired difference (``paired_differences``) is shown when its CI excludes
0; a cut 1 - a / b of J_c or rho_c (``paired_ratios``: the bootstrap of sum(a) / sum(b) over episode pairs) holds
against a threshold when its whole CI lies above it and fails when its whole CI lies below; the stretch is met when
the CIs of J_c and v_x both clear the paper's values, not met when either lies wholly on the wrong side; anything
between is "not shown".
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd
import yaml

from pipelines.reporting import (
    PAPER,
    ci,
    cut_with_ci,
    difference,
    method_row,
    run_of,
    sign,
    write_outputs,
)
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences, paired_ratios

CALIBRATION = Path("results/operating_point/calibration.csv")
PROBES = Path("pipelines/operating_point_probes.yaml")
PLANNER = "paper_operating_point"
DECLARED_PLANNER = "declared_rule_probe"
PLANNERS = {PLANNER: ("frozen", "frozen_probe", "the frozen option (the rule used: the closest with J_c in its band)"),
            DECLARED_PLANNER: ("declared rule", "declared_rule_probe",
                               "the declared rule's probe (the closest by the distance when the option was frozen)")}
"""Planner option -> short name, its probe's key in the probes file, what it is."""
TRAFFIC = ("light", "dense")
METHODS = {"ppo_lsi": "PPO-L-SI (the table's own run)", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC (Algorithm 1)",
           "srmpc_track_rollout": "SRMPC, tracking the rollout (ours)"}
"""Method -> label. A planner method's run at option ``paper_operating_point`` is experiment
``operating_point/<method>``, at ``declared_rule_probe`` ``operating_point/<method>_declared_rule_probe``;
PPO-L-SI's is the table's own run (``table/ppo_lsi``)."""
SHORT = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC", "srmpc_track_rollout": "SRMPC (track)"}
PUBLISHED = {"return_per_step": 1, "mean_event_cost": 2, "cost_rate": 3, "mean_n_steps": 4, "mean_vx": 5}
"""Table metric -> its index in ``reporting.PAPER``'s rows."""
LABELS = {"return_per_step": ("J_r per step", 2), "mean_event_cost": ("J_c", 3), "cost_rate": ("rho_c", 4),
          "mean_n_steps": ("n_steps", 0), "mean_vx": ("v_x [m/s]", 2)}
TARGETS = {"mean_event_cost": 0.05, "mean_vx": 0.3}
"""The calibration's targets on LTV-MPC in light traffic, metric -> half-width of its band (J_c; v_x in m/s)."""
OUT_OF_SAMPLE_CHECKS = {("light", "ltv_mpc", k) for k in ("mean_n_steps", "return_per_step")}
"""Not aimed at, named as the calibration's first out-of-sample checks."""
STRETCH = {"light": (0.215, 24.63), "dense": (0.353, 24.47)}
"""Beat the paper's SRMPC row on both axes: J_c below and v_x above these."""
CUTS = (("ppo_lsi", 0.30), ("ltv_mpc", 0.65))
"""The light-traffic claim: SRMPC's J_c and rho_c more than 30% below PPO-L-SI's and 65% below LTV-MPC's."""


def folders(planner: str, traffic: str) -> dict[str, Path]:
    """Method -> its evaluation folder in ``traffic`` at ``planner`` (:data:`METHODS`), found by its experiment."""
    suffix = "" if planner == PLANNER else f"_{planner}"
    return {method: run_of("table/ppo_lsi" if method == "ppo_lsi" else f"operating_point/{method}{suffix}", traffic)
            for method in METHODS}


def verdict(value: float, interval: tuple[float, float]) -> str:
    low, high = interval
    return "inside" if low <= value <= high else "above" if value > high else "below"


def band_verdict(target: float, half_width: float, interval: tuple[float, float]) -> str:
    """Our CI against the band target +- half_width (module doc)."""
    low, high = interval
    if target - half_width <= low and high <= target + half_width:
        return "within the band"
    if high < target - half_width or low > target + half_width:
        return "outside the band"
    return "not shown within the band"


def role(traffic: str, method: str, key: str) -> str:
    if traffic == "light" and method == "ltv_mpc" and key in TARGETS:
        return "calibration target (aimed at on seeds 200000 + i)"
    if (traffic, method, key) in OUT_OF_SAMPLE_CHECKS:
        return "predicted (first out-of-sample check)"
    if method == "ppo_lsi":
        return "no planner (the table's run)"
    if key == "cost_rate":
        return "follows from J_c and n_steps (rho_c = mean J_c / mean n_steps)"
    return "predicted"


def three_way(signs: list[int], want: int) -> str:
    """holds when every CI is on the claimed side, fails when any is on the other, else not shown."""
    if all(s == want for s in signs):
        return "holds"
    return "fails" if any(s == -want for s in signs) else "not shown (a CI contains 0)"


def cut_of(ratio: dict) -> tuple[float | None, tuple[float, float]]:
    """A relative reduction 1 - a / b and its 95% CI from ``confidence_intervals.paired_ratios``' entry (an
    unbounded ratio gives a cut of -inf at that end)."""
    low, high = ratio["ratio_ci95"]
    return (None if ratio["ratio"] is None else 1 - ratio["ratio"]), (1 - high, 1 - low)


def claims(rows: dict, traffic: str) -> list[dict]:
    """The Results section's claims at one planner, from the paired differences (same seeds)."""
    s, out = rows["srmpc"], []
    d = s["paired_differences"]
    signs = [sign(d[m]["mean_event_cost_ci95"]) for m in ("ltv_mpc", "ppo_lsi")]
    out.append({"traffic": traffic, "claim": "SRMPC has the lowest J_c (below LTV-MPC and PPO-L-SI)",
                "verdict": three_way(signs, -1),
                "evidence": "; ".join(f"SRMPC - {SHORT[m]}: ΔJ_c {difference(d[m], 'mean_event_cost', 3)}"
                                      for m in ("ltv_mpc", "ppo_lsi"))})
    ltv = rows["ltv_mpc"]["mean_event_cost"]
    paper_cut = 1 - PAPER[(traffic, "srmpc")][2] / PAPER[(traffic, "ltv_mpc")][2]
    ratio = s["paired_ratios"]["ltv_mpc"]["mean_event_cost"]
    cut, cut_ci = cut_of(ratio)
    out.append({"traffic": traffic, "claim": f"SRMPC cuts J_c against LTV-MPC by {paper_cut:.0%} (the paper's table)",
                "verdict": "n/a (LTV-MPC J_c 0)" if cut is None else
                f"ours: {cut_with_ci(ratio)}; the paper's {paper_cut:.0%} {verdict(paper_cut, cut_ci)} our CI",
                "evidence": f"J_c {s['mean_event_cost']:.3f} vs {ltv:.3f} (cut: 1 - the ratio of J_c on the same "
                            "seeds, bootstrap CI)"})
    if traffic == "light":
        signs, parts = [], []
        for m in ("ppo_lsi", "ltv_mpc"):
            for key, name, digits in (("mean_return", "J_r", 0), ("mean_vx", "v_x", 2)):
                signs.append(sign(d[m][f"{key}_ci95"]))
                parts.append(f"{name} SRMPC - {SHORT[m]}: {difference(d[m], key, digits)}")
        out.append({"traffic": traffic, "claim": "SRMPC reaches a higher return and a higher average velocity than "
                    "PPO-L-SI and LTV-MPC", "verdict": three_way(signs, +1), "evidence": "; ".join(parts)})
        for m, threshold in CUTS:
            cuts = {k: cut_of(s["paired_ratios"][m][k]) for k in ("mean_event_cost", "cost_rate")}
            bounds = [interval for _, interval in cuts.values()]
            out.append({"traffic": traffic, "claim": f"SRMPC's J_c and rho_c more than {threshold:.0%} below "
                        f"{SHORT[m]}'s",
                        "verdict": "holds" if all(low > threshold for low, _ in bounds) else
                        "fails" if any(high < threshold for _, high in bounds) else
                        "not shown (a cut's CI contains the threshold)",
                        "evidence": f"J_c cut {cut_with_ci(s['paired_ratios'][m]['mean_event_cost'])} "
                                    f"({s['mean_event_cost']:.3f} vs {rows[m]['mean_event_cost']:.3f}), rho_c cut "
                                    f"{cut_with_ci(s['paired_ratios'][m]['cost_rate'])} "
                                    f"({s['cost_rate']:.4f} vs {rows[m]['cost_rate']:.4f}); a cut is 1 - the ratio "
                                    "on the same seeds, a negative cut a rise"})
    else:
        dl = d["ltv_mpc"]
        low, high = sorted(-v for v in dl["mean_vx_ci95"])  # LTV-MPC's lead in v_x over SRMPC, its 95% CI
        out.append({"traffic": traffic, "claim": "LTV-MPC is slightly better in performance (return per step, speed), "
                    "but comparable",
                    "verdict": "fails" if high < 0 or low > 1.0 else "holds" if high < 1.0 else
                    "not shown (the CI of its lead reaches 1 m/s)",
                    "evidence": f"LTV-MPC - SRMPC: v_x {difference(dl, 'mean_vx', 2, negate=True)} m/s, J_r "
                                f"{difference(dl, 'mean_return', 0, negate=True)}; J_r per step (mean J_r / mean "
                                f"n_steps) {ci(rows['ltv_mpc'], 'return_per_step', 2)} vs "
                                f"{ci(s, 'return_per_step', 2)} (rule: holds when LTV-MPC is not shown slower and "
                                "the CI of its lead stays under 1 m/s; fails when it is shown slower or its lead's CI "
                                "lies above 1 m/s)"})
    for m in ("srmpc", "srmpc_track_rollout"):
        j_c, vx = STRETCH[traffic]
        r = rows[m]
        (j_low, j_high), (v_low, v_high) = r["mean_event_cost_ci95"], r["mean_vx_ci95"]
        out.append({"traffic": traffic, "claim": f"Stretch: {METHODS[m]} beats the paper's SRMPC row on both axes "
                    f"(J_c < {j_c}, v_x > {vx})",
                    "verdict": "met" if j_high < j_c and v_low > vx else
                    "not met" if j_low > j_c or v_high < vx else "not shown (a CI contains the paper's value)",
                    "evidence": f"J_c {ci(r, 'mean_event_cost', 3)}, v_x {ci(r, 'mean_vx', 2)}"})
    return out


def calibration_probe(key: str) -> dict | None:
    """The calibration's row of the probe named by ``key`` of the probes file (``frozen_probe``,
    ``declared_rule_probe``)."""
    if not CALIBRATION.exists():
        return None
    name = yaml.safe_load(PROBES.read_text()).get(key)
    rows = pd.read_csv(CALIBRATION).set_index("probe")
    if name not in rows.index:
        return None
    return {"probe": name, **{k: (v.item() if hasattr(v, "item") else v) for k, v in rows.loc[name].items()}}


def planner_result(planner: str, resamples: int, seed: int) -> dict:
    """One option's cells in both traffic levels: rows with verdicts, roles and paired differences, claims."""
    result: dict = {"planner": planner, "claims": []}
    for traffic in TRAFFIC:
        rows, frames = {}, {}
        found = folders(planner, traffic)
        for method in METHODS:
            rows[method], frames[method] = method_row(found[method], resamples, seed)
            rows[method]["directory"] = str(found[method])
            if (traffic, method) in PAPER:
                published = PAPER[(traffic, method)]
                rows[method]["paper"] = {k: published[i] for k, i in PUBLISHED.items()}
                rows[method]["verdicts"] = {k: verdict(published[i], rows[method][f"{k}_ci95"])
                                            for k, i in PUBLISHED.items()}
                rows[method]["roles"] = {k: role(traffic, method, k) for k in PUBLISHED}
        target = PAPER[("light", "ltv_mpc")]
        if traffic == "light":
            rows["ltv_mpc"]["calibration_band"] = {
                k: {"target": target[PUBLISHED[k]], "half_width": h,
                    "verdict": band_verdict(target[PUBLISHED[k]], h, rows["ltv_mpc"][f"{k}_ci95"])}
                for k, h in TARGETS.items()}
        for method in ("srmpc", "srmpc_track_rollout"):
            rows[method]["paired_differences"] = {
                other: paired_differences(frames[method], frames[other], resamples, seed)
                for other in ("ltv_mpc", "ppo_lsi")}
            rows[method]["paired_ratios"] = {other: paired_ratios(frames[method], frames[other], resamples, seed)
                                             for other in ("ltv_mpc", "ppo_lsi")}
        result[traffic] = rows
        result["claims"] += claims(rows, traffic)
    counts = {v: 0 for v in ("inside", "above", "below")}
    for traffic in TRAFFIC:
        for method in ("ltv_mpc", "srmpc"):
            for v in result[traffic][method]["verdicts"].values():
                counts[v] += 1
    result["verdict_counts"] = counts
    result["calibration_probe"] = calibration_probe(PLANNERS[planner][1])
    return result


def statistic_moves(result: dict) -> list[str]:
    """The J_r per step verdicts that the mean of per-episode ratios would give otherwise."""
    moves = []
    for traffic in TRAFFIC:
        for method in ("ppo_lsi", "ltv_mpc", "srmpc"):
            r = result[traffic][method]
            old = verdict(r["paper"]["return_per_step"], r["mean_return_per_step_ci95"])
            if old != r["verdicts"]["return_per_step"]:
                moves.append(f"{traffic} {SHORT[method]}: {r['verdicts']['return_per_step']} "
                             f"({ci(r, 'return_per_step', 2)}; the mean of ratios "
                             f"{ci(r, 'mean_return_per_step', 2)} would say {old})")
    return moves


def cell_table(rows: dict, traffic: str, methods: list[str]) -> list[str]:
    lines = ["| method | " + " | ".join(f"{LABELS[k][0]} ours | paper | verdict" for k in PUBLISHED) + " |",
             "|---|" + "---|---|---|" * len(PUBLISHED)]
    for method in methods:
        r, cells = rows[method], []
        for key in PUBLISHED:
            published = r.get("paper", {}).get(key)
            mark = " (target)" if traffic == "light" and method == "ltv_mpc" and key in TARGETS else ""
            cells += [ci(r, key, LABELS[key][1]) + mark, "–" if published is None else f"{published:g}",
                      r.get("verdicts", {}).get(key, "–")]
        lines.append(f"| {METHODS[method]} | " + " | ".join(cells) + " |")
    return lines


def target_lines(result: dict) -> list[str]:
    """The calibration targets at both options: LTV-MPC in light traffic against the paper's bands."""
    target = PAPER[("light", "ltv_mpc")]
    lines = ["## The calibration targets: LTV-MPC, light traffic", "",
             f"| option | J_c (paper {target[2]}) | ±{TARGETS['mean_event_cost']} band | v_x [m/s] (paper "
             f"{target[5]}) | ±{TARGETS['mean_vx']} band | on the calibration seeds |", "|---|---|---|---|---|---|"]
    for planner, part in ((PLANNER, result), (DECLARED_PLANNER, result[DECLARED_PLANNER])):
        r = part["light"]["ltv_mpc"]
        band = r["calibration_band"]
        probe = part.get("calibration_probe")
        seen = (f"`{probe['probe']}`, {probe['episodes']:.0f} episodes: J_c {probe['mean_event_cost']:.3f}, v_x "
                f"{probe['mean_vx']:.2f}, distance {probe['distance_to_target']:.2f}") if probe else "–"
        lines.append(f"| `{planner}` ({PLANNERS[planner][0]}) | {ci(r, 'mean_event_cost', 3)}: paper's "
                     f"{r['verdicts']['mean_event_cost']} our CI | {band['mean_event_cost']['verdict']} | "
                     f"{ci(r, 'mean_vx', 2)}: paper's {r['verdicts']['mean_vx']} our CI | "
                     f"{band['mean_vx']['verdict']} | {seen} |")
    return [*lines, "", "Band: within when our whole 95% CI lies inside target ± half-width, outside when it misses "
            "the band, not shown when it crosses an edge. Neither option reaches the paper's speed.", ""]


def markdown(result: dict) -> str:
    declared = result[DECLARED_PLANNER]
    lines = ["# The paper's table at the calibrated planners", "",
             "Two LTV-MPC planner options from the calibration on LTV-MPC in light traffic alone, on seeds "
             "200000 + i (`results/operating_point/calibration.md`), aimed at the paper's light LTV-MPC row "
             "(J_c 0.625 ± 0.05, v_x 24.38 ± 0.3 m/s); no probe reached both bands:", "",
             f"- `planner={PLANNER}` (slack prices x0.05, speed weight 10, 1 m margin) is {PLANNERS[PLANNER][2]}. "
             "That rule was written with the freeze, after the probes were seen, and restated as the fastest "
             "with J_c in its band after these predictions were committed: it is post hoc.",
             f"- `planner={DECLARED_PLANNER}` (slack prices x0.01, speed weight 2, 1 m margin) is "
             f"{PLANNERS[DECLARED_PLANNER][2]}, run here on the same seeds after the fact.", "",
             "LTV-MPC light J_c and v_x are the calibration targets; its n_steps and J_r per step the first "
             "out-of-sample checks; rho_c = mean J_c / mean n_steps follows from J_c and n_steps and is no check "
             "of its own. Every other planner cell is a prediction. 1000 episodes per cell on the table's seeds "
             "(episode i from seed i, every method the same scenes); J_r per step = mean J_r / mean n_steps (the "
             "paper's statistic); 95% CIs (Wilson for J_c, bootstrap over episodes otherwise, J_r per step and "
             "rho_c as ratios of means); verdict: where the paper's number lies against our CI.", "",
             *target_lines(result)]
    for traffic in TRAFFIC:
        lines += [f"## {traffic} traffic", "", f"`planner={PLANNER}` ({PLANNERS[PLANNER][0]}):", "",
                  *cell_table(result[traffic], traffic, list(METHODS)), "",
                  f"`planner={DECLARED_PLANNER}` ({PLANNERS[DECLARED_PLANNER][0]}; PPO-L-SI as above):", "",
                  *cell_table(declared[traffic], traffic, [m for m in METHODS if m != "ppo_lsi"]), "",
                  "Paired differences on the same seeds (mean [95% CI]):", "",
                  "| option | difference | J_r | J_c | n_steps | v_x [m/s] |", "|---|---|---|---|---|---|"]
        for planner, part in ((PLANNER, result), (DECLARED_PLANNER, declared)):
            for other, d in part[traffic]["srmpc"]["paired_differences"].items():
                lines.append(f"| {PLANNERS[planner][0]} | SRMPC - {SHORT[other]} | {difference(d, 'mean_return', 0)} "
                             f"| {difference(d, 'mean_event_cost', 3)} | {difference(d, 'mean_n_steps', 0)} | "
                             f"{difference(d, 'mean_vx', 2)} |")
        for planner, part in ((PLANNER, result), (DECLARED_PLANNER, declared)):
            lines += ["", f"The paper's claims at `planner={planner}` ({PLANNERS[planner][0]}):", ""]
            lines += [f"- {c['claim']}: **{c['verdict']}**. {c['evidence']}." for c in part["claims"]
                      if c["traffic"] == traffic]
        lines.append("")
    lines += ["## Counts", ""]
    for planner, part in ((PLANNER, result), (DECLARED_PLANNER, declared)):
        c = part["verdict_counts"]
        lines.append(f"- `planner={planner}` ({PLANNERS[planner][0]}): of the 20 published numbers of the four "
                     f"planner cells, {c['inside']} lie inside our 95% CI, {c['above']} above it and {c['below']} "
                     "below it (rho_c among them, though it follows from J_c and n_steps).")
    moves = [f"`{planner}`, {m}" for planner, part in ((PLANNER, result), (DECLARED_PLANNER, declared))
             for m in statistic_moves(part)]
    lines += ["", "J_r per step verdicts that the mean of per-episode ratios would give otherwise: "
              + ("; ".join(moves) if moves else "none") + ".", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    result = planner_result(PLANNER, args.resamples, args.seed)
    result["calibration_targets"] = sorted(f"light/ltv_mpc/{k}" for k in TARGETS)
    result[DECLARED_PLANNER] = planner_result(DECLARED_PLANNER, args.resamples, args.seed)
    text = markdown(result)
    write_outputs({Path("results/operating_point.md"): text,
                   Path("results/operating_point.json"): json.dumps(result, indent=2) + "\n"})
    print(text)


if __name__ == "__main__":
    main()
