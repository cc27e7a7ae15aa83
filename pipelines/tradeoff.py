"""The safety-speed trade-off: J_c against mean v_x for LTV-MPC and SRMPC over planner settings.

Every point is one 1000-episode evaluation on the table's seeds (episode i from seed i), so any two
points are paired episode by episode. The planner-based methods are curves over the planner settings they
share at each grid point (the longitudinal safety margin [m], and the speed weight of
``planner.state_weights`` where the sweep varies it); PPO-L-SI, PPO and lane keeping have no planner and
are single points; the paper's three published rows are hollow markers.

Reads the experiments of :data:`CURVE_EXPERIMENTS` (``tradeoff/<method>_<planner>``, the paper's operating point
``operating_point/<method>``, and for the 8 m points, conf/planner/ltv_mpc.yaml, the table's own runs of the same
seeds) and the single points' (``table/<method>``), each found by the experiment and traffic its ``config.yaml``
names; a point's planner settings are read from that config as data. Writes:

- ``results/tradeoff.json``: ``[traffic][method]`` is a list of points, each with its ``settings``,
  ``episodes``, ``mean_event_cost``, ``mean_vx``, ``mean_return`` (and the other keys of ``table.json``)
  with their ``_ci95`` and ``versus_table_planner`` (v_x difference and J_c ratio against the curve's 8 m point);
  ``[traffic]["dominance"]``, ``["at_policy_speed"]`` and ``["paper_operating_point"]``;
- ``results/tradeoff.md``: the same as tables, with the verdicts in words;
- ``results/figures/tradeoff.png``: one panel per traffic level, 95% CIs on both axes; with ``results/rss.json``
  (DVC stage ``rss``) also PPO-L-RSS's policy and SRMPC proposed by it (table planner, recommended setting) as
  triangles (``[traffic]["rss"]`` in the JSON).

Dominance: SRMPC point s dominates LTV-MPC point l when s is faster and safer. It is *shown* when the
paired 95% bootstrap CIs of v_x(s) - v_x(l) lie above 0 and of J_c(s) - J_c(l) lie below 0; it holds *by
point estimate* when only the means say so.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd

from pipelines.reporting import (
    METHODS,
    PAPER,
    cut_with_ci,
    method_row,
    planner_knobs,
    read_config,
    run_of,
    runs,
    variant_name,
    write_outputs,
)
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences, paired_ratios

TRAFFIC = ("light", "dense")
CURVES = {"ltv_mpc": "LTV-MPC", "srmpc": "SRMPC (Algorithm 1)", "srmpc_track_rollout": "SRMPC, tracking the rollout"}
SINGLE = ("ppo_lsi", "ppo", "lane_keeping")
TABLE_POINT = {"ltv_mpc": "table/ltv_mpc", "srmpc": "table/srmpc", "srmpc_track_rollout": "variants/track_rollout"}
"""Each curve's point at the table's planner (8 m): the table's own run."""
CURVE_EXPERIMENTS = {method: [TABLE_POINT[method], f"operating_point/{method}",
                              *(f"tradeoff/{method}_{planner}" for planner in
                                ("margin_1m", "margin_1m_speed_weight_2", "margin_2m", "margin_4m"))]
                     for method in CURVES}
"""Each curve's points (experiments): the table's planner, the paper's operating point, the sweep's planners."""
SRMPC_CURVES = ("srmpc", "srmpc_track_rollout")
RSS = Path("results/rss.json")
RSS_POINTS = {"ppo_lsi/ppo_lsi_rss": ("PPO-L-RSS", "ppo_lsi"),
              "srmpc/ppo_lsi_rss": ("SRMPC (Algorithm 1), PPO-L-RSS proposing", "srmpc"),
              "srmpc_recommended/ppo_lsi_rss": ("SRMPC tracking the rollout, 1 m, PPO-L-RSS proposing",
                                                "srmpc_track_rollout")}
