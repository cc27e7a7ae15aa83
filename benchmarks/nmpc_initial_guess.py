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

and IPOPT (``srmpc.mpc.nmpc.casadi_reference``, exact Hessian) from the same primal point. Timed: the
NMPC's whole solve (its QPs after the first warm-started, without the stall test:
``NmpcSettings(qp_warm_start=True, stall_iterations=0)``), process pinned
to one core, numba on one thread, after a warm-up solve.

- Warm- against cold-started QP subproblems: right after each NMPC solve, the same NMPC with every QP started
  cold (``NmpcSettings(qp_warm_start=False, stall_iterations=0)``, the revisions before the warm start) solves it, then the warm-started
  NMPC again, so that both compared solves see the same machine load and warm caches (the timed solve above
  follows IPOPT's solves): converged plans, SQP iterations, interior-point iterations per QP and per solve, and
  time, per guess (``qp_warm_start_vs_cold``).
- The stall test (``NmpcSettings.stall_iterations`` = ``STALL_ITERATIONS``, the default): after the cold solve, the
  warm-started NMPC with the stall test solves it, right before the repeated warm solve without it, both timed
  with warm caches: converged plans (and whether each is the plan without the test: same status, iterations and
  objective, hence IPOPT's certificate), statuses, SQP iterations of all solves, mean, median and p99 time, per
  guess (``stall_test_vs_without``).

- Agreement with IPOPT: objective within ``AGREEMENT`` (relative), first input and trajectory within
  their absolute tolerances.
- KKT certification of every converged NMPC plan: IPOPT warm-started at the plan (small barrier,
  ``casadi_reference.WARM_START_OPTIONS``); certified when IPOPT succeeds and moves the trajectory less
  than ``AGREEMENT``'s trajectory tolerance, i.e. the plan is a KKT point of IPOPT's NLP. Where the NMPC and
  IPOPT from the same guess disagree and the plan is certified, they reached different local optima.
- The NMPC's own KKT residual (``NmpcResult.kkt``, ``srmpc.mpc.nmpc.kkt_residual``: stationarity, complementarity and
  primal infeasibility with the last QP's multipliers, IPOPT's scaled error E), beside its convergence test:
  its distribution over the converged plans, by IPOPT's verdict.
- The lowest optimum of a state: the lowest objective among every solver's optimum for it, the NMPC's converged
  plans from the three guesses and IPOPT's successful solves from the same guesses. A solve is at it when it
  converged and its objective is within ``AGREEMENT``'s objective tolerance of it (the tolerance covers
  IPOPT's interior slacks); shares are of all 300 states, a failed solve counted as not at it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from collections import Counter
from pathlib import Path

import numba
import numpy as np

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller
from srmpc.mpc.nmpc import NmpcSettings, NmpcSolver
from srmpc.mpc.problem import OcpStepData
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
STALL_ITERATIONS = 3
"""K of the stall test measured against the solve without it (``NmpcSettings.stall_iterations``; its step length
``stall_step_length`` at its default 1/16)."""
MAX_OBSERVED = 6
"""Observation slots; recorded predictions are padded to this many vehicles."""
STATE_NAMES = ("x [m]", "y [m]", "psi [rad]", "v [m/s]")
"""The plan's state components (``largest_move``)."""


def record_states(states_per_run: int, stride: int, warmup: int, max_steps: int) -> dict[str, np.ndarray]:
    """Planner inputs of closed-loop steps (module doc), ``states_per_run`` per (traffic, driver)."""
    rows: dict[str, list] = {key: [] for key in (
        "ego", "last_input", "others", "n_observed", "tracking", "cv_states", "cv_inputs", "shifted_states",
        "shifted_inputs", "has_previous", "rollout_states", "rollout_inputs", "dense", "driver_srmpc")}
    for dense, traffic in enumerate(("light", "dense")):
        base = [f"+experiment={traffic}_traffic", "tracking.enabled=false"]
        srmpc_config = to_objects(compose_config(base + ["controller=srmpc"]))
        ltv_config = to_objects(compose_config(base + ["controller=ltv_mpc"]))
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


def kkt_fields(result) -> dict:
    """The NMPC result's convergence-test quantities and its KKT residual (``NmpcResult.kkt``)."""
    kkt = result.kkt
    return {"primal_infeasibility": result.primal_infeasibility, "step_norm": result.stationarity,
            "kkt_error": kkt.error, "kkt_stationarity": kkt.stationarity, "kkt_complementarity": kkt.complementarity,
            "kkt_stationarity_scale": kkt.stationarity_scale,
            "kkt_complementarity_scale": kkt.complementarity_scale}


def certify(reference, planner_inputs: tuple, result) -> dict:
    """IPOPT warm-started at a converged NMPC plan (module doc): what it did and whether the plan is certified."""
    warm = reference.solve(*planner_inputs, result.states, result.inputs, result.collision_slacks,
                           result.safety_slacks, warm=True)
    difference = np.abs(warm.states - result.states)
    stage, component = np.unravel_index(int(np.argmax(difference)), difference.shape)
    drift = float(difference[stage, component])
    return {"certified": bool(warm.success and drift <= AGREEMENT["trajectory_m"]), "ipopt_status": warm.status,
            "ipopt_success": warm.success, "ipopt_iterations": warm.iterations, "trajectory_drift": drift,
            "largest_move": {"stage": int(stage), "state": STATE_NAMES[component],
                             "nmpc": float(result.states[stage, component]),
                             "ipopt": float(warm.states[stage, component])},
            "first_input_drift": float(np.abs(warm.inputs[0] - result.inputs[0]).max()),
            "ipopt_objective": warm.objective, "objective_change": warm.objective - result.objective,
            "ipopt_primal_infeasibility": warm.primal_infeasibility,
            "ipopt_dual_infeasibility": warm.dual_infeasibility}


def qp_fields(result) -> dict:
    """A solve's SQP and QP counts and time (``qp_warm_start_vs_cold``)."""
    return {"converged": result.converged, "iterations": result.iterations, "time_s": result.solve_time_s,
            "qp_iterations": [int(q) for q in result.qp_iterations], "status": result.status,
            "objective": result.objective}


def solve_all(states: dict[str, np.ndarray], solver: NmpcSolver, reference, cold_solver: NmpcSolver,
              stall_solver: NmpcSolver) -> list[dict]:
    """Per state and guess: the NMPC's and IPOPT's outcomes and, for a converged plan, its certification; the
    same NMPC solve with cold-started QPs and with the stall test (module doc)."""
    records = []
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = state_inputs(states, i)
        n = others.shape[1]
        record = {"state": i, "dense": int(states["dense"][i]), "driver_srmpc": int(states["driver_srmpc"][i]),
                  "n_observed": n, "has_previous": bool(states["has_previous"][i])}
        for guess in GUESSES:
            guess_states, guess_inputs = guess_of(states, i, guess)
            step = OcpStepData(ego, guess_states, guess_inputs, tracking, last_input, others)
            result = solver.solve(step)
            cold = cold_solver.solve(step)
            stalled = stall_solver.solve(step)
            repeated = solver.solve(step)
            start = solver.initial_point(step)
            ipopt = reference.solve(ego, last_input, others, tracking, start.states, start.inputs, start.slacks[:n],
                                    start.sigmas)
            row = {"status": result.status, "converged": result.converged, "iterations": result.iterations,
                   "time_s": result.solve_time_s, "qp_time_s": float(np.sum(result.qp_times_s)),
                   "objective": result.objective, "first_input": result.inputs[0].tolist(),
                   "ipopt_success": ipopt.success, "ipopt_status": ipopt.status,
                   "ipopt_iterations": ipopt.iterations, "ipopt_time_s": ipopt.solve_time_s,
                   "ipopt_objective": ipopt.objective, **kkt_fields(result),
                   "qps": qp_fields(repeated), "cold_qps": qp_fields(cold), "stall_qps": qp_fields(stalled)}
            row.update(compare(result, ipopt))
            if result.converged:
                row["certificate"] = certify(reference, (ego, last_input, others, tracking), result)
            record[guess] = row
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


def lowest_optimum(record: dict) -> float:
    """The lowest objective of every solver's optimum for the state (module doc); NaN if none succeeded."""
    values = [record[g]["objective"] for g in GUESSES if record[g]["converged"]]
    values += [record[g]["ipopt_objective"] for g in GUESSES if record[g]["ipopt_success"]]
    return min(values) if values else float("nan")


def at_lowest(objective: float, succeeded: bool, lowest: float) -> bool:
    """A solve is at the state's lowest optimum: it succeeded and is within ``AGREEMENT``'s objective tolerance."""
    return bool(succeeded and objective - lowest <= AGREEMENT["objective_relative"] * max(1.0, abs(lowest)))


def summarize(records: list[dict]) -> dict:
    """The initial-guess table: per guess iterations, time, failures, and the lowest optimum (module doc) out of
    all states."""
    table = {}
    lowest = np.array([lowest_optimum(r) for r in records])
    for guess in (*GUESSES, "best_of_two"):
        rows = [r[guess] for r in records]
        converged = np.array([row["converged"] for row in rows])
        iterations = np.array([row["iterations"] for row in rows], dtype=float)
        time_ms = np.array([row["time_s"] for row in rows]) * 1e3
        objective = np.array([row["objective"] for row in rows])
        at = np.array([at_lowest(row["objective"], row["converged"], low) for row, low in zip(rows, lowest,
                                                                                               strict=True)])
        entry = {
            "states": len(rows), "failures": int((~converged).sum()),
            "iterations_median": float(np.median(iterations[converged])),
            "iterations_p99": float(np.percentile(iterations[converged], 99)),
            "iterations_mean": float(np.mean(iterations[converged])),
            "time_median_ms": float(np.median(time_ms)), "time_p99_ms": float(np.percentile(time_ms, 99)),
            "objective_median": float(np.median(objective[converged])),
            "objective_mean": float(np.mean(objective[converged])),
            "states_at_lowest_optimum": int(at.sum()), "share_of_states_at_lowest_optimum": float(at.mean()),
            "converged_not_at_lowest_optimum": int((converged & ~at).sum()),
            "objective_excess_over_lowest_mean": float(np.mean((objective - lowest)[converged])),
            "ipopt_iterations_median": float(np.median([row["ipopt_iterations"] for row in rows])),
            "ipopt_iterations_p99": float(np.percentile([row["ipopt_iterations"] for row in rows], 99)),
        }
        if guess != "best_of_two":
            ipopt_at = [at_lowest(row["ipopt_objective"], row["ipopt_success"], low)
                        for row, low in zip(rows, lowest, strict=True)]
            entry["failure_statuses"] = dict(Counter(row["status"] for row in rows if not row["converged"]))
            entry["ipopt_failures"] = int(sum(not row["ipopt_success"] for row in rows))
            entry["ipopt_states_at_lowest_optimum"] = int(sum(ipopt_at))
            entry["ipopt_share_of_states_at_lowest_optimum"] = float(np.mean(ipopt_at))
            entry["ipopt_time_median_ms"] = float(np.median([row["ipopt_time_s"] for row in rows]) * 1e3)
            entry["qp_time_median_ms"] = float(np.median([row["qp_time_s"] for row in rows]) * 1e3)
        else:
            entry["share_from_rollout"] = float(np.mean([row["from_rollout"] for row in rows]))
        table[guess] = entry
    return table


def qp_start_comparison(records: list[dict]) -> dict:
    """Per guess, the NMPC with warm-started QPs (``qp_warm_start=True``, the solver of the other tables; its repeated
    solve) and with every QP cold, solved back to back (module doc): converged plans, SQP iterations (converged),
    interior-point iterations per QP (all, and those after the first) and per solve, time."""
    table = {}
    for guess in GUESSES:
        entry = {}
        for key, name in (("qps", "warm"), ("cold_qps", "cold")):
            rows = [r[guess][key] for r in records]
            converged = np.array([row["converged"] for row in rows])
            iterations = np.array([row["iterations"] for row in rows], dtype=float)[converged]
            per_qp = [q for row in rows for q in row["qp_iterations"]]
            later = [q for row in rows for q in row["qp_iterations"][1:]]
            time_ms = np.array([row["time_s"] for row in rows]) * 1e3
            entry[name] = {
                "converged": int(converged.sum()), "iterations_median": float(np.median(iterations)),
                "iterations_mean": float(np.mean(iterations)),
                "qp_iterations_per_qp_mean": float(np.mean(per_qp)),
                "qp_iterations_after_the_first_qp_mean": float(np.mean(later)),
                "qp_iterations_per_solve_median": float(np.median([sum(row["qp_iterations"]) for row in rows])),
                "time_median_ms": float(np.median(time_ms)), "time_p99_ms": float(np.percentile(time_ms, 99)),
                "time_mean_ms": float(np.mean(time_ms))}
        entry["time_median_ratio_warm_to_cold"] = entry["warm"]["time_median_ms"] / entry["cold"]["time_median_ms"]
        table[guess] = entry
    return table


def stall_comparison(records: list[dict]) -> dict:
    """Per guess, the warm-started NMPC without the stall test (its repeated solve) and with it, solved back to back
    (module doc): converged plans, those equal to the plan without the test and certified by IPOPT, statuses, SQP
    iterations (converged and all), time (mean, median, p99)."""
    table = {"stall_iterations": STALL_ITERATIONS}
    for guess in GUESSES:
        entry = {}
        for key, name in (("qps", "without"), ("stall_qps", "with_stall_test")):
            rows = [r[guess][key] for r in records]
            converged = np.array([row["converged"] for row in rows])
            iterations = np.array([row["iterations"] for row in rows], dtype=float)
            time_ms = np.array([row["time_s"] for row in rows]) * 1e3
            entry[name] = {
                "converged": int(converged.sum()), "statuses": dict(Counter(row["status"] for row in rows)),
                "iterations_median": float(np.median(iterations[converged])),
                "iterations_mean": float(np.mean(iterations[converged])),
                "iterations_mean_all_solves": float(np.mean(iterations)),
                "iterations_max_all_solves": int(iterations.max()),
                "qp_iterations_per_solve_mean": float(np.mean([sum(row["qp_iterations"]) for row in rows])),
                "time_mean_ms": float(np.mean(time_ms)), "time_median_ms": float(np.median(time_ms)),
                "time_p99_ms": float(np.percentile(time_ms, 99))}
        same = [r[guess]["stall_qps"]["converged"] and all(
            r[guess]["stall_qps"][k] == r[guess]["qps"][k] for k in ("status", "iterations", "objective"))
            for r in records]
        certified = [r[guess]["converged"] and r[guess]["certificate"]["certified"]
                     and r[guess]["stall_qps"]["converged"] for r in records]
        entry["with_stall_test"]["converged_same_plan_as_without"] = int(sum(same))
        entry["with_stall_test"]["converged_and_certified_by_ipopt"] = int(sum(certified))
        entry["time_mean_ratio_with_to_without"] = (entry["with_stall_test"]["time_mean_ms"]
                                                    / entry["without"]["time_mean_ms"])
        table[guess] = entry
    return table


def lowest_optimum_summary(records: list[dict]) -> dict:
    """Who found each state's lowest optimum: the NMPC from some guess, IPOPT only, or no solver."""
    lowest = [lowest_optimum(r) for r in records]
    by_nmpc = [any(at_lowest(r[g]["objective"], r[g]["converged"], low) for g in GUESSES)
               for r, low in zip(records, lowest, strict=True)]
    by_ipopt = [any(at_lowest(r[g]["ipopt_objective"], r[g]["ipopt_success"], low) for g in GUESSES)
                for r, low in zip(records, lowest, strict=True)]
    return {"states": len(records), "objective_tolerance_relative": AGREEMENT["objective_relative"],
            "found_by_nmpc_from_some_guess": int(sum(by_nmpc)), "found_by_ipopt_from_some_guess": int(sum(by_ipopt)),
            "found_by_ipopt_only": int(sum(b and not a for a, b in zip(by_nmpc, by_ipopt, strict=True))),
            "found_by_nmpc_only": int(sum(a and not b for a, b in zip(by_nmpc, by_ipopt, strict=True))),
            "no_solver_succeeded": int(sum(np.isnan(low) for low in lowest)),
            "definition": "per state, the lowest objective among the NMPC's converged plans and IPOPT's successful "
                          "solves from the three guesses; at it: within the relative tolerance"}


def agreement(records: list[dict]) -> dict:
    """How often the NMPC and IPOPT agree from the same guess; different local optima (disagreeing, the NMPC's
    plan certified) and which is lower; disagreeing pairs whose NMPC plan IPOPT does not certify."""
    result = {"tolerances": AGREEMENT}
    total = {"pairs": 0, "both_converged": 0, "agree": 0, "different_local_optima": 0, "nmpc_lower": 0,
             "ipopt_lower": 0, "disagree_nmpc_not_certified": 0}
    for guess in GUESSES:
        rows = [r[guess] for r in records]
        both = [row for row in rows if row["converged"] and row["ipopt_success"]]
        agree = [row for row in both if row["agree"]]
        different = [row for row in both if not row["agree"] and row["certificate"]["certified"]]
        entry = {
            "pairs": len(rows), "both_converged": len(both), "agree": len(agree),
            "agreement_rate": len(agree) / max(1, len(both)),
            "different_local_optima": len(different),
            "nmpc_lower": sum(row["objective"] < row["ipopt_objective"] for row in different),
            "ipopt_lower": sum(row["objective"] >= row["ipopt_objective"] for row in different),
            "disagree_nmpc_not_certified": sum(1 for row in both if not row["agree"]
                                               and not row["certificate"]["certified"]),
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


KKT_THRESHOLDS = (1e-6, 1e-4, 1e-2)
"""Levels of the KKT error E whose counts the benchmark reports (IPOPT's own ``tol`` here is 1e-9)."""


def quantiles(values) -> dict:
    values = np.asarray(values, dtype=float)
    if not values.size:
        return {}
    return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90)),
            "p99": float(np.percentile(values, 99)), "max": float(values.max())}


