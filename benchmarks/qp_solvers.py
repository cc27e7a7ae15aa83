"""QP solvers on the same planner QPs: our Riccati interior point against HPIPM, PIQP and OSQP, one core.

Writes results/benchmarks/qp_solvers.json: per QP stream (the LTV-MPC's QPs and SRMPC's policy QPs) and
pooled, per solver: failures, iterations, time per solve (median, p99), first-input and objective
agreement with a tight Clarabel reference, and ratios ours / peer from this run (ratio of medians, for the
solve time with a paired bootstrap 95% interval over the QPs both solved).

QPs: light and dense twin episodes (the committed config, ``tracking.enabled=false``, seeds ``1000 e`` /
``1000 e + 1``) are driven by SRMPC; at every step the LTV-MPC and SRMPC controllers (each with its own
previous solution) plan on that scene as configured (``riccati_ipm``, warm-started), and each QP their
planner solved (SRMPC: the QP linearized about the policy rollout) is re-solved by every solver below,
in an order that rotates every QP. Each solver keeps its own warm-start memory per stream, so a warm
start is from that solver's own solution of the stream's previous QP, shifted one stage.

Solvers (tolerances as configured in the project unless said):

- ``riccati_ipm`` / ``riccati_ipm_cold``: ours, warm (as the planner uses it) and cold, tolerance 1e-8;
  time = the whole ``solve(qp)`` call (it reads the QP's stage-wise arrays, so there is nothing to copy).
- ``hpipm_native`` / ``_warm``: HPIPM's C API on the stage-wise OCP QP (``srmpc.mpc.solvers.hpipm_native``:
  boxes only where our QP has them, structures created once, mode SPEED with mu0 = 1, our tolerance 1e-8 on
  equalities, inequalities and complementarity, 1e-4 on stationarity (our relative test's absolute size
  with any vehicle observed), our iteration limit; warm = primal warm start from the shifted previous
  solution); ``solve`` =
  ``d_ocp_qp_ipm_solve`` alone, ``call`` = plus writing the values and reading the solution through ctypes.
  Run on CasADi's ``libhpipm.so`` (BLASFEO GENERIC target) and, with ``--hpipm-library``, on a build
  for this CPU (rows ``hpipm_avx2*``: the same HPIPM and BLASFEO commits CasADi pins, built from their
  repositories outside this project with BLASFEO's TARGET=X64_INTEL_HASWELL and HPIPM's TARGET=AVX; see
  docs/benchmarks.md).
- ``hpipm_casadi`` / ``_warm``: the same stage-wise QP through CasADi's ``hpipm`` plugin
  (``srmpc.mpc.solvers.hpipm_reference``: every variable boxed at +-1e4 by CasADi, structures rebuilt per call);
  ``solve`` = CasADi's reported ``t_wall_solver``, ``call`` = the wall time of the CasADi call.
- ``piqp``: PIQP's native sparse API (set up once, ``update`` values, ``solve``), eps 1e-7, KKT solver
  ``sparse_multistage`` (PIQP's own for OCP structure; ``--piqp-kkt`` to change); ``solve`` = ``solve()``,
  ``call`` = ``update`` + ``solve``.
- ``osqp``: OSQP's native API on the general form, eps 1e-5 (the project's setting: 1e-3 gave first-input
  errors near 1), warm-started from its previous (x, y) shifted, no polishing; timed as PIQP.

Agreement: Clarabel (through qpsolvers, tolerances 1e-9) solves each QP outside the timing; per solver the
first-input error |u_0 - u_0^ref|_inf and the objective error |f - f_ref| / max(1, |f_ref|), f = 1/2 z^T P z
+ q^T z. The process is pinned to one core, numba and torch on one thread.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections import Counter
from pathlib import Path

import numba
import numpy as np
import torch

from srmpc.confidence_intervals import bootstrap_indices, percentile_interval
from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller
from srmpc.mpc.solvers import (
    NATIVE_PIQP_TOLERANCE,
    OSQP_TOLERANCE,
    RICCATI_IPM_TOLERANCE,
    RiccatiInteriorPointSolver,
    make_solver,
)
from srmpc.mpc.solvers.hpipm_native import (
    HPIPM_MU0,
    HPIPM_STATIONARITY_TOLERANCE,
    HPIPM_TOLERANCE,
    HpipmNativeSolver,
    casadi_hpipm_library,
)
from srmpc.mpc.solvers.hpipm_reference import CASADI_INFINITY, HpipmCasadiSolver
from srmpc.output_folder import atomic_write_text
from srmpc.sim.single_env import TwinScenarioEnv

OUTPUT = Path("results/benchmarks/qp_solvers.json")
STREAMS = {"ltv_mpc": ["controller=ltv_mpc"], "srmpc": ["controller=srmpc"]}
"""QP stream -> the controller whose planner QPs it collects (overrides of the committed config)."""
OURS = ("riccati_ipm", "riccati_ipm_cold")
SWEEP = {"mode": ("speed", "speed_abs", "balance"), "mu0": (1.0, 10.0, 100.0), "tol_stat": (1e-8, 1e-6, 1e-4)}
"""HPIPM settings tried (cold, on every ``SWEEP_EVERY``-th QP): its modes, initial barrier parameter and
stationarity tolerance, to show whether another setting would need fewer iterations."""
SWEEP_EVERY = 5


class Timed:
    """One solver: ``solve(qp)`` -> (z or None, iterations, solve_s, call_s, status) (module doc for the timings)."""

    def reset(self) -> None:
        pass


class Ours(Timed):
    def __init__(self, warm: bool) -> None:
        self.solver = RiccatiInteriorPointSolver(warm_start=warm)

    def reset(self) -> None:
        self.solver.reset()

    def solve(self, qp):
        start = time.perf_counter()
        solution = self.solver.solve(qp)
        elapsed = time.perf_counter() - start
        return solution.z if solution.solved else None, solution.iterations, elapsed, elapsed, solution.status


class HpipmNative(Timed):
    def __init__(self, warm: bool, library: Path | None = None) -> None:
        self.solver = HpipmNativeSolver(warm_start=warm, library=library)

    def reset(self) -> None:
        self.solver.reset()

    def solve(self, qp):
        result = self.solver.solve(qp)
        return (result.z if result.solved else None, result.iterations, result.solve_s, result.solve_s + result.setup_s,
                f"hpipm status {result.status}")


class HpipmCasadi(Timed):
    def __init__(self, warm: bool) -> None:
        self.solver = HpipmCasadiSolver(warm_start=warm)

    def reset(self) -> None:
        self.solver.reset()

    def solve(self, qp):
        result = self.solver.solve(qp)
        return (result.z if result.solved else None, result.iterations, result.reported_solver_s, result.call_s,
                f"hpipm status {result.status}")


class Piqp(Timed):
    """PIQP's sparse solver on the split form, set up once per QP shape, then ``update`` + ``solve``."""

    def __init__(self, kkt_solver: str) -> None:
        import piqp

        self.piqp, self.kkt_solver = piqp, getattr(piqp.KKTSolver, kkt_solver)
        self.solver, self.shape = None, None

    def reset(self) -> None:
        self.solver = None

    def solve(self, qp):
        piqp = self.piqp
        start = time.perf_counter()
        shape = (qp.n_variables, qp.n_equalities, qp.n_inequalities)
        if self.solver is None or self.shape != shape:
            self.solver, self.shape = piqp.SparseSolver(), shape
            settings = self.solver.settings
            settings.eps_abs = settings.eps_rel = NATIVE_PIQP_TOLERANCE
            settings.preconditioner_reuse_on_update = True
            settings.kkt_solver = self.kkt_solver
            self.solver.setup(qp.cost_matrix, qp.cost_vector, qp.equality_matrix, qp.equality_rhs,
                              qp.inequality_matrix, qp.inequality_lower, np.full(qp.n_inequalities, np.inf),
                              qp.variable_lower, qp.variable_upper)
        else:
            self.solver.update(c=qp.cost_vector, A=qp.equality_matrix, b=qp.equality_rhs, G=qp.inequality_matrix,
                               h_l=qp.inequality_lower, x_u=qp.variable_upper)
        solve_start = time.perf_counter()
        status = self.solver.solve()
        end = time.perf_counter()
        result = self.solver.result
        z = np.array(result.x) if status == piqp.PIQP_SOLVED else None
        return z, int(result.info.iter), end - solve_start, end - start, str(status)