"""Rows of results/rss.json drawn as points: key -> (label, the color of the method it varies)."""
RSS_SETTINGS = {"ppo_lsi/ppo_lsi_rss": "-", "srmpc/ppo_lsi_rss": "8 m", "srmpc_recommended/ppo_lsi_rss": "1 m"}
TABLE_KEYS = ("episodes", "mean_return", "return_per_step", "mean_return_per_step", "mean_event_cost", "cost_rate",
              "mean_n_steps", "mean_vx")


def point(directory: Path, resamples: int, seed: int) -> tuple[dict, pd.DataFrame]:
    """One evaluation as a trade-off point, and its episodes."""
    row, episodes = method_row(directory, resamples, seed)
    keep = {k: v for k, v in row.items() if k.removesuffix("_ci95") in TABLE_KEYS}
    return {"settings": planner_knobs(read_config(directory)), "directory": str(directory), **keep}, episodes


def collect(resamples: int, seed: int) -> tuple[dict, dict]:
    """points[traffic][method] (sorted by v_x) and episodes[directory]."""
    points: dict = {t: {m: [] for m in (*CURVES, *SINGLE)} for t in TRAFFIC}
    episodes: dict[str, pd.DataFrame] = {}
    experiments = {**CURVE_EXPERIMENTS, **{m: [f"table/{m}"] for m in SINGLE}}
    required = {*TABLE_POINT.values(), *(f"table/{m}" for m in SINGLE)}
    for traffic in TRAFFIC:  # the table's runs are required, the sweep's points are those that exist
        found = [(run_of(e, traffic) if e in required else runs().get((e, traffic)), m)
                 for m, names in experiments.items() for e in names]
        found = sorted((directory, method) for directory, method in found if directory is not None)
        for directory, method in found:  # in folder order, as the sort below keeps ties
            p, e = point(directory, resamples, seed)
            if method in SINGLE:
                p.pop("settings")
            points[traffic][method].append(p)
            episodes[p["directory"]] = e
    for traffic, methods in points.items():
        for curve in methods.values():
            curve.sort(key=lambda q: q["mean_vx"])
        for curve in CURVES:
            versus_table_planner(methods[curve], str(run_of(TABLE_POINT[curve], traffic)))
    return points, episodes


def versus_table_planner(curve: list[dict], table_point: str) -> None:
    """Add to each point of ``curve`` ``versus_table_planner``: its mean v_x minus that of the curve's point at the
    table's planner (the 8 m point, the table's run in folder ``table_point``), and its J_c over that point's (None
    where that J_c is 0). Point estimates of two unpaired means; the paired CIs are in ``dominance``."""
    reference = next((p for p in curve if p["directory"] == table_point), None)
    if reference is None:
        return
    for p in curve:
        p["versus_table_planner"] = {
            "mean_vx_difference": p["mean_vx"] - reference["mean_vx"],
            "mean_event_cost_ratio": (p["mean_event_cost"] / reference["mean_event_cost"]
                                      if reference["mean_event_cost"] else None)}


def label(p: dict) -> str:
    s = p.get("settings")
    if not s:
        return "-"
    text = f"{s['safety_margin_longitudinal_m']:g} m"
    if s["speed_weight"] != 0.5:
        text += f", w_v {s['speed_weight']:g}"
    if s["x_weight"] != 0.0:
        text += f", w_x {s['x_weight']:g}"
    if s.get("slack_price_scale", 1.0) != 1.0:
        text += f", slack x{s['slack_price_scale']:g}"
    return text