def certification(records: list[dict]) -> dict:
    """IPOPT's certification of every converged NMPC plan (module doc), per guess and in all, each plan that
    fails it described."""
    result = {"criterion": f"IPOPT warm-started at the plan succeeds and moves the trajectory at most "
                           f"{AGREEMENT['trajectory_m']:g} (m, rad, m/s)"}
    failures = []
    for guess in GUESSES:
        rows = [(r, r[guess]) for r in records if r[guess]["converged"]]
        certified = [row for _, row in rows if row["certificate"]["certified"]]
        result[guess] = {"converged_plans": len(rows), "certified": len(certified),
                         "not_certified": len(rows) - len(certified),
                         "trajectory_drift": quantiles([row["certificate"]["trajectory_drift"] for _, row in rows])}
        for record, row in rows:
            if not row["certificate"]["certified"]:
                failures.append({
                    "state": record["state"], "guess": guess, "traffic": "dense" if record["dense"] else "light",
                    "n_observed": record["n_observed"],
                    "nmpc": {key: row[key] for key in ("status", "iterations", "objective", "primal_infeasibility",
                                                       "step_norm", "kkt_error", "kkt_stationarity",
                                                       "kkt_complementarity")},
                    "ipopt_cold_from_the_same_guess": {"success": row["ipopt_success"],
                                                       "objective": row["ipopt_objective"], "agree": row["agree"],
                                                       "trajectory_difference": row["trajectory"]},
                    "ipopt_warm_at_the_plan": row["certificate"]})
    plans = sum(result[g]["converged_plans"] for g in GUESSES)
    certified = sum(result[g]["certified"] for g in GUESSES)
    result["all_guesses"] = {"converged_plans": plans, "certified": certified, "not_certified": plans - certified}
    result["not_certified"] = failures
    return result


