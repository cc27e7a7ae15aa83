"""DVC stage ``nmpc``: the NMPC solved to convergence in closed loop, from each initial guess, beside LTV-MPC and
SRMPC at the same planner config; and the initial-guess study it rests on.

    python -m pipelines.nmpc

Reads, at each planner config (the table's, ``planner=ltv_mpc``, and the paper's operating point,
``planner=paper_operating_point``) and traffic level, on the table's episodes (episode i from seed i, 1000 each):

- ``results/evaluation/nmpc/``: the NMPC (``srmpc/mpc/nmpc.py``) started from constant velocity in the lane, from
  its shifted previous solution, from the policy's rollout (the paper's proposal) and from the better of the last
  two (AC4MPC's rule) (DVC stage ``evaluate_nmpc``);
- LTV-MPC and SRMPC at the same config: ``results/evaluation/twin/`` (the table's runs) and
  ``results/evaluation/tradeoff/`` (the operating point's), each folder found by its ``config.yaml``;
- ``results/benchmarks/nmpc_initial_guess.json``: SQP iterations, time and optimum per guess on 300 recorded states,
  and the agreement with CasADi + IPOPT.

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

from omegaconf import OmegaConf

from pipelines.reporting import ci, difference, evaluations, method_row, settings_of, sign, write_outputs
from srmpc.confidence_intervals import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, paired_differences
from srmpc.config.compose import compose_config

ROOTS = (Path("results/evaluation/nmpc"), Path("results/evaluation/twin"), Path("results/evaluation/tradeoff"))
STUDY = Path("results/benchmarks/nmpc_initial_guess.json")
PLANNERS = {"ltv_mpc": "the table's planner config (`planner=ltv_mpc`)",
            "paper_operating_point": "the paper's operating point (`planner=paper_operating_point`)"}
TRAFFIC = ("light", "dense")
METHODS = {"ltv_mpc": "LTV-MPC", "srmpc": "SRMPC (Algorithm 1)",
           "nmpc_constant_velocity": "NMPC from constant velocity", "nmpc": "NMPC from the shifted previous solution",
           "nmpc_rollout": "NMPC from the policy's rollout", "nmpc_best_of_two": "NMPC, best of two (AC4MPC)"}
"""Method (``reporting.method_of``) -> label; the first two are the comparators every NMPC row is paired with."""
COMPARATORS = ("ltv_mpc", "srmpc")
CONVERGENCE_PAIRS = (("nmpc", "ltv_mpc"), ("nmpc_rollout", "srmpc"))
"""(converged, one QP) about the same initial guess: what solving to convergence changes."""
GUESS_PAIRS = (("nmpc_rollout", "nmpc_constant_velocity"), ("nmpc_rollout", "nmpc"))
"""The policy's rollout against the other guesses, both converged: what the RL guess changes in closed loop."""
VERDICT_METRICS = {"mean_event_cost": ("J_c", ("less safe", "safer")), "mean_vx": ("v_x", ("faster", "slower")),
                   "mean_return": ("J_r", ("higher return", "lower return"))}
"""Paired metric -> (label, (word when the CI is above 0, word when below))."""
STUDY_GUESSES = {"constant_velocity": "constant velocity", "shifted_previous": "shifted previous",
                 "policy_rollout": "policy rollout", "best_of_two": "best of two"}