def dominance(methods: dict, episodes: dict, resamples: int, seed: int) -> list[dict]:
    """For each LTV-MPC point: the SRMPC points faster and safer, with paired differences."""
    verdicts = []
    for ltv in methods["ltv_mpc"]:
        candidates = []
        for curve in SRMPC_CURVES:
            for s in methods[curve]:
                d = paired_differences(episodes[s["directory"]], episodes[ltv["directory"]], resamples, seed)
                faster, safer = d["mean_vx"] > 0, d["mean_event_cost"] < 0
                shown = d["mean_vx_ci95"][0] > 0 and d["mean_event_cost_ci95"][1] < 0
                ratios = paired_ratios(episodes[s["directory"]], episodes[ltv["directory"]], resamples, seed)
                candidates.append({"method": curve, "settings": s["settings"], "paired_difference": d,
                                   "paired_ratios": ratios,
                                   "dominates_by_point_estimate": bool(faster and safer),
                                   "dominance_shown": bool(shown)})
        verdicts.append({"ltv_mpc": {"settings": ltv["settings"], "mean_vx": ltv["mean_vx"],
                                     "mean_event_cost": ltv["mean_event_cost"]},
                         "dominated_by_point_estimate": any(c["dominates_by_point_estimate"] for c in candidates),
                         "dominance_shown": any(c["dominance_shown"] for c in candidates),
                         "srmpc_points": candidates})
    return verdicts


def at_speed(curve: list[dict], vx: float) -> dict:
    """J_c of a curve at speed ``vx``: linear between the two points around it, else the nearest point."""
    speeds = [p["mean_vx"] for p in curve]
    if speeds and speeds[0] <= vx <= speeds[-1] and len(curve) > 1:
        i = max(1, int(np.searchsorted(speeds, vx)))
        a, b = curve[i - 1], curve[i]
        w = 0.0 if b["mean_vx"] == a["mean_vx"] else (vx - a["mean_vx"]) / (b["mean_vx"] - a["mean_vx"])
        return {"how": "interpolated", "between": [a["settings"], b["settings"]],
                "mean_event_cost": a["mean_event_cost"] + w * (b["mean_event_cost"] - a["mean_event_cost"])}
    nearest = min(curve, key=lambda p: abs(p["mean_vx"] - vx))
    return {"how": "nearest point (outside the curve's speed range)", "settings": nearest["settings"],
            "mean_vx": nearest["mean_vx"], "mean_event_cost": nearest["mean_event_cost"],
            "mean_event_cost_ci95": nearest["mean_event_cost_ci95"]}


def paper_operating_point(traffic: str, methods: dict, episodes: dict, resamples: int, seed: int) -> dict:
    """The LTV-MPC point nearest the paper's LTV-MPC speed, and SRMPC at the same settings beside it."""
    paper_vx = PAPER[(traffic, "ltv_mpc")][5]
    ltv = min(methods["ltv_mpc"], key=lambda p: abs(p["mean_vx"] - paper_vx))
    same = [p for p in methods["srmpc"] if p["settings"] == ltv["settings"]]
    result = {"paper_ltv_mpc_vx": paper_vx, "ltv_mpc": ltv, "srmpc": same[0] if same else None,
              "paper_reduction": 1 - PAPER[(traffic, "srmpc")][2] / PAPER[(traffic, "ltv_mpc")][2]}
    if same:
        s = same[0]
        result["paired_difference"] = paired_differences(episodes[s["directory"]], episodes[ltv["directory"]],
                                                         resamples, seed)
        result["reduction"] = (1 - s["mean_event_cost"] / ltv["mean_event_cost"]) if ltv["mean_event_cost"] else None
        result["ratio"] = paired_ratios(episodes[s["directory"]], episodes[ltv["directory"]], resamples, seed)
    return result


CONFIRMATION_EXPERIMENT = "confirmation/srmpc_recommended"
"""The recommended setting's experiment on fresh seeds (conf/experiment/confirmation/srmpc_recommended.yaml)."""
TARGET = {"light": {"min_vx": 24.1, "max_event_cost": 0.006}, "dense": {"min_vx": 22.3, "max_event_cost": 0.036}}
"""The issue's target: at least PPO-L-SI's speed (its table row), at no more than a tenth of its J_c."""
STRETCH = {"light": {"min_vx": 24.63, "max_event_cost": 0.215}, "dense": {"min_vx": 24.47, "max_event_cost": 0.353}}
"""Beat the paper's SRMPC row on both axes."""


