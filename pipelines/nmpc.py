"""DVC stage ``nmpc``: the NMPC solved to convergence in closed loop, from each initial guess, beside LTV-MPC and
SRMPC at the same planner config; and the initial-guess study it rests on.

    python -m pipelines.nmpc

Reads, at each planner config (the table's, ``planner=ltv_mpc``, and the paper's operating point,
``planner=paper_operating_point``) and traffic level, on the table's episodes (episode i from seed i, 1000 each):

- experiments ``nmpc/<guess>[_paper_operating_point]``: the NMPC (``srmpc/mpc/nmpc/sqp.py``) started from constant
  velocity in the lane, from its shifted previous solution, from the policy's rollout (the paper's proposal) and
  from the better of the last two (AC4MPC's rule);
- LTV-MPC and SRMPC at the same config: experiments ``table/<method>`` (the table's runs) and
  ``operating_point/<method>`` (the operating point's), each folder found by the experiment its ``config.yaml``
  names (:data:`EXPERIMENTS`);
- ``results/benchmarks/nmpc_initial_guess.json``: SQP iterations, time and optimum per guess on 300 recorded states
  (the lowest optimum over every solver's optimum for a state, out of all states), the agreement with CasADi +
  IPOPT, IPOPT's KKT certification of every converged plan and the NMPC's own KKT residual.

Writes ``results/nmpc.json`` (``[planner][traffic][method]``: the table metrics with 95% CIs, the share of steps
whose SQP converged, and ``paired`` differences against LTV-MPC and SRMPC; ``verdicts``; ``initial_guess_study``)
and ``results/nmpc.md``.

Verdicts, each on the paired difference of two methods on the same seeds: a metric "changes" only when its 95% CI
excludes 0 (``reporting.sign``). Solving to convergence is judged on the two pairs that share an initial guess:
NMPC from the shifted previous solution against LTV-MPC (which linearizes about that guess) and NMPC from the
rollout against SRMPC (which linearizes about the rollout). The RL guess in closed loop: NMPC from the rollout
against NMPC from constant velocity and from the shifted previous solution.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from pipelines.reporting import ci, difference, method_row, run_of, sign, write_outputs
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences

STUDY = Path("results/benchmarks/nmpc_initial_guess.json")
PLANNERS = {"ltv_mpc": "the table's planner config (`planner=ltv_mpc`)",
            "paper_operating_point": "the paper's operating point (`planner=paper_operating_point`)"}
TRAFFIC = ("light", "dense")
METHODS = {"ltv_mpc": "LTV-MPC", "srmpc": "SRMPC (Algorithm 1)",
           "nmpc_constant_velocity": "NMPC from constant velocity", "nmpc": "NMPC from the shifted previous solution",
           "nmpc_rollout": "NMPC from the policy's rollout", "nmpc_best_of_two": "NMPC, best of two (AC4MPC)"}
"""Method -> label; the first two are the comparators every NMPC row is paired with."""
EXPERIMENTS = {"ltv_mpc": {"ltv_mpc": "table/ltv_mpc", "paper_operating_point": "operating_point/ltv_mpc"},
               "srmpc": {"ltv_mpc": "table/srmpc", "paper_operating_point": "operating_point/srmpc"},
               **{method: {"ltv_mpc": f"nmpc/{guess}", "paper_operating_point": f"nmpc/{guess}_paper_operating_point"}
                  for method, guess in (("nmpc_constant_velocity", "constant_velocity"), ("nmpc", "shifted"),
                                        ("nmpc_rollout", "rollout"), ("nmpc_best_of_two", "best_of_two"))}}
"""Method -> planner option -> its experiment (conf/experiment/<experiment>.yaml)."""
COMPARATORS = ("ltv_mpc", "srmpc")
EXTRA_PAIRS = {"nmpc_best_of_two": ("nmpc_rollout",)}
"""Further paired differences in a row's ``paired``: best of two against its own solve from the rollout (what the
second solve from the shifted previous solution changes)."""
CONVERGENCE_PAIRS = (("nmpc", "ltv_mpc"), ("nmpc_rollout", "srmpc"))
"""(converged, one QP) about the same initial guess: what solving to convergence changes."""
GUESS_PAIRS = (("nmpc_rollout", "nmpc_constant_velocity"), ("nmpc_rollout", "nmpc"))
"""The policy's rollout against the other guesses, both converged: what the RL guess changes in closed loop."""
VERDICT_METRICS = {"mean_event_cost": ("J_c", ("less safe", "safer")), "mean_vx": ("v_x", ("faster", "slower")),
                   "mean_return": ("J_r", ("higher return", "lower return"))}