def kkt_summary(records: list[dict]) -> dict:
    """The NMPC's KKT residual over its converged plans (module doc): distribution, counts below
    ``KKT_THRESHOLDS``, and by IPOPT's certification verdict."""
    rows = [r[g] for r in records for g in GUESSES if r[g]["converged"]]
    errors = np.array([row["kkt_error"] for row in rows])
    certified = np.array([row["certificate"]["certified"] for row in rows])
    not_certified_errors = np.sort(errors[~certified])
    return {
        "converged_plans": len(rows),
        "error": quantiles(errors),
        "stationarity": quantiles([row["kkt_stationarity"] for row in rows]),
        "complementarity": quantiles([row["kkt_complementarity"] for row in rows]),
        "primal_infeasibility": quantiles([row["primal_infeasibility"] for row in rows]),
        "stationarity_scale": quantiles([row["kkt_stationarity_scale"] for row in rows]),
        "complementarity_scale": quantiles([row["kkt_complementarity_scale"] for row in rows]),
        "plans_with_error_at_most": {f"{level:g}": int((errors <= level).sum()) for level in KKT_THRESHOLDS},
        "error_certified": quantiles(errors[certified]),
        "error_not_certified": not_certified_errors.tolist(),
        "rank_of_not_certified": [int((errors < e).sum()) for e in not_certified_errors],
        "note": "E = max(r_d / s_d, r_p, r_c / s_c), IPOPT's scaled overall error (srmpc/mpc/nmpc/kkt_residual.py) "
                "at the returned plan with the last QP's multipliers; rank: plans with a smaller E",
    }