class Osqp(Timed):
    """OSQP on the general form, set up once, ``update`` + warm start from its shifted previous (x, y)."""

    def __init__(self) -> None:
        import osqp

        self.osqp = osqp
        self.settings = {"eps_abs": OSQP_TOLERANCE, "eps_rel": OSQP_TOLERANCE, "warm_starting": True,
                         "polishing": False, "verbose": False, "max_iter": 20000}
        self.solver, self.previous = None, None

    def reset(self) -> None:
        self.previous = None

    def solve(self, qp):
        start = time.perf_counter()
        if self.solver is None:
            self.solver = self.osqp.OSQP()
            self.solver.setup(qp.cost_matrix.copy(), qp.cost_vector.copy(), qp.general_matrix.copy(),
                              qp.general_lower.copy(), qp.general_upper.copy(), **self.settings)
        else:
            self.solver.update(q=qp.cost_vector, l=qp.general_lower, u=qp.general_upper, Ax=qp.general_matrix.data)
        if self.previous is not None:
            x, y = self.previous
            self.solver.warm_start(x=x[qp.variable_shift], y=y[qp.general_row_shift])
        solve_start = time.perf_counter()
        result = self.solver.solve(raise_error=False)
        end = time.perf_counter()
        solved = result.info.status_val == self.osqp.SolverStatus.OSQP_SOLVED
        self.previous = (np.array(result.x), np.array(result.y)) if solved else None
        return ((np.array(result.x) if solved else None), int(result.info.iter), end - solve_start, end - start,
                str(result.info.status))