"""Paired metric -> (label, (word when the CI is above 0, word when below))."""
STUDY_KEYS = ("per_guess", "lowest_optimum", "agreement_with_ipopt", "kkt_certification_by_ipopt", "kkt_residual",
              "machine")
"""The keys of ``results/benchmarks/nmpc_initial_guess.json`` the report carries."""
STUDY_GUESSES = {"constant_velocity": "constant velocity", "shifted_previous": "shifted previous",
                 "policy_rollout": "policy rollout", "best_of_two": "best of two"}


def folders(planner: str, traffic: str) -> dict[str, Path]:
    """Method -> its evaluation folder at planner option ``planner`` in ``traffic`` (:data:`EXPERIMENTS`), found by
    the experiment its config.yaml names."""
    return {method: run_of(EXPERIMENTS[method][planner], traffic) for method in METHODS}


def converged_share(outcomes: dict) -> float:
    """The share of steps whose planner solved (the NMPC: its SQP converged); the rest used the fallback chain."""
    steps = outcomes["solved"] + outcomes["shifted_previous"] + outcomes["emergency_brake"]
    return outcomes["solved"] / steps


def verdicts(paired: dict) -> dict[str, str]:
    """Per metric of ``VERDICT_METRICS``: its word when the paired CI excludes 0, else "no difference resolved"."""
    words = {}
    for key, (label, (above, below)) in VERDICT_METRICS.items():
        side = sign(paired[f"{key}_ci95"])
        words[label] = above if side > 0 else below if side < 0 else "no difference resolved"
    return words


def closed_loop(resamples: int, seed: int) -> tuple[dict, list[dict]]:
    """Rows per planner and traffic, and the verdicts on the pairs of ``CONVERGENCE_PAIRS`` and ``GUESS_PAIRS``."""
    result: dict = {}
    judged: list[dict] = []
    for planner in PLANNERS:
        result[planner] = {}
        for traffic in TRAFFIC:
            rows, frames = {}, {}
            for method, directory in folders(planner, traffic).items():
                rows[method], frames[method] = method_row(directory, resamples, seed)
                rows[method]["directory"] = str(directory)
                rows[method]["converged_share"] = converged_share(rows[method]["outcomes"])
            for method in METHODS:
                if method not in COMPARATORS:
                    rows[method]["paired"] = {other: paired_differences(frames[method], frames[other], resamples, seed)
                                              for other in (*COMPARATORS, *EXTRA_PAIRS.get(method, ()))}
            for kind, pairs in (("convergence", CONVERGENCE_PAIRS), ("initial_guess", GUESS_PAIRS)):
                for a, b in pairs:
                    paired = paired_differences(frames[a], frames[b], resamples, seed)
                    judged.append({"kind": kind, "planner": planner, "traffic": traffic, "a": a, "b": b,
                                   "paired": paired, "verdicts": verdicts(paired)})
            result[planner][traffic] = rows
    return result, judged