def confirmation(traffic: str, resamples: int, seed: int) -> dict | None:
    """The recommended setting on fresh seeds (100000 + i), beside LTV-MPC at its planner settings and
    PPO-L-SI on the same episodes; against the target and the stretch (strict on both axes)."""
    found = {name: runs().get((f"confirmation/{name}", traffic)) for name in
             ("srmpc_recommended", "ltv_mpc_margin_1m", "ppo_lsi")}
    if None in found.values():
        return None
    rows, frames = {}, {}
    for name, directory in found.items():
        rows[name], frames[name] = point(directory, resamples, seed)
    s, policy = rows["srmpc_recommended"], rows["ppo_lsi"]
    recommended = read_config(found["srmpc_recommended"])
    own_target = {"min_vx": policy["mean_vx"], "max_event_cost": policy["mean_event_cost"] / 10}

    def meets(goal: dict) -> bool:
        return bool(s["mean_vx"] >= goal["min_vx"] and s["mean_event_cost"] <= goal["max_event_cost"])

    return {**rows, "seed": int(recommended["evaluation"]["seed"]),
            "recommended": {"variant": variant_name(recommended), "settings": planner_knobs(recommended)},
            "paired_differences": {other: paired_differences(frames["srmpc_recommended"], frames[other],
                                                             resamples, seed)
                                   for other in ("ltv_mpc_margin_1m", "ppo_lsi")},
            "paired_ratios": {other: paired_ratios(frames["srmpc_recommended"], frames[other], resamples, seed)
                              for other in ("ltv_mpc_margin_1m", "ppo_lsi")},
            "target": {**TARGET[traffic], "meets": meets(TARGET[traffic])},
            "target_on_these_seeds": {**own_target, "meets": meets(own_target)},
            "stretch": {**STRETCH[traffic],
                        "meets": bool(s["mean_vx"] > STRETCH[traffic]["min_vx"]
                                      and s["mean_event_cost"] < STRETCH[traffic]["max_event_cost"])}}


def ci(p: dict, key: str, digits: int) -> str:
    low, high = p[f"{key}_ci95"]
    return f"{p[key]:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def ratio_text(r: dict) -> str:
    """A paired ratio (``confidence_intervals.paired_ratios``) with its CI, and what its upper end bounds:
    "0.018 [0.000, 0.060]: at most 1/17 (95% upper bound)". With a lower end at 0 only the bound is meaningful."""
    if r["ratio"] is None:
        return "no finite ratio (the other's J_c is 0)"
    low, high = r["ratio_ci95"]
    if high == float("inf"):
        return f"{r['ratio']:.3f} [{low:.3f}, no upper bound]"
    bound = f"at most 1/{1 / high:.0f} (95% upper bound)" if 0 < high < 1 else ""
    return f"{r['ratio']:.3f} [{low:.3f}, {high:.3f}]" + (f": {bound}" if bound else "")


def why(p: dict, goal: dict) -> str:
    """Each axis of a goal against point ``p``: ``J_c 0.001 ≤ 0.006; v_x 23.98 < 24.10``."""
    cost, vx = p["mean_event_cost"], p["mean_vx"]
    return (f"J_c {cost:.3f} {'≤' if cost <= goal['max_event_cost'] else '>'} {goal['max_event_cost']:.4g}; "
            f"v_x {vx:.2f} {'≥' if vx >= goal['min_vx'] else '<'} {goal['min_vx']:.2f}")


def dominance_examples(verdict: dict) -> list[dict]:
    """The SRMPC points a dominance verdict names: where dominance is shown, only points whose paired CIs exclude 0
    on both axes (the one at the LTV-MPC point's own setting if it is among them, and the fastest); otherwise the
    fastest point-estimate dominator, labelled as such by the caller."""
    best = [c for c in verdict["srmpc_points"] if c["dominates_by_point_estimate"]]
    shown = [c for c in best if c["dominance_shown"]]
    if not shown:
        return [max(best, key=lambda c: c["paired_difference"]["mean_vx"])] if best else []
    same = [c for c in shown if c["settings"] == verdict["ltv_mpc"]["settings"]]
    fastest = max(shown, key=lambda c: c["paired_difference"]["mean_vx"])
    return [*same, *([fastest] if fastest not in same else [])]