def make_solvers(args) -> dict[str, Timed]:
    solvers = {"riccati_ipm": Ours(True), "riccati_ipm_cold": Ours(False),
               "hpipm_native": HpipmNative(False), "hpipm_native_warm": HpipmNative(True),
               "hpipm_casadi": HpipmCasadi(False), "hpipm_casadi_warm": HpipmCasadi(True),
               "piqp": Piqp(args.piqp_kkt), "osqp": Osqp()}
    if args.hpipm_library is not None:
        solvers["hpipm_avx2"] = HpipmNative(False, args.hpipm_library)
        solvers["hpipm_avx2_warm"] = HpipmNative(True, args.hpipm_library)
    return solvers


def make_sweep(library: Path | None) -> dict[str, HpipmNativeSolver]:
    return {f"{mode} mu0={mu0:g} tol_stat={tol:g}": HpipmNativeSolver(mode=mode, mu0=mu0, stationarity_tolerance=tol,
                                                                      library=library)
            for mode in SWEEP["mode"] for mu0 in SWEEP["mu0"] for tol in SWEEP["tol_stat"]}


def solve_sweep(qp, sweep: dict[str, HpipmNativeSolver], u0_ref: np.ndarray, record: dict) -> None:
    """HPIPM (cold) with each setting of ``SWEEP``: iterations and first-input error (inf if failed)."""
    for name, solver in sweep.items():
        result = solver.solve(qp)
        row = record.setdefault(name, {"iterations": [], "u0_error": []})
        row["iterations"].append(result.iterations)
        row["u0_error"].append(float(np.max(np.abs(qp.split_solution(result.z)[1][0] - u0_ref)))
                               if result.solved else float("inf"))


def solve_everywhere(qp, solvers: dict[str, Timed], reference, samples: dict, turn: int, qp_id: str,
                     sweep: dict | None = None) -> None:
    """One QP: the Clarabel reference, then every solver (order rotating with ``turn``); the HPIPM
    settings sweep on every ``SWEEP_EVERY``-th."""
    ref = reference.solve(qp)
    if not ref.solved:
        return
    u0_ref, f_ref = qp.split_solution(ref.z)[1][0], qp.objective(ref.z)
    if sweep is not None and turn % SWEEP_EVERY == 0:
        solve_sweep(qp, sweep["solvers"], u0_ref, sweep["record"])
    names = list(solvers)
    for i in range(len(names)):
        name = names[(turn + i) % len(names)]
        z, iterations, solve_s, call_s, status = solvers[name].solve(qp)
        row = samples[name]
        row["qps"] += 1
        if z is None or not np.all(np.isfinite(z)):
            row["failures"] += 1
            row["failure_status"].append(f"{status} after {iterations} iterations")
            continue
        row["iterations"].append(iterations)
        row["qp_id"].append(qp_id)
        row["solve_us"].append(solve_s * 1e6)
        row["call_us"].append(call_s * 1e6)
        row["u0_error"].append(float(np.max(np.abs(qp.split_solution(z)[1][0] - u0_ref))))
        row["objective_error"].append(abs(qp.objective(z) - f_ref) / max(1.0, abs(f_ref)))
        row["n_observed"].append(qp.n_observed)


