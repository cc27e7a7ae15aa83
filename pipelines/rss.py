"""DVC stage ``rss``: the safety index built on Responsibility-Sensitive Safety, trained and evaluated against
the paper's.

    python -m pipelines.rss

Reads
- ``results/training/summary.json`` (DVC stage ``training_figure``): end-of-training J_r, J_c, rho_c and v_x of PPO,
  PPO-L-SI and PPO-L-RSS (3 seeds, Student-t CIs) and of PPO-L-RSS with ad-rss-lib's parameters (seed 0), and the
  paper's training claim checked for PPO-L-RSS (``paper_claim_ppo_lsi_rss``);
- experiments ``rss/<method>_<agent>``: each PPO-L-RSS policy alone (``ppo_lsi``), as SRMPC's proposer at the
  table's planner config (``srmpc``) and at the recommended setting (``srmpc_recommended``: tracking the rollout,
  1 m safety region), 1000 episodes on the table's seeds;
- the same methods with PPO-L-SI on the same seeds: experiments ``table/ppo_lsi``, ``table/srmpc``
  and ``tradeoff/srmpc_track_rollout_margin_1m``;
- the confirmation: PPO-L-RSS's policy (experiment ``confirmation/ppo_lsi_rss``) and
  PPO-L-SI's (``confirmation/ppo_lsi``) on 1000 fresh episodes (seeds 100000 + i);

and writes ``results/rss.json`` (parameter sets, training rows, evaluation rows with 95% CIs, paired differences
RSS minus SI per episode seed, verdicts) and ``results/rss.md`` (the same as tables and sentences).

Verdict of a paired difference with 95% CI [low, high]: for J_c, ``safer`` when high < 0, ``less safe`` when
low > 0; for v_x, ``faster`` when low > 0, ``slower`` when high < 0; otherwise ``no difference resolved``.
The recommended parameter set is judged on the policy it trains (what a safety index is for): a set whose policy is
``less safe`` than PPO-L-SI's in either traffic level is excluded; among the others, the one with the lower J_c
summed over both levels, unless its v_x is lower by more than :data:`SPEED_TOLERANCE_MPS` in either level; none
when every set is excluded.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipelines.reporting import ci, method_row, read_config, run_of, write_outputs
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences
from srmpc.config.compose import compose_config, to_objects
from srmpc.scenario.safety_index import rss_lateral_distance, rss_longitudinal_distance

TRAINING_SUMMARY = Path("results/training/summary.json")
TRAFFIC = ("light", "dense")
AGENTS = {"ppo_lsi_rss": "PPO-L-RSS", "ppo_lsi_rss_ad_rss_lib": "PPO-L-RSS (ad-rss-lib)"}
"""The RSS agents (results/training/<agent>/) and their labels."""
PARAMETER_SETS = {"ppo_lsi_rss": ("IEEE 9304756, aggressive", ["+experiment=training/ppo_lsi_rss"]),
                  "ppo_lsi_rss_ad_rss_lib": ("intel/ad-rss-lib defaults",
                                             ["+experiment=training/rss_sensitivity/ad_rss_lib"])}
"""Agent -> (the parameter set's source, the training overrides that compose it)."""
METHODS = {"ppo_lsi": ("policy", "table/ppo_lsi"), "srmpc": ("SRMPC, table planner", "table/srmpc"),
           "srmpc_recommended": ("SRMPC, recommended setting", "tradeoff/srmpc_track_rollout_margin_1m")}
"""Method -> (label, its experiment with PPO-L-SI's policy on the same seeds); with an RSS agent's policy it is
experiment ``rss/<method>_<agent>``."""
TRAINING_AGENTS = {"ppo": "PPO", "ppo_lsi": "PPO-L-SI", **AGENTS}
CONFIRMATION = {"ppo_lsi": "confirmation/ppo_lsi", "ppo_lsi_rss": "confirmation/ppo_lsi_rss"}
CONFIRMATION_SEED = 100000
"""PPO-L-SI's and PPO-L-RSS's policies on fresh seeds (100000 + i), the same for both."""
SPEED_TOLERANCE_MPS = 0.5
"""A parameter set is not recommended for a lower J_c if its SRMPC is slower than the other's by more than this."""


def parameter_sets() -> dict:
    """Each RSS parameter set as the training composes it, with its distances at typical highway speeds."""
    sets = {}
    for agent, (source, overrides) in PARAMETER_SETS.items():
        rss = to_objects(compose_config(["stage=train", *overrides])).scenario.safety_index.rss
        lon = lambda rear, front, rss=rss: rss_longitudinal_distance(  # noqa: E731
            rear, front, rss.response_time_ego_s, rss.longitudinal_acceleration_max_mps2,
            rss.longitudinal_brake_min_mps2, rss.longitudinal_brake_max_mps2)
        sets[agent] = {
            "source": source, "parameters": vars(rss),
            "longitudinal_m": {"25_behind_25": lon(25.0, 25.0), "25_behind_20": lon(25.0, 20.0),
                               "22_behind_22": lon(22.0, 22.0)},
            "lateral_m": {"both_still": rss_lateral_distance(
                0.0, 0.0, rss.response_time_ego_s, rss.response_time_others_s, rss.lateral_acceleration_max_mps2,
                rss.lateral_brake_min_mps2, rss.lateral_margin_m)},
        }
    return sets


def training_rows(summary: dict) -> dict:
    keys = ("return", "cost_return", "cost_rate", "vx")
    return {agent: {**{k: summary[agent][k] for k in keys}, **{f"{k}_ci95": summary[agent][f"{k}_ci95"] for k in keys},
                    "seeds": summary[agent]["seeds"], "frames": summary[agent]["frames"]}
            for agent in TRAINING_AGENTS if agent in summary}


def folder(experiment: str, traffic: str, seed: int = 0) -> Path:
    """The folder of ``experiment`` in ``traffic``, checked against its config.yaml's seeds (episode i from seed + i;
    0: the table's)."""
    path = run_of(experiment, traffic)
    first = int(read_config(path)["evaluation"]["seed"])
    if first != seed:
        raise SystemExit(f"rss: {path} ({experiment}) starts from seed {first}, not {seed}")
    return path


def difference_verdicts(d: dict) -> dict:
    low, high = d["mean_event_cost_ci95"]
    safety = "safer" if high < 0 else "less safe" if low > 0 else "no difference resolved"
    low, high = d["mean_vx_ci95"]
    speed = "faster" if low > 0 else "slower" if high < 0 else "no difference resolved"
    return {"J_c": safety, "v_x": speed}


def evaluation(resamples: int, seed: int) -> dict:
    result: dict = {}
    for traffic in TRAFFIC:
        rows: dict = {}
        for method, (_, si_experiment) in METHODS.items():
            si_folder = folder(si_experiment, traffic)
            si_row, si_frame = method_row(si_folder, resamples, seed)
            rows[f"{method}/ppo_lsi"] = {**si_row, "directory": str(si_folder)}
            for agent in AGENTS:
                directory = folder(f"rss/{method}_{agent}", traffic)
                row, frame = method_row(directory, resamples, seed)
                difference = paired_differences(frame, si_frame, resamples, seed)
                rows[f"{method}/{agent}"] = {**row, "directory": str(directory), "minus_ppo_lsi": difference,
                                             "verdicts": difference_verdicts(difference)}
        result[traffic] = rows
    return result


def confirmation(resamples: int, seed: int) -> dict:
    """PPO-L-RSS's policy against PPO-L-SI's on the confirmation's fresh seeds (100000 + i), paired."""
    result = {}
    for traffic in TRAFFIC:
        si_dir = folder(CONFIRMATION["ppo_lsi"], traffic, CONFIRMATION_SEED)
        si_row, si_frame = method_row(si_dir, resamples, seed)
        directory = folder(CONFIRMATION["ppo_lsi_rss"], traffic, CONFIRMATION_SEED)
        row, frame = method_row(directory, resamples, seed)
        difference = paired_differences(frame, si_frame, resamples, seed)
        result[traffic] = {"ppo_lsi": {**si_row, "directory": str(si_dir)},
                           "ppo_lsi_rss": {**row, "directory": str(directory), "minus_ppo_lsi": difference,
                                           "verdicts": difference_verdicts(difference)}}
    return result


def recommendation(rows: dict) -> dict:
    """The parameter set by the rule of the module docstring, on the policies (``ppo_lsi/<agent>`` rows)."""
    excluded = sorted(agent for agent in AGENTS
                      if any(rows[t][f"ppo_lsi/{agent}"]["verdicts"]["J_c"] == "less safe" for t in TRAFFIC))
    cost = {agent: sum(rows[t][f"ppo_lsi/{agent}"]["mean_event_cost"] for t in TRAFFIC) for agent in AGENTS}
    candidates = sorted((agent for agent in AGENTS if agent not in excluded), key=lambda agent: cost[agent])
    chosen = candidates[0] if candidates else None
    if len(candidates) > 1:
        slower_by = max(rows[t][f"ppo_lsi/{candidates[1]}"]["mean_vx"] - rows[t][f"ppo_lsi/{chosen}"]["mean_vx"]
                        for t in TRAFFIC)
        chosen = chosen if slower_by <= SPEED_TOLERANCE_MPS else candidates[1]
    return {"agent": chosen, "source": PARAMETER_SETS[chosen][0] if chosen else None, "summed_policy_J_c": cost,
            "excluded_less_safe_than_ppo_lsi": excluded, "speed_tolerance_mps": SPEED_TOLERANCE_MPS}


def markdown(result: dict) -> str:
    lines = ["# A safety index built on Responsibility-Sensitive Safety (PPO-L-RSS)", "",
             "The paper's barrier phi = (sigma + d_safe)^n - d^n - k d_dot per observed vehicle, with d_safe the "
             "pair's "
             "RSS distance instead of the constant d_min = 1 m (`scenario.safety_index.kind=rss`, "
             "`srmpc/scenario/safety_index.py`): same lane, longitudinal "
             "d = [v_r rho + a_acc rho^2 / 2 + (v_r + rho a_acc)^2 / (2 b_min) - v_f^2 / (2 b_max)]_+ "
             "(the vehicle behind "
             "is the rear one); other lane, lateral d = mu + [(2 v_1 + rho a) rho / 2 + (v_1 + rho a)^2 / (2 b) "
             "- ((2 v_2 - rho a) rho / 2 - (v_2 - rho a)^2 / (2 b))]_+ (vehicle 1 the left one). Road edges keep the "
             "paper's term. Everything else is PPO-L-SI's (conf/agent/ppo_lsi.yaml), 20M environment steps per "
             "seed.", "",
             "## Parameter sets", "",
             "| agent | source | rho ego / others [s] | a_acc / b_min / b_max [m/s^2] | lateral a / b [m/s^2], mu [m] "
             "| d_lon 25 behind 25 m/s [m] | d_lon 25 behind 20 m/s [m] | d_lat, both still [m] |",
             "|---|---|---|---|---|---|---|---|"]
    for agent, s in result["parameter_sets"].items():
        p = s["parameters"]
        lines.append(
            f"| {AGENTS[agent]} | {s['source']} | {p['response_time_ego_s']} / {p['response_time_others_s']} | "
            f"{p['longitudinal_acceleration_max_mps2']} / {p['longitudinal_brake_min_mps2']} / "
            f"{p['longitudinal_brake_max_mps2']} | {p['lateral_acceleration_max_mps2']} / "
            f"{p['lateral_brake_min_mps2']}, {p['lateral_margin_m']} | {s['longitudinal_m']['25_behind_25']:.1f} | "
            f"{s['longitudinal_m']['25_behind_20']:.1f} | {s['lateral_m']['both_still']:.2f} |")
    lines += ["", "The paper's index asks for sigma + d_min = 1.5 m plus k = 1 s times the closing speed, whatever the "
              "speeds.", "",
              "## Training (end of training: the last 5% of the 20M steps; mean over seeds, 95% Student-t CI)",
              "", "| agent | seeds | J_r | J_c | rho_c | v_x [m/s] |", "|---|---|---|---|---|---|"]
    for agent, r in result["training"].items():
        cell = lambda key, digits, r=r: (f"{r[key]:.{digits}f}" + (  # noqa: E731
            f" [{r[f'{key}_ci95'][0]:.{digits}f}, {r[f'{key}_ci95'][1]:.{digits}f}]" if r[f"{key}_ci95"] else ""))
        lines.append(f"| {TRAINING_AGENTS[agent]} | {len(r['seeds'])} | {cell('return', 0)} | {cell('cost_return', 3)} "
                     f"| {cell('cost_rate', 6)} | {cell('vx', 2)} |")
    claim = result["training_claim"]
    interval = lambda values, fmt: f"[{values[0]:{fmt}}, {values[1]:{fmt}}]" if values else "[-]"  # noqa: E731
    lines += ["", f"The paper's training claim for PPO-L-RSS ({claim['statement']}): **{claim['verdict']}** "
              f"(rule: {claim['rule']}). Pooled over the seeds: cost-rate ratio PPO-L-RSS / PPO "
              f"{claim['cost_rate_ratio_rss_over_ppo']:.2f} "
              f"{interval(claim['cost_rate_ratio_rss_over_ppo_ci95'], '.2f')}, return difference "
              f"{claim['return_difference_rss_minus_ppo']:+.0f} "
              f"{interval(claim['return_difference_rss_minus_ppo_ci95'], '+.0f')}. Per seed: "
              + "; ".join(f"seed {s}: ratio {v['cost_rate_ratio_rss_over_ppo']:.2f} "
                          f"{interval(v['cost_rate_ratio_rss_over_ppo_ci95'], '.2f')} ({v['events'][0]} against "
                          f"{v['events'][1]} events), {v['verdict']}" for s, v in claim["per_seed"].items())
              + "."]
    lines += ["", "## Evaluation (1000 episodes per traffic level on the table's seeds; 95% CIs)", ""]
    for traffic in TRAFFIC:
        rows = result["evaluation"][traffic]
        lines += [f"### {traffic} traffic", "", "| method | proposer / policy | J_r | J_c | rho_c | v_x [m/s] |",
                  "|---|---|---|---|---|---|"]
        for key, r in rows.items():
            method, agent = key.split("/")
            lines.append(f"| {METHODS[method][0]} | {TRAINING_AGENTS[agent]} | {ci(r, 'mean_return', 0)} | "
                         f"{ci(r, 'mean_event_cost', 3)} | {ci(r, 'cost_rate', 4)} | {ci(r, 'mean_vx', 2)} |")
        lines += ["", "Paired differences, RSS minus PPO-L-SI on the same seeds (mean [95% CI]):", "",
                  "| method | proposer / policy | ΔJ_r | ΔJ_c | Δv_x [m/s] | verdict |", "|---|---|---|---|---|---|"]
        for key, r in rows.items():
            if "minus_ppo_lsi" not in r:
                continue
            method, agent = key.split("/")
            d, v = r["minus_ppo_lsi"], r["verdicts"]
            sign = lambda key, digits, d=d: (f"{d[key]:+.{digits}f} [{d[f'{key}_ci95'][0]:+.{digits}f}, "  # noqa: E731
                                             f"{d[f'{key}_ci95'][1]:+.{digits}f}]")
            lines.append(f"| {METHODS[method][0]} | {TRAINING_AGENTS[agent]} | {sign('mean_return', 0)} | "
                         f"{sign('mean_event_cost', 3)} | {sign('mean_vx', 2)} | {v['J_c']}, {v['v_x']} |")
        lines.append("")
    lines += ["### The policies on fresh seeds (100000 + i, 1000 episodes per traffic level)", "",
              "| traffic | policy | J_c | v_x [m/s] | ΔJ_c (RSS - SI) | Δv_x [m/s] | verdict |",
              "|---|---|---|---|---|---|---|"]
    for traffic in TRAFFIC:
        rows = result["confirmation"][traffic]
        d, v = rows["ppo_lsi_rss"]["minus_ppo_lsi"], rows["ppo_lsi_rss"]["verdicts"]
        lines.append(f"| {traffic} | PPO-L-SI | {ci(rows['ppo_lsi'], 'mean_event_cost', 3)} | "
                     f"{ci(rows['ppo_lsi'], 'mean_vx', 2)} | | | |")
        lines.append(f"| {traffic} | PPO-L-RSS | {ci(rows['ppo_lsi_rss'], 'mean_event_cost', 3)} | "
                     f"{ci(rows['ppo_lsi_rss'], 'mean_vx', 2)} | {d['mean_event_cost']:+.3f} "
                     f"[{d['mean_event_cost_ci95'][0]:+.3f}, {d['mean_event_cost_ci95'][1]:+.3f}] | "
                     f"{d['mean_vx']:+.2f} "
                     f"[{d['mean_vx_ci95'][0]:+.2f}, {d['mean_vx_ci95'][1]:+.2f}] | {v['J_c']}, {v['v_x']} |")
    lines.append("")
    rec = result["recommendation"]
    excluded = ", ".join(AGENTS[a] for a in rec["excluded_less_safe_than_ppo_lsi"]) or "none"
    chosen = (f"**{rec['source']}** ({AGENTS[rec['agent']]}, its policy's J_c summed over both levels "
              f"{rec['summed_policy_J_c'][rec['agent']]:.3f})" if rec["agent"] else "**none**")
    lines += ["## Verdicts", ""] + [f"- {v}" for v in result["verdicts"]] + [
        f"- Recommended parameter set: {chosen}. The rule (pipelines/rss.py) judges a set by the policy it trains: "
        f"excluded as less safe than PPO-L-SI's policy in a traffic level: {excluded}; then the lower J_c unless "
        f"{rec['speed_tolerance_mps']} m/s slower. ad-rss-lib's set was trained on one seed only."]
    return "\n".join(lines) + "\n"


def verdicts(result: dict) -> list[str]:
    """Per traffic level and method, PPO-L-RSS against PPO-L-SI; then the proposal's two questions."""
    out = []
    for traffic in TRAFFIC:
        rows = result["evaluation"][traffic]
        for method, (label, _) in METHODS.items():
            v = rows[f"{method}/ppo_lsi_rss"]["verdicts"]
            out.append(f"{traffic}, {label}, PPO-L-RSS against PPO-L-SI: J_c {v['J_c']}, v_x {v['v_x']}.")
    for traffic in TRAFFIC:
        v = result["confirmation"][traffic]["ppo_lsi_rss"]["verdicts"]
        out.append(f"{traffic}, policy, fresh seeds (100000 + i), PPO-L-RSS against PPO-L-SI: J_c {v['J_c']}, "
                   f"v_x {v['v_x']}.")
    policy = [result["evaluation"][t]["ppo_lsi/ppo_lsi_rss"]["verdicts"] for t in TRAFFIC]
    proposer = [result["evaluation"][t][f"{m}/ppo_lsi_rss"]["verdicts"]
                for t in TRAFFIC for m in METHODS if m != "ppo_lsi"]
    safer_policy = all(v["J_c"] == "safer" for v in policy)
    faster_policy = all(v["v_x"] == "faster" for v in policy)
    better_proposer = (all(v["J_c"] != "less safe" and v["v_x"] != "slower" for v in proposer)
                       and any(v["J_c"] == "safer" or v["v_x"] == "faster" for v in proposer))
    out.append(f"A safer policy: {'yes' if safer_policy else 'no'}; "
               f"a faster policy: {'yes' if faster_policy else 'no'} "
               "(PPO-L-RSS against PPO-L-SI, both traffic levels).")
    out.append("A better proposer for SRMPC (no worse on J_c and v_x at both planner settings and traffic levels, "
               "better "
               f"on one): {'yes' if better_proposer else 'no'}.")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    summary = json.loads(TRAINING_SUMMARY.read_text())
    if "paper_claim_ppo_lsi_rss" not in summary:
        raise SystemExit(f"rss: {TRAINING_SUMMARY} has no PPO-L-RSS (run DVC stages train_rss, training_figure first)")
    result = {"parameter_sets": parameter_sets(), "training": training_rows(summary),
              "training_claim": summary["paper_claim_ppo_lsi_rss"], "evaluation": evaluation(args.resamples, args.seed)}
    result["confirmation"] = confirmation(args.resamples, args.seed)
    result["verdicts"] = verdicts(result)
    result["recommendation"] = recommendation(result["evaluation"])
    text = markdown(result)
    write_outputs({Path("results/rss.md"): text, Path("results/rss.json"): json.dumps(result, indent=2) + "\n"})
    print(text)


if __name__ == "__main__":
    main()