def markdown(report: dict) -> str:
    lines = ["# The safety-speed trade-off: LTV-MPC and SRMPC over planner settings", "",
             "Generated by `pipelines/tradeoff.py` (DVC stage `tradeoff`). Each row: 1000 episodes on the table's",
             "seeds; LTV-MPC and SRMPC share the planner settings of a row. 95% CIs: Wilson (J_c), bootstrap",
             "(v_x, J_r); paired differences: bootstrap over the same episodes. The 8 m rows and the policies'",
             "and lane keeping's rows are the table's own runs (results/evaluation/twin/); every other row is",
             "stage `evaluate_tradeoff`'s (results/evaluation/tradeoff/). Each row's settings are read from its",
             "folder's config.yaml.", ""]
    for traffic in TRAFFIC:
        r = report[traffic]
        lines += [f"## {traffic.capitalize()} traffic", "",
                  "| method | planner setting | J_c | v_x [m/s] | J_r |", "|---|---|---|---|---|"]
        for method in (*CURVES, *SINGLE):
            for p in r[method]:
                name = CURVES.get(method) or METHODS[method]
                lines.append(f"| {name} | {label(p)} | {ci(p, 'mean_event_cost', 3)} | {ci(p, 'mean_vx', 2)} | "
                             f"{ci(p, 'mean_return', 0)} |")
        for key, (name, _) in RSS_POINTS.items():
            p = (r.get("rss") or {}).get(key)
            if p is not None:
                lines.append(f"| {name} (results/rss.md) | {RSS_SETTINGS[key]} | {ci(p, 'mean_event_cost', 3)} | "
                             f"{ci(p, 'mean_vx', 2)} | {ci(p, 'mean_return', 0)} |")
        for method in ("ppo_lsi", "ltv_mpc", "srmpc"):
            values = PAPER[(traffic, method)]
            lines.append(f"| {METHODS[method]} (paper) | - | {values[2]:.3f} | {values[5]:.2f} | {values[0]:.0f} |")
        lines += ["", "**Dominance** (SRMPC faster *and* safer than an LTV-MPC point, paired):", ""]
        for v in r["dominance"]:
            best = [c for c in v["srmpc_points"] if c["dominates_by_point_estimate"]]
            l_ = v["ltv_mpc"]
            head = (f"- LTV-MPC at {label(l_)} (J_c {l_['mean_event_cost']:.3f}, v_x {l_['mean_vx']:.2f}): ")
            if v["dominance_shown"]:
                head += "dominated, shown by the paired CIs: by "
            elif v["dominated_by_point_estimate"]:
                head += "dominated by point estimate only (a paired CI crosses 0): by "
            else:
                lines.append(head + "**not dominated**: no SRMPC point is both faster and safer.")
                continue
            shown = [c for c in best if c["dominance_shown"]]
            head += (f"{len(shown)} of {len(v['srmpc_points'])} SRMPC points, e.g. " if shown else
                     f"{len(best)} of {len(v['srmpc_points'])} SRMPC points by point estimate, none shown; the "
                     "fastest: ")
            parts = []
            for c in dominance_examples(v):
                d = c["paired_difference"]
                parts.append(f"{CURVES[c['method']]} at {label(c)} (Δv_x {d['mean_vx']:+.2f} "
                             f"[{d['mean_vx_ci95'][0]:+.2f}, {d['mean_vx_ci95'][1]:+.2f}], ΔJ_c "
                             f"{d['mean_event_cost']:+.3f} [{d['mean_event_cost_ci95'][0]:+.3f}, "
                             f"{d['mean_event_cost_ci95'][1]:+.3f}])")
            lines.append(head + "; ".join(parts) + ".")
        policy = r["ppo_lsi"][0]
        lines += ["", f"**At PPO-L-SI's speed** (v_x {policy['mean_vx']:.2f}, "
                      f"J_c {ci(policy, 'mean_event_cost', 3)}):", ""]
        for curve in SRMPC_CURVES:
            a = r["at_policy_speed"][curve]
            if a["how"] == "interpolated":
                lines.append(f"- {CURVES[curve]}: J_c {a['mean_event_cost']:.3f} (interpolated between "
                             f"{label({'settings': a['between'][0]})} and {label({'settings': a['between'][1]})}).")
            else:
                lines.append(f"- {CURVES[curve]}: the curve does not reach that speed; its fastest point "
                             f"({label(a)}) drives {a['mean_vx']:.2f} m/s at J_c {a['mean_event_cost']:.3f}.")
        o = r["paper_operating_point"]
        lines += ["", f"**The paper's operating point** (its LTV-MPC drives at {o['paper_ltv_mpc_vx']:.2f} m/s): our "
                  f"LTV-MPC comes closest at {label(o['ltv_mpc'])}, v_x {ci(o['ltv_mpc'], 'mean_vx', 2)}, "
                  f"J_c {ci(o['ltv_mpc'], 'mean_event_cost', 3)}."]
        if o["srmpc"] is not None and o.get("reduction") is not None:
            d = o["paired_difference"]
            lines.append(f"SRMPC at the same setting: J_c {ci(o['srmpc'], 'mean_event_cost', 3)}, v_x "
                         f"{ci(o['srmpc'], 'mean_vx', 2)}; J_c reduced by "
                         f"{cut_with_ci(o['ratio']['mean_event_cost'])} (paper: "
                         f"{o['paper_reduction']:.0%}), paired ΔJ_c {d['mean_event_cost']:+.3f} "
                         f"[{d['mean_event_cost_ci95'][0]:+.3f}, {d['mean_event_cost_ci95'][1]:+.3f}].")
        c = r.get("confirmation")
        if c is not None:
            s, l_, policy = c["srmpc_recommended"], c["ltv_mpc_margin_1m"], c["ppo_lsi"]
            chosen = c["recommended"]
            lines += ["", "**The recommended setting, confirmed on fresh seeds** "
                      f"(`+experiment={CONFIRMATION_EXPERIMENT}`: SRMPC variant {chosen['variant']}, a "
                      f"{chosen['settings']['safety_margin_longitudinal_m']:g} m safety margin; "
                      f"{s['episodes']} episodes from seed {c['seed']}, never used by the sweep):", "",
                      "| method | J_c | v_x [m/s] | J_r |", "|---|---|---|---|",
                      f"| SRMPC, recommended | {ci(s, 'mean_event_cost', 3)} | {ci(s, 'mean_vx', 2)} | "
                      f"{ci(s, 'mean_return', 0)} |",
                      f"| LTV-MPC, same planner | {ci(l_, 'mean_event_cost', 3)} | {ci(l_, 'mean_vx', 2)} | "
                      f"{ci(l_, 'mean_return', 0)} |",
                      f"| PPO-L-SI | {ci(policy, 'mean_event_cost', 3)} | {ci(policy, 'mean_vx', 2)} | "
                      f"{ci(policy, 'mean_return', 0)} |", ""]
            for other, name in (("ppo_lsi", "PPO-L-SI"), ("ltv_mpc_margin_1m", "LTV-MPC")):
                d = c["paired_differences"][other]
                lines.append(f"- SRMPC - {name}, paired: Δv_x {ci(d, 'mean_vx', 2)}, ΔJ_c "
                             f"{ci(d, 'mean_event_cost', 3)}, ΔJ_r {ci(d, 'mean_return', 0)}; J_c SRMPC / {name}: "
                             f"{ratio_text(c['paired_ratios'][other]['mean_event_cost'])}.")
            t, o, st = c["target"], c["target_on_these_seeds"], c["stretch"]

            lines += [f"- Target (v_x ≥ {t['min_vx']}, J_c ≤ {t['max_event_cost']}): "
                      f"**{'met' if t['meets'] else 'not met'}** ({why(s, t)}); against PPO-L-SI on these seeds: "
                      f"**{'met' if o['meets'] else 'not met'}** ({why(s, o)}).",
                      f"- Stretch, the paper's SRMPC row (v_x > {st['min_vx']}, J_c < {st['max_event_cost']}): "
                      f"**{'met' if st['meets'] else 'not met'}** ({why(s, st)})."]
        lines.append("")
    return "\n".join(lines) + "\n"