def run(traffic: str, episodes: int, steps: int, warmup: int, solvers: dict, sweep: dict) -> dict[str, dict]:
    base = [f"+experiment={traffic}_traffic", "tracking.enabled=false"]
    configs = {name: to_objects(compose_config(base + overrides)) for name, overrides in STREAMS.items()}
    env = TwinScenarioEnv(configs["srmpc"].scenario)
    controllers = {name: build_controller(config, env) for name, config in configs.items()}
    reference = make_solver("clarabel")
    samples = {stream: {name: _scratch() for name in solvers[stream]} for stream in STREAMS}
    turn = 0
    for episode in range(episodes):
        observation, _ = env.reset(seed=1000 * episode + (traffic == "dense"))
        for stream in STREAMS:
            controllers[stream].reset()
            for solver in solvers[stream].values():
                solver.reset()
        for step in range(steps):
            scene = env.unwrapped.measurement
            actions = {stream: controllers[stream].act(observation, scene) for stream in STREAMS}
            for stream, controller in controllers.items():
                plan = controller.last_plan if stream == "srmpc" else controller.last_report.plan
                solved = plan.outcome.value == "solved" and plan.iterations is not None
                if stream == "srmpc":
                    solved = solved and plan.reference_source.value == "given"
                if solved:
                    record = samples[stream] if step >= warmup else {n: _scratch() for n in samples[stream]}
                    solve_everywhere(controller.planner.qp, solvers[stream], reference, record, turn,
                                     f"{traffic}:{stream}:{turn}", sweep if step >= warmup else None)
                    turn += 1
            observation, _, terminated, truncated, _ = env.step(actions["srmpc"])
            if terminated or truncated:
                break
    return samples


def _scratch() -> dict:
    return {"qps": 0, "failures": 0, "failure_status": [], "iterations": [], "qp_id": [], "solve_us": [],
            "call_us": [], "u0_error": [], "objective_error": [], "n_observed": []}


def summary(row: dict) -> dict:
    def stats(values, *quantiles):
        array = np.asarray(values, dtype=float)
        out = {"median": float(np.median(array))}
        for q in quantiles:
            out[f"p{q}"] = float(np.percentile(array, q))
        out["max"] = float(array.max())
        return out
    failures = {"qps": row["qps"], "failures": row["failures"],
                "failure_status": dict(Counter(row["failure_status"]))}
    if not row["solve_us"]:
        return failures
    return {**failures, "iterations": stats(row["iterations"], 99),
            "solve_us": stats(row["solve_us"], 99), "call_us": stats(row["call_us"], 99),
            "u0_error": stats(row["u0_error"], 99), "objective_error": stats(row["objective_error"], 99),
            "n_observed_median": float(np.median(row["n_observed"]))}


def ratios(per_solver: dict, raw: dict, resamples: int = 2000, seed: int = 0) -> dict:
    """Ours / peer for each peer: the ratio of the medians of ``solve_us`` and ``call_us`` (< 1: ours faster),
    and for ``solve_us`` a 95% bootstrap interval of that ratio over the QPs both solved (paired resampling
    of QPs; QPs of one episode are not independent, so the interval is narrower than a resampling of
    episodes would give)."""
    out = {}
    for mine in OURS:
        for peer, row in per_solver.items():
            if peer in OURS or "solve_us" not in row:
                continue
            pair = {key: per_solver[mine][key]["median"] / row[key]["median"] for key in ("solve_us", "call_us")}
            mine_by_qp = dict(zip(raw[mine]["qp_id"], raw[mine]["solve_us"], strict=True))
            peer_by_qp = dict(zip(raw[peer]["qp_id"], raw[peer]["solve_us"], strict=True))
            common = sorted(set(mine_by_qp) & set(peer_by_qp))
            a = np.array([mine_by_qp[q] for q in common])
            b = np.array([peer_by_qp[q] for q in common])
            index = bootstrap_indices(len(common), resamples, seed)
            pair["solve_us_ratio_ci95"] = list(percentile_interval(np.median(a[index], axis=1)
                                                                   / np.median(b[index], axis=1)))
            pair["paired_qps"] = len(common)
            out[f"{mine}/{peer}"] = pair
    return out


def cpu_model() -> str:
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return platform.processor() or platform.machine()
    return next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), platform.machine())