def figure(table: dict, records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    guesses = (*GUESSES, "best_of_two")
    labels = ["constant\nvelocity", "shifted\nprevious", "policy\nrollout", "best of\ntwo"]
    fig, axes = plt.subplots(1, 5, figsize=(21, 4))
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
    positions = np.arange(1, 5)
    axes[3].bar(positions - 0.2, [table[g]["share_of_states_at_lowest_optimum"] for g in guesses], width=0.4,
                color="tab:green", label="NMPC")
    axes[3].bar(positions[:3] + 0.2, [table[g]["ipopt_share_of_states_at_lowest_optimum"] for g in GUESSES],
                width=0.4, color="tab:grey", label="IPOPT, same guess")
    axes[3].set_xticks(positions, labels)
    axes[3].set_ylim(0, 1)
    axes[3].set_ylabel(f"share of all {len(records)} states")
    axes[3].set_title("At the state's lowest optimum (any solver)", fontsize=10)
    axes[3].legend(fontsize=8, loc="upper left")
    rows = [r[g] for r in records for g in GUESSES if r[g]["converged"]]
    errors = np.sort([row["kkt_error"] for row in rows])
    axes[4].plot(errors, np.arange(1, errors.size + 1) / errors.size, color="tab:blue", label="converged plans")
    failed = [row["kkt_error"] for row in rows if not row["certificate"]["certified"]]
    axes[4].plot(failed, [np.mean(errors <= e) for e in failed], "rx", label="not certified by IPOPT")
    axes[4].set_xscale("log")
    axes[4].set_xlabel("KKT error E (IPOPT-scaled, last QP's multipliers)")
    axes[4].set_ylabel("share of converged plans")
    axes[4].set_title("The NMPC's KKT residual")
    axes[4].legend(fontsize=8)
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
    from srmpc.mpc.nmpc.casadi_reference import IpoptReference

    load_before = os.getloadavg()
    if args.load_states:
        with np.load(args.load_states) as data:
            states = {key: data[key] for key in data.files}
    else:
        states = record_states(args.states_per_run, args.stride, args.warmup, args.max_steps)
    if args.save_states:
        np.savez_compressed(args.save_states, **states)
    config = to_objects(compose_config(["+experiment=dense_traffic", "controller=ltv_mpc",
                                        "tracking.enabled=false"]))
    from srmpc.controller_factory import planner_ocp

    ocp, _ = planner_ocp(config)
    solver = NmpcSolver(ocp, NmpcSettings(qp_warm_start=True, stall_iterations=0))  # warm-started QPs (module doc)
    cold_solver = NmpcSolver(ocp, NmpcSettings(qp_warm_start=False, stall_iterations=0))
    stall_solver = NmpcSolver(ocp, NmpcSettings(qp_warm_start=True, stall_iterations=STALL_ITERATIONS))
    reference = IpoptReference(ocp)
    ego, last_input, others, tracking = state_inputs(states, 0)
    for nmpc in (solver, cold_solver, stall_solver):  # compile
        nmpc.solve(OcpStepData(ego, *guess_of(states, 0, "policy_rollout"), tracking, last_input, others))
    records = solve_all(states, solver, reference, cold_solver, stall_solver)
    table = summarize(records)
    rollout, constant = table["policy_rollout"], table["constant_velocity"]
    measured = {"policy_rollout_median_ms": rollout["time_median_ms"],
                "rollout_fewer_median_iterations_than_constant_velocity":
                    rollout["iterations_median"] < constant["iterations_median"]}
    result = {
        "per_guess": table,
        "lowest_optimum": lowest_optimum_summary(records),
        "agreement_with_ipopt": agreement(records),
        "kkt_certification_by_ipopt": certification(records),
        "kkt_residual": kkt_summary(records),
        "qp_warm_start_vs_cold": qp_start_comparison(records),
        "stall_test_vs_without": stall_comparison(records),
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
    print(json.dumps({"per_guess": table, "lowest_optimum": result["lowest_optimum"],
                      "agreement": result["agreement_with_ipopt"]["all_guesses"],
                      "certification": result["kkt_certification_by_ipopt"]["all_guesses"],
                      "kkt_residual": result["kkt_residual"]["error"], "targets": result["targets"],
                      "stall_test_vs_without": result["stall_test_vs_without"]}, indent=1))


if __name__ == "__main__":
    main()
