"""NMPC from four initial guesses, checked against CasADi + IPOPT, on states recorded in closed loop.

Writes results/benchmarks/nmpc_initial_guess.json and results/figures/nmpc_initial_guess.png.

Method: light and dense twin episodes (the committed config, ``tracking.enabled=false``, seeds
``2000 e`` / ``2000 e + 1``) are driven by LTV-MPC and by the paper's SRMPC; from step ``--warmup`` on,
every ``--stride``-th step's planner inputs are recorded: the measured state, the last input, the
observed vehicles' constant-velocity predictions, the tracking reference, the driving controller's
previous QP plan shifted by one step (its ``default_reference``: lane following at an episode's
first step) and the SRMPC policy's rollout in the same scene. On each state the NMPC (``srmpc.mpc.nmpc``,
SQP with our Riccati interior-point QP solver, the table's planner OCP) is solved from

- ``constant_velocity``: constant velocity in the closest lane (LTV-MPC's start, ``lane_following_reference``);
- ``shifted_previous``: the shifted previous solution;
- ``policy_rollout``: the policy's rollout (SRMPC's);
- ``best_of_two``: both of the last two, keeping the lower converged objective (AC4MPC's rule; its time
  and iterations are the sum of both solves);

and IPOPT (``srmpc.mpc.casadi_reference``, exact Hessian) from the same primal point. Timed: the
NMPC's whole solve, process pinned to one core, numba on one thread, after a warm-up solve.
Agreement with IPOPT: objective within ``AGREEMENT`` (relative), first input and trajectory within
their absolute tolerances. Where they disagree, IPOPT warm-started at the NMPC's solution (small barrier)
tells whether the NMPC's point is a KKT point of IPOPT's NLP (it then moves less than the trajectory
tolerance): then the two reached different local optima and the lower objective is counted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections import Counter
from pathlib import Path

import numba
import numpy as np

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller
from srmpc.mpc.nmpc import NmpcSolver
from srmpc.output_folder import atomic_write_text
from srmpc.sim.single_env import TwinScenarioEnv

OUTPUT = Path("results/benchmarks/nmpc_initial_guess.json")
FIGURE = Path("results/figures/nmpc_initial_guess.png")
GUESSES = ("constant_velocity", "shifted_previous", "policy_rollout")
"""Initial guesses solved directly; ``best_of_two`` combines the last two."""
AGREEMENT = {"objective_relative": 1e-3, "first_input": 1e-3, "trajectory_m": 1e-2}
"""NMPC vs IPOPT: |F - F_ipopt| / max(1, |F_ipopt|) (dimensionless), max |u_0 - u_0'| (rad, m/s^2),
max |x_k - x_k'| over the plan (m, rad, m/s). The objective's tolerance covers IPOPT's interior slacks: at
its tolerance they sit near 1e-8 instead of 0, and w_col,1 = 1e4 per unit makes that up to ~3e-4 of F when
the trajectories agree to 1e-7."""
TARGETS = {"policy_rollout_median_ms": 1.0, "rollout_fewer_median_iterations_than_constant_velocity": True}
"""Issue 30 (benchmark, not test): the NMPC step from the rollout median <= 1 ms on one core; fewer
median SQP iterations from the rollout than from constant velocity."""
MAX_OBSERVED = 6
"""Observation slots; recorded predictions are padded to this many vehicles."""


def record_states(states_per_run: int, stride: int, warmup: int, max_steps: int) -> dict[str, np.ndarray]:
    """Planner inputs of closed-loop steps (module doc), ``states_per_run`` per (traffic, driver)."""
    rows: dict[str, list] = {key: [] for key in (
        "ego", "last_input", "others", "n_observed", "tracking", "cv_states", "cv_inputs", "shifted_states",
        "shifted_inputs", "has_previous", "rollout_states", "rollout_inputs", "dense", "driver_srmpc")}
    for dense, traffic in enumerate(("light", "dense")):
        base = [f"+experiment={traffic}_traffic", "tracking.enabled=false"]
        srmpc_config = to_objects(compose_config(base + ["evaluation.controller=srmpc"]))
        ltv_config = to_objects(compose_config(base + ["evaluation.controller=ltv_mpc"]))
        env = TwinScenarioEnv(srmpc_config.scenario)
        srmpc = build_controller(srmpc_config, env)
        ltv = build_controller(ltv_config, env)
        for driver_srmpc, driver in enumerate((ltv, srmpc)):
            count, episode = 0, 0
            while count < states_per_run:
                observation, _ = env.reset(seed=2000 * episode + dense)
                driver.reset()
                srmpc.reset()
                for step in range(max_steps):
                    scene = env.unwrapped.measurement
                    if step >= warmup and (step - warmup) % stride == 0 and count < states_per_run:
                        rollout = srmpc.policy_rollout()
                        if rollout is not None:
                            planner = driver.planner
                            ego = np.asarray(scene.ego, dtype=np.float64)
                            observed = scene.slot_vehicle[scene.slot_vehicle >= 0]
                            predicted = planner.predict(scene.others[observed])
                            padded = np.zeros((planner.config.horizon + 1, MAX_OBSERVED, 4))
                            padded[:, :predicted.shape[1]] = predicted
                            cv_states, cv_inputs = planner.lane_following_reference(ego)
                            shifted_states, shifted_inputs, source = planner.default_reference(ego)
                            for key, value in (
                                    ("ego", ego), ("last_input", driver.last_input.copy()), ("others", padded),
                                    ("n_observed", predicted.shape[1]), ("tracking", driver.tracking_reference),
                                    ("cv_states", cv_states), ("cv_inputs", cv_inputs),
                                    ("shifted_states", shifted_states), ("shifted_inputs", shifted_inputs),
                                    ("has_previous", source.value == "shifted_previous"),
                                    ("rollout_states", rollout.ego[0]), ("rollout_inputs", rollout.actions[0]),
                                    ("dense", dense), ("driver_srmpc", driver_srmpc)):
                                rows[key].append(np.array(value))
                            count += 1
                    observation, _, terminated, truncated, _ = env.step(driver.act(observation, scene))
                    if terminated or truncated:
                        break
                episode += 1
    return {key: np.stack(values) for key, values in rows.items()}


def state_inputs(states: dict[str, np.ndarray], i: int) -> tuple:
    """(x_hat, u_hat, predictions (N + 1, V_obs, 4), x^ref) of recorded state i."""
    n = int(states["n_observed"][i])
    return states["ego"][i], states["last_input"][i], states["others"][i][:, :n], states["tracking"][i]


def guess_of(states: dict[str, np.ndarray], i: int, guess: str) -> tuple[np.ndarray, np.ndarray]:
    prefix = {"constant_velocity": "cv", "shifted_previous": "shifted", "policy_rollout": "rollout"}[guess]
    return states[f"{prefix}_states"][i], states[f"{prefix}_inputs"][i]


def compare(nmpc, ipopt) -> dict[str, float]:
    """Distances between two plans (``AGREEMENT``'s quantities) and whether they are within it."""
    objective = abs(nmpc.objective - ipopt.objective) / max(1.0, abs(ipopt.objective))
    first_input = float(np.abs(nmpc.inputs[0] - ipopt.inputs[0]).max())
    trajectory = float(np.abs(nmpc.states - ipopt.states).max())
    agree = (objective <= AGREEMENT["objective_relative"] and first_input <= AGREEMENT["first_input"]
             and trajectory <= AGREEMENT["trajectory_m"])
    return {"objective_relative": objective, "first_input": first_input, "trajectory": trajectory, "agree": agree}


def time_qp_against_hpipm(solver: NmpcSolver, hpipm_factory) -> dict:
    """Our Riccati interior-point solver and HPIPM on the same QP: the last SQP subproblem of the latest solve
    (its stage-wise form, ``casadi_reference.HpipmQp``). Each solved twice, the second call timed."""
    qp = solver.qp
    for _ in range(2):
        start = time.perf_counter()
        ours = solver.qp_solver.solve(qp)
        ours_s = time.perf_counter() - start
    hpipm = hpipm_factory(qp)
    for _ in range(2):
        _, inputs, success, wall_s, internal_s, iterations = hpipm.solve()
    first_input = float(np.abs(qp.split_solution(ours.z)[1][0] - inputs[0]).max()) if ours.solved else np.nan
    return {"ours_s": ours_s, "ours_solved": ours.solved, "hpipm_wall_s": wall_s, "hpipm_internal_s": internal_s,
            "hpipm_success": success, "hpipm_iterations": iterations, "first_input_difference": first_input,
            "rows": int(qp.n_observed)}


def solve_all(states: dict[str, np.ndarray], solver: NmpcSolver, reference, hpipm_factory) -> list[dict]:
    """Per state and guess: the NMPC's and IPOPT's outcomes (module doc); HPIPM on the rollout's last QP."""
    records = []
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = state_inputs(states, i)
        n = others.shape[1]
        record = {"dense": int(states["dense"][i]), "driver_srmpc": int(states["driver_srmpc"][i]),
                  "n_observed": n, "has_previous": bool(states["has_previous"][i])}
        for guess in GUESSES:
            guess_states, guess_inputs = guess_of(states, i, guess)
            result = solver.solve(ego, last_input, others, tracking, guess_states, guess_inputs)
            start = solver.initial_point(ego, others, guess_states, guess_inputs)
            ipopt = reference.solve(ego, last_input, others, tracking, start.states, start.inputs, start.slacks[:n],
                                    start.sigmas)
            row = {"status": result.status, "converged": result.converged, "iterations": result.iterations,
                   "time_s": result.solve_time_s, "qp_time_s": float(np.sum(result.qp_times_s)),
                   "objective": result.objective, "first_input": result.inputs[0].tolist(),
                   "ipopt_success": ipopt.success, "ipopt_iterations": ipopt.iterations,
                   "ipopt_time_s": ipopt.solve_time_s, "ipopt_objective": ipopt.objective}
            row.update(compare(result, ipopt))
            if result.converged and ipopt.success and not row["agree"]:
                certified = reference.solve(ego, last_input, others, tracking, result.states, result.inputs,
                                            result.collision_slacks, result.safety_slacks, warm=True)
                row["nmpc_is_ipopt_kkt_point"] = bool(
                    certified.success and np.abs(certified.states - result.states).max() <= AGREEMENT["trajectory_m"])
            record[guess] = row
            if guess == "policy_rollout" and n:
                record["hpipm"] = time_qp_against_hpipm(solver, hpipm_factory)
        rollout, shifted = record["policy_rollout"], record["shifted_previous"]
        candidates = [row for row in (rollout, shifted) if row["converged"]]
        best = min(candidates, key=lambda row: row["objective"]) if candidates else rollout
        record["best_of_two"] = {
            "converged": bool(candidates), "iterations": rollout["iterations"] + shifted["iterations"],
            "time_s": rollout["time_s"] + shifted["time_s"], "objective": best["objective"],
            "ipopt_iterations": rollout["ipopt_iterations"] + shifted["ipopt_iterations"],
            "from_rollout": best is rollout}
        records.append(record)
    return records


def summarize(records: list[dict]) -> dict:
    """The initial-guess table: per guess iterations, time, failures, objective against the lowest."""
    table = {}
    lowest = np.array([min(r[g]["objective"] for g in (*GUESSES, "best_of_two") if r[g]["converged"])
                       if any(r[g]["converged"] for g in GUESSES) else np.nan for r in records])
    for guess in (*GUESSES, "best_of_two"):
        rows = [r[guess] for r in records]
        converged = np.array([row["converged"] for row in rows])
        iterations = np.array([row["iterations"] for row in rows], dtype=float)
        time_ms = np.array([row["time_s"] for row in rows]) * 1e3
        objective = np.array([row["objective"] for row in rows])
        excess = (objective - lowest)[converged]
        entry = {
            "states": len(rows), "failures": int((~converged).sum()),
            "iterations_median": float(np.median(iterations[converged])),
            "iterations_p99": float(np.percentile(iterations[converged], 99)),
            "iterations_mean": float(np.mean(iterations[converged])),
            "time_median_ms": float(np.median(time_ms)), "time_p99_ms": float(np.percentile(time_ms, 99)),
            "objective_median": float(np.median(objective[converged])),
            "objective_mean": float(np.mean(objective[converged])),
            "share_at_lowest_objective": float(np.mean(excess <= 1e-4 * np.maximum(1.0, np.abs(lowest[converged])))),
            "objective_excess_over_lowest_mean": float(np.mean(excess)),
            "ipopt_iterations_median": float(np.median([row["ipopt_iterations"] for row in rows])),
            "ipopt_iterations_p99": float(np.percentile([row["ipopt_iterations"] for row in rows], 99)),
        }
        if guess != "best_of_two":
            entry["failure_statuses"] = dict(Counter(row["status"] for row in rows if not row["converged"]))
            entry["ipopt_failures"] = int(sum(not row["ipopt_success"] for row in rows))
            entry["ipopt_time_median_ms"] = float(np.median([row["ipopt_time_s"] for row in rows]) * 1e3)
            entry["qp_time_median_ms"] = float(np.median([row["qp_time_s"] for row in rows]) * 1e3)
        else:
            entry["share_from_rollout"] = float(np.mean([row["from_rollout"] for row in rows]))
        table[guess] = entry
    return table


def agreement(records: list[dict]) -> dict:
    """How often the NMPC and IPOPT agree from the same guess; different local optima and which is lower."""
    result = {"tolerances": AGREEMENT}
    total = {"pairs": 0, "both_converged": 0, "agree": 0, "different_local_optima": 0, "nmpc_lower": 0,
             "ipopt_lower": 0, "nmpc_not_kkt_for_ipopt": 0}
    for guess in GUESSES:
        rows = [r[guess] for r in records]
        both = [row for row in rows if row["converged"] and row["ipopt_success"]]
        agree = [row for row in both if row["agree"]]
        different = [row for row in both if not row["agree"] and row.get("nmpc_is_ipopt_kkt_point")]
        entry = {
            "pairs": len(rows), "both_converged": len(both), "agree": len(agree),
            "agreement_rate": len(agree) / max(1, len(both)),
            "different_local_optima": len(different),
            "nmpc_lower": sum(row["objective"] < row["ipopt_objective"] for row in different),
            "ipopt_lower": sum(row["objective"] >= row["ipopt_objective"] for row in different),
            "nmpc_not_kkt_for_ipopt": sum(1 for row in both if not row["agree"]
                                          and not row.get("nmpc_is_ipopt_kkt_point")),
            "max_objective_relative_when_agreeing": max((row["objective_relative"] for row in agree), default=0.0),
            "max_first_input_when_agreeing": max((row["first_input"] for row in agree), default=0.0),
            "max_trajectory_when_agreeing": max((row["trajectory"] for row in agree), default=0.0),
            "median_first_input": float(np.median([row["first_input"] for row in both])) if both else None,
        }
        for key in total:
            total[key] += entry[key]
        result[guess] = entry
    total["agreement_rate"] = total["agree"] / max(1, total["both_converged"])
    result["all_guesses"] = total
    return result


def hpipm_summary(records: list[dict]) -> dict:
    """Median times of our QP solver and HPIPM on the same QPs, and their ratio (ours / HPIPM)."""
    rows = [r["hpipm"] for r in records if "hpipm" in r and r["hpipm"]["ours_solved"] and r["hpipm"]["hpipm_success"]]
    ours = np.median([row["ours_s"] for row in rows]) * 1e6
    wall = np.median([row["hpipm_wall_s"] for row in rows]) * 1e6
    internal = np.median([row["hpipm_internal_s"] for row in rows]) * 1e6
    return {"qps": len(rows), "qps_tried": sum("hpipm" in r for r in records),
            "ours_median_us": float(ours), "hpipm_wall_median_us": float(wall),
            "hpipm_internal_median_us": float(internal),
            "ratio_ours_over_hpipm_wall": float(ours / wall), "ratio_ours_over_hpipm_internal": float(ours / internal),
            "hpipm_iterations_median": float(np.median([row["hpipm_iterations"] for row in rows])),
            "first_input_difference_max": float(np.max([row["first_input_difference"] for row in rows])),
            "note": "QP: the last SQP subproblem from the policy's rollout, per state with observed vehicles; "
                    "HPIPM through CasADi's conic interface (mode speed) on the same QP written stage-wise "
                    "(casadi_reference.HpipmQp); wall = the CasADi call, internal = HPIPM's own time"}


def figure(table: dict, records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    guesses = (*GUESSES, "best_of_two")
    labels = ["constant\nvelocity", "shifted\nprevious", "policy\nrollout", "best of\ntwo"]
    fig, axes = plt.subplots(1, 4, figsize=(17, 4))
    iterations = [[r[g]["iterations"] for r in records if r[g]["converged"]] for g in guesses]
    axes[0].boxplot(iterations, showfliers=True)
    axes[0].set_xticks(range(1, 5), labels)
    axes[0].set_ylabel("SQP iterations (QP solves)")
    axes[0].set_title("NMPC iterations to convergence")
    ipopt = [[r[g]["ipopt_iterations"] for r in records] for g in GUESSES]
    axes[1].boxplot(ipopt, showfliers=True)
    axes[1].set_xticks(range(1, 4), labels[:3])
    axes[1].set_ylabel("IPOPT iterations")
    axes[1].set_title("IPOPT from the same guesses")
    for guess, label in zip(guesses, labels, strict=True):
        times = np.sort([r[guess]["time_s"] * 1e3 for r in records])
        axes[2].plot(times, np.linspace(0, 1, times.size), label=label.replace("\n", " "))
    axes[2].axvline(TARGETS["policy_rollout_median_ms"], color="grey", linestyle=":", label="1 ms target")
    axes[2].set_xscale("log")
    axes[2].set_xlabel("NMPC wall time per step [ms], one core")
    axes[2].set_ylabel("share of states")
    axes[2].legend(fontsize=8)
    axes[2].set_title("Time to convergence")
    shares = [table[g]["share_at_lowest_objective"] for g in guesses]
    axes[3].bar(range(1, 5), shares, color="tab:green")
    axes[3].set_xticks(range(1, 5), labels)
    axes[3].set_ylim(0, 1)
    axes[3].set_ylabel("share of converged solves")
    axes[3].set_title("At the lowest optimum found from any guess")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states-per-run", type=int, default=75, help="states per (traffic, driver); 4 runs")
    parser.add_argument("--stride", type=int, default=3, help="record every stride-th step")
    parser.add_argument("--warmup", type=int, default=1, help="first recorded step of each episode")
    parser.add_argument("--max-steps", type=int, default=200, help="steps per episode at most")
    parser.add_argument("--save-states", type=Path, help="also write the recorded states here (.npz)")
    parser.add_argument("--load-states", type=Path, help="use states recorded earlier (.npz)")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    numba.set_num_threads(1)
    from srmpc.mpc.casadi_reference import HpipmQp, IpoptReference

    load_before = os.getloadavg()
    if args.load_states:
        with np.load(args.load_states) as data:
            states = {key: data[key] for key in data.files}
    else:
        states = record_states(args.states_per_run, args.stride, args.warmup, args.max_steps)
    if args.save_states:
        np.savez_compressed(args.save_states, **states)
    config = to_objects(compose_config(["+experiment=dense_traffic", "evaluation.controller=ltv_mpc",
                                        "tracking.enabled=false"]))
    from srmpc.controller_factory import planner_ocp

    ocp, _ = planner_ocp(config)
    solver = NmpcSolver(ocp)
    reference = IpoptReference(ocp)
    ego, last_input, others, tracking = state_inputs(states, 0)
    solver.solve(ego, last_input, others, tracking, *guess_of(states, 0, "policy_rollout"))  # compile
    records = solve_all(states, solver, reference, HpipmQp)
    table = summarize(records)
    rollout, constant = table["policy_rollout"], table["constant_velocity"]
    measured = {"policy_rollout_median_ms": rollout["time_median_ms"],
                "rollout_fewer_median_iterations_than_constant_velocity":
                    rollout["iterations_median"] < constant["iterations_median"]}
    result = {
        "per_guess": table,
        "agreement_with_ipopt": agreement(records),
        "qp_subsolver_vs_hpipm": hpipm_summary(records),
        "targets": {"policy_rollout_median_ms": {"limit": TARGETS["policy_rollout_median_ms"],
                                                 "measured": measured["policy_rollout_median_ms"],
                                                 "ratio_to_target": measured["policy_rollout_median_ms"]
                                                 / TARGETS["policy_rollout_median_ms"]},
                    "rollout_fewer_median_iterations_than_constant_velocity": {
                        "rollout_median": rollout["iterations_median"],
                        "constant_velocity_median": constant["iterations_median"],
                        "met": measured["rollout_fewer_median_iterations_than_constant_velocity"]}},
        "meets_targets": bool(measured["policy_rollout_median_ms"] <= TARGETS["policy_rollout_median_ms"]
                              and measured["rollout_fewer_median_iterations_than_constant_velocity"]),
        "nmpc_settings": {key: value for key, value in vars(solver.settings).items()},
        "states": {"total": int(states["ego"].shape[0]), "dense": int(states["dense"].sum()),
                   "driven_by_srmpc": int(states["driver_srmpc"].sum()),
                   "with_previous_solution": int(states["has_previous"].sum())},
        "method": __doc__.split("Method: ")[1].strip(),
        "settings": {key: str(value) if isinstance(value, Path) else value for key, value in vars(args).items()},
        "machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                    "load_average_1_5_15min_before": list(load_before),
                    "load_average_1_5_15min_after": list(os.getloadavg())},
    }
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(OUTPUT, json.dumps(result, indent=2) + "\n")
    figure(table, records, FIGURE)
    print(json.dumps({"per_guess": table, "agreement": result["agreement_with_ipopt"]["all_guesses"],
                      "targets": result["targets"]}, indent=1))


if __name__ == "__main__":
    main()