def study_lines(study: dict) -> list[str]:
    """The per-guess table; "at the lowest optimum" counts states out of all, a failed solve as not at it."""
    lowest = study["lowest_optimum"]
    lines = ["| guess | SQP iterations median / p99 | ms median / p99 | failures | NMPC at the lowest optimum | "
             "IPOPT (same guess) at the lowest optimum | IPOPT iterations median |", "|---|---|---|---|---|---|---|"]
    for key, label in STUDY_GUESSES.items():
        g = study["per_guess"][key]
        ipopt = (f"{g['ipopt_states_at_lowest_optimum']} of {g['states']} "
                 f"({g['ipopt_share_of_states_at_lowest_optimum']:.0%})" if "ipopt_states_at_lowest_optimum" in g
                 else "–")
        lines.append(f"| {label} | {g['iterations_median']:.0f} / {g['iterations_p99']:.0f} | "
                     f"{g['time_median_ms']:.1f} / {g['time_p99_ms']:.0f} | {g['failures']} of {g['states']} | "
                     f"{g['states_at_lowest_optimum']} of {g['states']} ({g['share_of_states_at_lowest_optimum']:.0%}) "
                     f"| {ipopt} | {g['ipopt_iterations_median']:.0f} |")
    machine = study.get("machine")
    if machine:
        before, after = machine["load_average_1_5_15min_before"][0], machine["load_average_1_5_15min_after"][0]
        lines += ["", f"Times: one core of a {machine['cpus']}-core machine whose 1-minute load average was "
                      f"{before:.1f} before the run and {after:.1f} after it (other jobs ran beside it): compare them "
                      f"with each other, not with other runs."]
    lines += ["", f"The lowest optimum of a state: the lowest objective among every solver's optimum for it (the "
                  f"NMPC's converged plans from the three guesses and IPOPT's successful solves from the same "
                  f"guesses); a solve is at it within {lowest['objective_tolerance_relative']:g} relative, and a "
                  f"failed solve is not. Of the {lowest['states']} states, the NMPC from some guess reached it in "
                  f"{lowest['found_by_nmpc_from_some_guess']}, IPOPT from some guess in "
                  f"{lowest['found_by_ipopt_from_some_guess']}; only IPOPT in {lowest['found_by_ipopt_only']}, "
                  f"only the NMPC in {lowest['found_by_nmpc_only']}."]
    return lines


def agreement_lines(agreement: dict) -> list[str]:
    """The agreement with CasADi + IPOPT from the same guesses, one sentence per guess."""
    tolerances = agreement["tolerances"]
    lines = [f"Against CasADi + IPOPT from the same guesses (agree: objective within "
             f"{tolerances['objective_relative']:g} relative, first input within {tolerances['first_input']:g}, "
             f"trajectory within {tolerances['trajectory_m']:g} m):", ""]
    for key, label in {**STUDY_GUESSES, "all_guesses": "all three guesses"}.items():
        a = agreement.get(key)
        if a:
            lines.append(f"- {label}: {a['agree']} of {a['both_converged']} pairs where both converged agree "
                         f"({a['agreement_rate']:.0%}); {a['different_local_optima']} reach different local optima "
                         f"(our plan certified below), ours lower in {a['nmpc_lower']}, IPOPT's in "
                         f"{a['ipopt_lower']}; in {a['disagree_nmpc_not_certified']} IPOPT does not certify our plan.")
    return lines