def git_commit() -> dict:
    def git(*command):
        return subprocess.run(["git", *command], capture_output=True, text=True, check=False).stdout.strip()
    return {"commit": git("rev-parse", "HEAD"), "dirty_paths": git("status", "--porcelain").splitlines()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=2, help="episodes per traffic level")
    parser.add_argument("--steps", type=int, default=150, help="steps per episode at most")
    parser.add_argument("--warmup", type=int, default=3, help="steps per episode whose QPs are solved, not recorded")
    parser.add_argument("--hpipm-library", type=Path, default=None,
                        help="a libhpipm.so built for this CPU (docs/benchmarks.md): adds hpipm_avx2 rows")
    parser.add_argument("--piqp-kkt", default="sparse_multistage", help="PIQP's KKT solver (piqp.KKTSolver name)")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    start = time.perf_counter()
    merged = {stream: {} for stream in STREAMS}
    solvers = {stream: make_solvers(args) for stream in STREAMS}  # reset at every episode's start
    sweep = {"solvers": make_sweep(args.hpipm_library), "record": {}}
    for traffic in ("light", "dense"):
        samples = run(traffic, args.episodes, args.steps, args.warmup, solvers, sweep)
        for stream, per_solver in samples.items():
            for name, row in per_solver.items():
                target = merged[stream].setdefault(name, _scratch())
                for key, value in row.items():
                    target[key] = target[key] + value
    pooled = {name: _scratch() for name in merged["ltv_mpc"]}
    for per_solver in merged.values():
        for name, row in per_solver.items():
            for key, value in row.items():
                pooled[name][key] = pooled[name][key] + value
    results = {stream: {name: summary(row) for name, row in per_solver.items()}
               for stream, per_solver in merged.items()}
    results["all"] = {name: summary(row) for name, row in pooled.items()}
    elapsed = time.perf_counter() - start
    result = {
        "per_stream": results,
        "ratios": {stream: ratios(per_solver, pooled if stream == "all" else merged[stream])
                   for stream, per_solver in results.items()},
        "hpipm_settings_sweep": {
            "note": f"HPIPM's C API, cold, on every {SWEEP_EVERY}th QP of both streams (library: "
                    f"{'--hpipm-library' if args.hpipm_library else 'CasADi wheel'}); tolerances otherwise as above; "
                    "u0_error_max inf = a failed solve",
            **{name: {"qps": len(row["iterations"]), "iterations_median": float(np.median(row["iterations"])),
                      "iterations_p99": float(np.percentile(row["iterations"], 99)),
                      "failures": int(np.sum(np.isinf(row["u0_error"]))),
                      "u0_error_max": float(np.max(row["u0_error"]))} for name, row in sweep["record"].items()}},
        "method": __doc__.split("\n\n", 1)[1].strip(),
        "settings": {**{k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                     "tolerances": {"riccati_ipm": RICCATI_IPM_TOLERANCE,
                                    "hpipm_eq_ineq_comp": HPIPM_TOLERANCE,
                                    "hpipm_stationarity": HPIPM_STATIONARITY_TOLERANCE, "hpipm_mu0": HPIPM_MU0,
                                    "piqp_eps_abs_rel": NATIVE_PIQP_TOLERANCE, "osqp_eps_abs_rel": OSQP_TOLERANCE,
                                    "clarabel_reference": 1e-9},
                     "hpipm_casadi_infinity": CASADI_INFINITY,
                     "hpipm_libraries": {"casadi_wheel": str(casadi_hpipm_library()) + " (BLASFEO target GENERIC)",
                                         "avx2": (str(args.hpipm_library) + " (BLASFEO X64_INTEL_HASWELL, HPIPM AVX)")
                                         if args.hpipm_library else None}},
        "timings": {"solve_us": "the solver's own solve call (ours: the whole solve(qp); hpipm_native: "
                                "d_ocp_qp_ipm_solve; hpipm_casadi: CasADi's t_wall_solver; piqp / osqp: solve())",
                    "call_us": "from our QP's values to the solution (ours: the same call; hpipm_native: + ctypes "
                               "writes and reads; hpipm_casadi: the CasADi call's wall time; piqp / osqp: + update)"},
        "run_seconds": elapsed,
        "source": git_commit(),
        "machine": {"processor": cpu_model(), "platform": platform.platform(),
                    "cpus": os.cpu_count(), "pinned_to_one_core": hasattr(os, "sched_setaffinity"),
                    "load_average_1_5_15min_before": list(load_before),
                    "load_average_1_5_15min_after": list(os.getloadavg())},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, json.dumps(result, indent=2) + "\n")
    for stream, per_solver in results.items():
        for name, row in per_solver.items():
            if "solve_us" in row:
                print(f"{stream:8s} {name:18s} qps {row['qps']:4d} fail {row['failures']:3d} "
                      f"it {row['iterations']['median']:4.0f}/{row['iterations']['p99']:4.0f}  "
                      f"solve {row['solve_us']['median']:8.0f}/{row['solve_us']['p99']:8.0f} us  "
                      f"call {row['call_us']['median']:8.0f} us  u0 {row['u0_error']['max']:.1e}  "
                      f"f {row['objective_error']['max']:.1e}")
    print(f"{elapsed:.0f} s, wrote {args.out}")


if __name__ == "__main__":
    main()