def figure(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"ltv_mpc": "tab:blue", "srmpc": "tab:red", "srmpc_track_rollout": "tab:orange",
              "ppo_lsi": "tab:green", "ppo": "tab:purple", "lane_keeping": "tab:gray"}
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.4))
    for ax, traffic in zip(axes, TRAFFIC, strict=True):
        r = report[traffic]
        for method in (*CURVES, *SINGLE):
            pts = r[method]
            x = np.array([p["mean_vx"] for p in pts])
            y = np.array([p["mean_event_cost"] for p in pts])
            xerr = np.abs(np.array([p["mean_vx_ci95"] for p in pts]).T - x)
            yerr = np.abs(np.array([p["mean_event_cost_ci95"] for p in pts]).T - y)
            name = CURVES.get(method) or METHODS[method]
            ax.errorbar(x, y, xerr=xerr, yerr=yerr, fmt="o-" if method in CURVES else "s", color=colors[method],
                        label=name, capsize=2, markersize=4, linewidth=1)
            for p in pts if method in CURVES else []:
                ax.annotate(label(p), (p["mean_vx"], p["mean_event_cost"]), fontsize=6, xytext=(3, 3),
                            textcoords="offset points", color=colors[method])
        for key, (name, color) in RSS_POINTS.items():
            p = (r.get("rss") or {}).get(key)
            if p is None:
                continue
            ax.errorbar([p["mean_vx"]], [p["mean_event_cost"]],
                        xerr=np.abs(np.array([p["mean_vx_ci95"]]).T - p["mean_vx"]),
                        yerr=np.abs(np.array([p["mean_event_cost_ci95"]]).T - p["mean_event_cost"]),
                        fmt="^", color=colors[color], markeredgecolor="black", label=name, capsize=2, markersize=6)
        for method in ("ppo_lsi", "ltv_mpc", "srmpc"):
            values = PAPER[(traffic, method)]
            ax.plot(values[5], values[2], "o", markerfacecolor="none", markeredgecolor=colors[method],
                    markersize=9, label=f"{METHODS[method]} (paper)")
        ax.set_yscale("symlog", linthresh=0.01)
        ax.set_xlabel("mean v_x [m/s]")
        ax.set_ylabel("J_c (share of episodes with a collision or road exit)")
        ax.set_title(f"{traffic} traffic, 1000 episodes per point")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()  # below both panels: it covers no point
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=5, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    temporary = path.with_name(path.stem + ".tmp.png")
    fig.savefig(temporary, dpi=130)
    temporary.replace(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    points, episodes = collect(args.resamples, args.seed)
    report = {}
    for traffic in TRAFFIC:
        methods = points[traffic]
        report[traffic] = {
            **methods,
            "dominance": dominance(methods, episodes, args.resamples, args.seed),
            "at_policy_speed": {c: at_speed(methods[c], methods["ppo_lsi"][0]["mean_vx"]) for c in SRMPC_CURVES},
            "paper_operating_point": paper_operating_point(traffic, methods, episodes, args.resamples, args.seed),
            "confirmation": confirmation(traffic, args.resamples, args.seed),
        }
        if RSS.is_file():
            rows = json.loads(RSS.read_text())["evaluation"][traffic]
            report[traffic]["rss"] = {key: {k: v for k, v in rows[key].items() if k.removesuffix("_ci95") in TABLE_KEYS
                                            or k == "directory"} for key in RSS_POINTS}
    Path("results/figures").mkdir(parents=True, exist_ok=True)
    figure(report, Path("results/figures/tradeoff.png"))
    write_outputs({Path("results/tradeoff.json"): json.dumps(report, indent=1) + "\n",
                   Path("results/tradeoff.md"): markdown(report)})
    print(markdown(report))


if __name__ == "__main__":
    main()