def certification_lines(certification: dict, kkt: dict) -> list[str]:
    """IPOPT's KKT certification of every converged plan, each failure described, and the NMPC's KKT residual."""
    total = certification["all_guesses"]
    per_guess = "; ".join(f"{label} {certification[key]['certified']} of {certification[key]['converged_plans']}"
                          for key, label in STUDY_GUESSES.items() if key in certification)
    lines = [f"KKT certification ({certification['criterion']}): {total['certified']} of the "
             f"{total['converged_plans']} converged plans are KKT points of IPOPT's NLP ({per_guess})"
             + (f"; {total['not_certified']} are not:" if total["not_certified"] else "."), ""]
    for f in certification["not_certified"]:
        nmpc, warm, cold = f["nmpc"], f["ipopt_warm_at_the_plan"], f["ipopt_cold_from_the_same_guess"]
        move = warm["largest_move"]
        lines.append(
            f"- state {f['state']} ({f['traffic']}, {f['n_observed']} observed), {STUDY_GUESSES[f['guess']]}: the "
            f"NMPC converged in {nmpc['iterations']} iterations (theta {nmpc['primal_infeasibility']:.1e}, step "
            f"{nmpc['step_norm']:.1e}, KKT error E {nmpc['kkt_error']:.1e}: stationarity "
            f"{nmpc['kkt_stationarity']:.1e}, complementarity {nmpc['kkt_complementarity']:.1e}) at F = "
            f"{nmpc['objective']:.2f}; IPOPT started there: {warm['ipopt_status']} after {warm['ipopt_iterations']} "
            f"iterations, its largest move {move['state']} at stage {move['stage']} from {move['nmpc']:.2f} to "
            f"{move['ipopt']:.2f}, the first input by {warm['first_input_drift']:.2g}, F "
            f"{warm['objective_change']:+.2f} ({warm['objective_change'] / nmpc['objective']:+.1%}; its final "
            f"primal / dual infeasibility {warm['ipopt_primal_infeasibility']:.1e} / "
            f"{warm['ipopt_dual_infeasibility']:.1e}); IPOPT from the same guess "
            f"{'agrees' if cold['agree'] else 'does not agree'} (F = {cold['objective']:.2f}).")
    if kkt:
        error, counts = kkt["error"], kkt["plans_with_error_at_most"]
        below = ", ".join(f"{count} at most {level}" for level, count in counts.items())
        text = (f"The NMPC's own KKT residual with the last QP's multipliers (IPOPT's scaled error E; "
                f"`srmpc/mpc/nmpc/kkt_residual.py`), reported beside its convergence test: over the "
                f"{kkt['converged_plans']} converged plans E median {error['median']:.1e}, p90 {error['p90']:.1e}, "
                f"p99 {error['p99']:.1e}, max {error['max']:.1e} ({below}).")
        if kkt["error_not_certified"]:
            text += (" The plans IPOPT does not certify have E "
                     + ", ".join(f"{e:.1e}" for e in kkt["error_not_certified"])
                     + f" ({', '.join(str(r) for r in kkt['rank_of_not_certified'])} of the "
                       f"{kkt['converged_plans']} plans have a smaller E); the certified ones median "
                       f"{kkt['error_certified']['median']:.1e}, max {kkt['error_certified']['max']:.1e}.")
        lines += ["", text]
    return lines


def markdown(result: dict) -> str:
    lines = ["# NMPC solved to convergence, from four initial guesses", "",
             "The planner's OCP without linearization (`srmpc/mpc/nmpc/sqp.py`: SQP on the exact bicycle and ellipse "
             "constraints, `riccati_ipm` subproblems, l1 merit line search; converged: NLP infeasibility <= 1e-6 and "
             "QP step <= 1e-4 within 50 iterations, a KKT proxy without multipliers; the KKT residual with "
             "multipliers and IPOPT's certification are reported below). A step whose SQP does not converge falls "
             "back to LTV-MPC's chain (the last plan shifted, else the emergency brake).", "",
             f"## The initial-guess study (`{result['initial_guess_study']['source']}`)", ""]
    lines += study_lines(result["initial_guess_study"]) + [""]
    study = result["initial_guess_study"]
    if study.get("agreement_with_ipopt"):
        lines += agreement_lines(study["agreement_with_ipopt"]) + [""]
    if study.get("kkt_certification_by_ipopt"):
        lines += certification_lines(study["kkt_certification_by_ipopt"], study.get("kkt_residual")) + [""]
    lines += ["## Closed loop", "",
              "1000 episodes per cell on the table's seeds (episode i from seed i, every method the same scenes). "
              "J_c: share of episodes ending in a collision or road exit (Wilson 95% CI); v_x [m/s] and J_r: "
              "bootstrap over episodes; converged: the share of steps whose planner solved. Differences are paired "
              "on the seeds (mean [95% CI]).", ""]
    for planner, title in PLANNERS.items():
        for traffic in TRAFFIC:
            rows = result[planner][traffic]
            lines += [f"### {traffic} traffic, {title}", "",
                      "| method | J_c | v_x [m/s] | J_r | n_steps | converged | ΔJ_c vs LTV-MPC | Δv_x vs LTV-MPC | "
                      "ΔJ_c vs SRMPC | Δv_x vs SRMPC |", "|---|---|---|---|---|---|---|---|---|---|"]
            for method, label in METHODS.items():
                r = rows[method]
                paired = r.get("paired")
                deltas = ["–"] * 4 if paired is None else [
                    difference(paired[other], key, digits) for other in COMPARATORS
                    for key, digits in (("mean_event_cost", 3), ("mean_vx", 2))]
                lines.append(f"| {label} | {ci(r, 'mean_event_cost', 3)} | {ci(r, 'mean_vx', 2)} | "
                             f"{ci(r, 'mean_return', 0)} | {r['mean_n_steps']:.0f} | {r['converged_share']:.1%} | "
                             + " | ".join(deltas) + " |")
            lines.append("")
    for kind, title in (("convergence", "What solving to convergence changes (same initial guess)"),
                        ("initial_guess", "What the policy's rollout changes as the NMPC's initial guess")):
        lines += [f"## {title}", "", "| pair | planner | traffic | ΔJ_c | Δv_x | ΔJ_r | verdict |",
                  "|---|---|---|---|---|---|---|"]
        for v in result["verdicts"]:
            if v["kind"] == kind:
                d = v["paired"]
                lines.append(f"| {METHODS[v['a']]} - {METHODS[v['b']]} | {v['planner']} | {v['traffic']} | "
                             f"{difference(d, 'mean_event_cost', 3)} | {difference(d, 'mean_vx', 2)} | "
                             f"{difference(d, 'mean_return', 0)} | "
                             + ", ".join(f"{k}: {w}" for k, w in v["verdicts"].items()) + " |")
        lines.append("")
    lines += ["## Verdict", ""] + [f"- {s}" for s in result["summary"]] + [""]
    return "\n".join(lines)