def folders(planner: str, traffic: str) -> dict[str, Path]:
    """Method -> its evaluation folder at ``planner``'s settings in ``traffic`` on the table's seeds, read from
    each folder's config.yaml (never its name); two folders for one method are an error."""
    settings = OmegaConf.to_container(compose_config([f"planner={planner}"]).planner, resolve=True)
    wanted = settings_of({"planner": settings})
    found: dict[str, Path] = {}
    for directory, experiment in evaluations(*ROOTS):
        if (experiment["traffic"], experiment["seed"], experiment["simulator"]) == (traffic, 0, "twin") and \
                experiment["settings"] == wanted and experiment["method"] in METHODS:
            if experiment["method"] in found:
                raise SystemExit(f"nmpc: {directory} and {found[experiment['method']]} both hold "
                                 f"{experiment['method']} in {traffic} traffic at planner={planner}")
            found[experiment["method"]] = directory
    missing = [method for method in METHODS if method not in found]
    if missing:
        raise SystemExit(f"nmpc: no finished {', '.join(missing)} evaluation in {traffic} traffic at "
                         f"planner={planner} (run dvc repro evaluate_nmpc first)")
    return found


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
                                              for other in COMPARATORS}
            for kind, pairs in (("convergence", CONVERGENCE_PAIRS), ("initial_guess", GUESS_PAIRS)):
                for a, b in pairs:
                    paired = paired_differences(frames[a], frames[b], resamples, seed)
                    judged.append({"kind": kind, "planner": planner, "traffic": traffic, "a": a, "b": b,
                                   "paired": paired, "verdicts": verdicts(paired)})
            result[planner][traffic] = rows
    return result, judged


def study_lines(study: dict) -> list[str]:
    lines = ["| guess | SQP iterations median / p99 | ms median / p99 | failures | at the lowest optimum | "
             "IPOPT iterations median |", "|---|---|---|---|---|---|"]
    for key, label in STUDY_GUESSES.items():
        g = study["per_guess"][key]
        lines.append(f"| {label} | {g['iterations_median']:.0f} / {g['iterations_p99']:.0f} | "
                     f"{g['time_median_ms']:.1f} / {g['time_p99_ms']:.0f} | {g['failures']} / {g['states']} | "
                     f"{g['share_at_lowest_objective']:.0%} | {g['ipopt_iterations_median']:.0f} |")
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
                         f"({a['agreement_rate']:.0%}); {a['different_local_optima']} reach different local optima, "
                         f"ours lower in {a['nmpc_lower']}, IPOPT's in {a['ipopt_lower']}.")
    return lines


def markdown(result: dict) -> str:
    lines = ["# NMPC solved to convergence, from four initial guesses", "",
             "The planner's OCP without linearization (`srmpc/mpc/nmpc.py`: SQP on the exact bicycle and ellipse "
             "constraints, `riccati_ipm` subproblems, l1 merit line search; converged: NLP infeasibility <= 1e-6 and "
             "QP step <= 1e-4 within 50 iterations). A step whose SQP does not converge falls back to LTV-MPC's "
             "chain (the last plan shifted, else the emergency brake).", "",
             f"## The initial-guess study (`{result['initial_guess_study']['source']}`)", ""]
    lines += study_lines(result["initial_guess_study"]) + [""]
    agreement = result["initial_guess_study"].get("agreement_with_ipopt")
    if agreement:
        lines += agreement_lines(agreement) + [""]
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
        f"On the study's 300 states the rollout takes {rollout['iterations_median']:.0f} median SQP iterations against "
        f"{constant['iterations_median']:.0f} from constant velocity and {shifted['iterations_median']:.0f} from the "
        f"shifted previous solution ({rollout['time_median_ms']:.1f} against {constant['time_median_ms']:.1f} and "
        f"{shifted['time_median_ms']:.1f} ms median) and reaches the lowest optimum in "
        f"{rollout['share_at_lowest_objective']:.0%} of states ({constant['share_at_lowest_objective']:.0%} and "
        f"{shifted['share_at_lowest_objective']:.0%}).")
    return sentences


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=BOOTSTRAP_RESAMPLES, help="bootstrap resamples")
    parser.add_argument("--seed", type=int, default=BOOTSTRAP_SEED, help="bootstrap seed")
    args = parser.parse_args()
    study = json.loads(STUDY.read_text())
    rows, judged = closed_loop(args.resamples, args.seed)
    result = {**rows, "verdicts": judged, "summary": summary(judged, study),
              "initial_guess_study": {"source": str(STUDY), "per_guess": study["per_guess"],
                                      "agreement_with_ipopt": study.get("agreement_with_ipopt")}}
    text = markdown(result)
    write_outputs({Path("results/nmpc.md"): text, Path("results/nmpc.json"): json.dumps(result, indent=2) + "\n"})
    print(text)


if __name__ == "__main__":
    main()