def summary(judged: list[dict], study: dict) -> list[str]:
    """The answers in sentences: counts of cells where each metric changes, and the study's iteration saving."""
    sentences = []
    for kind, question in (("convergence", "Solving to convergence, against one QP about the same guess"),
                           ("initial_guess", "The rollout as the NMPC's guess, against the other two guesses")):
        cells = [v for v in judged if v["kind"] == kind]
        counts = {label: sum(w != "no difference resolved" for w in [v["verdicts"][label] for v in cells])
                  for label in ("J_c", "v_x", "J_r")}
        sentences.append(f"{question}: J_c changes in {counts['J_c']} of {len(cells)} paired cells, v_x in "
                         f"{counts['v_x']}, J_r in {counts['J_r']}.")
    guesses = study["per_guess"]
    rollout, constant = guesses["policy_rollout"], guesses["constant_velocity"]
    shifted = guesses["shifted_previous"]
    sentences.append(
        f"On the study's {rollout['states']} states the rollout takes {rollout['iterations_median']:.0f} median SQP "
        f"iterations against "
        f"{constant['iterations_median']:.0f} from constant velocity and {shifted['iterations_median']:.0f} from the "
        f"shifted previous solution ({rollout['time_median_ms']:.1f} against {constant['time_median_ms']:.1f} and "
        f"{shifted['time_median_ms']:.1f} ms median) and reaches the lowest optimum that any solver found (the "
        f"NMPC from any guess or IPOPT) in {rollout['states_at_lowest_optimum']} of {rollout['states']} states "
        f"({constant['states_at_lowest_optimum']} and {shifted['states_at_lowest_optimum']} of {shifted['states']}; "
        f"failures counted as not reaching it).")
    return sentences


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    study = json.loads(STUDY.read_text())
    rows, judged = closed_loop(args.resamples, args.seed)
    result = {**rows, "verdicts": judged, "summary": summary(judged, study),
              "initial_guess_study": {"source": str(STUDY), **{key: study.get(key) for key in STUDY_KEYS}}}
    text = markdown(result)
    write_outputs({Path("results/nmpc.md"): text, Path("results/nmpc.json"): json.dumps(result, indent=2) + "\n"})
    print(text)


if __name__ == "__main__":
    main()
