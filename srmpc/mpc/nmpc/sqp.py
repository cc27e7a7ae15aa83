"""Nonlinear MPC: the LTV-MPC's OCP on the exact model, solved by SQP until a convergence test (a KKT proxy) holds.

The NLP (same cost, bounds and horizon as the LTV-MPC's QP, ``problem.ocp``; no linearization)::

    min  F(w) = sum_{k=1..N} ||x_k - x^ref_k||_Q^2 + sum_{k=0..N-1} ||u_k||_R^2
                + ||u_0 - u_hat||_S^2 + sum_{k=1..N-1} ||u_k - u_{k-1}||_S^2
                + sum_j (w_col,1 s_j + w_col,2 s_j^2) + sum_{k,j} (w_safe,1 sigma_kj + w_safe,2 sigma_kj^2)
    s.t. x_0 = x_hat,  x_{k+1} = f(x_k, u_k)                 (exact 3-sub-step bicycle, ``problem.vehicle_model``)
         min_c g_{E_kj}(p_c(x_k))  + s_j      >= 1,  s_j >= 0      (collision, ``nonlinear_constraints``)
         min_c g_{E'_kj}(p_c(x_k)) + sigma_kj >= 1,  sigma_kj >= 0  (safety region)
         y, v boxes on x_1..N; delta, a boxes on u_0..N-1,

w = (x, u, s, sigma). At a solution F equals ``problem.nonlinear_cost.nonlinear_plan_cost`` of its inputs.

SQP (Gauss-Newton Hessian, l1 merit line search):

1. **QP subproblem.** At the iterate w_i, ``LtvMpcQp`` linearized about (x_i, u_i) is the SQP
   subproblem: its variables are absolute states and inputs (not deltas), its dynamics
   x_{k+1} = A_k x_k + B_k u_k + c_k the first-order expansion of f at w_i, and its Hessian P is
   F's exact Hessian (F is quadratic); the constraints' curvature is left out (Gauss-Newton),
   so P is the Lagrangian Hessian's positive semidefinite approximation and the reduced Hessian
   (R > 0) is positive definite. The QP (built for 2V vehicle slots) holds first the linearized
   collision rows (their sigma boxes closed: sigma_hi = 0), then the linearized safety rows with
   the safety slacks sigma_kj (sigma_hi = ``SAFETY_SLACK_UPPER``); the collision and safety rows
   have different gradients, so they cannot share one row as in the LTV-MPC's QP. The safety
   rows' own horizon slacks s'_j cost w_col > w_safe per unit, so a solution never uses them
   while sigma_kj <= 1 suffices, which it always does on the NLP (g' >= 0); they stay in w
   (with their cost in F and in the safety row) so that every QP solution is a point of the NLP.
   The QP is solved by our Riccati interior-point method (``solvers.RiccatiInteriorPointSolver``)
   and gives the step p_i = w_QP - w_i. The first QP of a solve starts cold (the solver's own starting
   point about x_i, u_i); each later one warm (``qp_warm_start``), from the current iterate and the
   previous QP's multipliers, unshifted (the QPs of one solve are all at one instant, and p_i -> 0
   near convergence): primal u_i rolled out through the new linearized dynamics, s and sigma those of
   w_i in their rows' slots; each row's multipliers those of the previous QP's row of the same kind and
   vehicle (0 for a row that screening just added), the bounds' as they were; inequality slacks
   t = max(a^T w - b, ``SUBPROBLEM_WARM_SLACK_FLOOR``) and every pair lifted to t z >= 0.5 mu_0
   (``solvers.ipm_start``). Safeguard: a warm start that has not solved the QP within
   ``qp_warm_start_iterations`` interior-point iterations, or fails, is discarded and the QP solved
   cold (the recorded iterations are then the sum). The QP's tolerance and the convergence test are
   the same either way; warm and cold QPs reach the same solution to the QP's tolerance, so the SQP's
   iterates differ from the cold-started ones only by that.
2. **Convergence test (a KKT proxy).** p_i = 0 solves the QP at w_i exactly when w_i is a KKT point
   of the NLP (the QP's constraints are the NLP's linearization at w_i and the reduced Hessian is
   positive definite), so ||p_i||_inf stands in for stationarity. Converged: primal infeasibility
   theta_inf(w) (largest dynamics defect |x_{k+1} - f(x_k, u_k)| and constraint violation) <=
   ``primal_tolerance`` and ||p_i||_inf <= ``stationarity_tolerance``, either at w_i, or at w_i + p_i
   when the full step was taken (theta measured there, the stationarity at w_i). The test is
   unscaled and uses no multipliers, so it certifies no KKT tolerance by itself: every result also
   carries the NLP's KKT residual with the last QP's multipliers (``kkt_residual``: stationarity of the
   Lagrangian, complementarity, primal infeasibility, and IPOPT's scaled error E), reported beside
   the test and not used by it (the closed-loop evaluations ran with this test).
3. **Merit line search.** phi_nu(w) = F(w) + nu theta_1(w), theta_1 the l1 norm of the defects and
   violations. Its directional derivative along p is D = grad F^T p - nu theta_1(w) (the QP step
   satisfies the linearized constraints). nu is raised to (grad F^T p + 1/2 p^T P p) /
   ((1 - rho) theta_1) + ``penalty_margin`` when below it (Nocedal & Wright eq. 18.36), so that
   D <= -rho nu theta_1 - 1/2 p^T P p < 0. F is quadratic: grad F^T p = (F(w + p) - F(w - p)) / 2 and
   grad F^T p + 1/2 p^T P p = F(w + p) - F(w), exactly. Backtracking alpha = 1, 1/2, ... until
   phi(w + alpha p) <= phi(w) + eta alpha D; below ``min_step`` the solve stops
   (``line_search_failed``).
4. **Anderson acceleration.** The Gauss-Newton iteration converges linearly, slowly where the
   constraints' curvature times their multipliers dominates the cost's (deep in a safety region:
   sigma's multiplier w_safe,1 + 2 w_safe,2 sigma is ~400). While full steps are taken, the last
   m + 1 pairs (w_i, G(w_i) = w_QP) give the type-II Anderson point
   w_AA = G_i - dG gamma,  gamma = argmin ||f_i - dF gamma||_2,  f = G(w) - w,
   (dF, dG: consecutive differences), projected into the boxes; it replaces the full step when its
   merit is lower. Convergence is still tested on the QP step at the new iterate. On the 300
   recorded states (``benchmarks/nmpc_initial_guess.py``) m = 5 took the median iterations from
   16 / 11 / 11 to 14 / 8 / 8 (constant velocity / shifted previous / rollout guess) and the
   unconverged solves from 35 to 26 of 900; m = 10 did no better.
5. **Stall test** (``stall_iterations`` K > 0, K = 3 by default; 0 turns it off). After K consecutive line searches that each accepted a step length
   alpha <= ``stall_step_length`` the solve stops, status ``stalled`` (not converged: the controller falls back as
   for any other unconverged solve). The convergence test is unchanged, so every converged plan is one the solve
   without the test also returns, from the same iterates; the test only ends earlier solves that are not converging.
   On the 300 recorded states x 3 guesses with warm QPs (``benchmarks/nmpc_initial_guess.py``) no converged solve
   ever took even two consecutive steps alpha <= 1/16 (875 of 876 took none), while the unconverged ones mostly
   crawl with tiny accepted steps (runs of 6 to 45) until ``max_iterations`` = 50, each iteration still paying a
   QP and the backtracking: they are the tail of the step time. K = 3 and alpha <= 1/16 leave a margin: in the
   first 20 closed-loop episodes of ``nmpc/rollout`` in dense traffic (warm QPs) the test changed no converged solve
   of 8000 and no episode, whereas alpha <= 1/8 ended one solve that converges without the test. Not caught: the
   unconverged solves that take full steps (alpha = 1) to ``max_iterations`` while ||p||_inf stagnates or slowly
   grows; a test on ||p||_inf (no new lowest value in M iterations) would end many converged solves too, since
   ||p||_inf is not monotone under Anderson's steps (M = 8 ended 137 of the 876 converged benchmark solves).

Screening: a vehicle's collision (safety) row is left out of the QP at w_i while min_{k,c} g (g') at
w_i is at least ``screening_norm`` and its slacks are 0; its slacks then keep their value (0). The NLP
is unchanged: theta, the merit and the convergence test evaluate every constraint exactly, so a step into
a screened constraint is penalized and the next QP has its row; at a converged point every screened
constraint is strictly inactive (norm >= ``screening_norm`` > 1 at the last linearization point, which
the last step moved by at most the stationarity tolerance), its multiplier 0. The QP's cost
grows with its rows (one backward Riccati pass per row's slack), so this is what keeps dense traffic
(12 rows unscreened) affordable.

The initial guess (x, u) is clipped into the input and state boxes, x_0 set to x_hat, and the
slacks start at the smallest values that satisfy the (exact) collision and safety constraints.

Implementation: the whole SQP is one compiled call, ``_sqp``, steps 1-5 above in that order, on flat points
w (``sqp_kernels``: F, theta, screening, the subproblem's assembly and warm start, Anderson's point) and on arrays
allocated once per solver: the QP's stage-wise arrays (``LtvMpcQp``, which keeps the last subproblem) and the
Riccati solver's workspace and warm-start memory (``RiccatiInteriorPointSolver`` with the subproblems' warm-start
settings: stage shift 0, slack floor, iteration limit; the planner's own warm start shifts the last solution by
one control step). Each QP is solved on max(rows, 1) vehicle slots instead of 2V (``solvers.solve_compact``),
with the same floats. F and theta are summed in numpy's order and Anderson's least squares is numpy's LAPACK
call; with ``qp_warm_start=False`` (every QP cold, the revisions before the warm start) every decision and
iterate equals that of the numpy implementation of earlier revisions, bit for bit (``tests/mpc/test_nmpc.py``
tests the pieces; all 900 solves of ``benchmarks/nmpc_initial_guess.py``'s states were compared).

Warm-started subproblems: on the 300 states of ``benchmarks/nmpc_initial_guess.py`` the SQP takes the same
iterations as with cold QPs (the QPs' solutions agree to their tolerance) and the QPs after the first take
fewer interior-point iterations (before/after in docs/planner.md, from ``results/benchmarks/
nmpc_initial_guess.json``). The slack floor 1e-3 and the limit of 15 iterations were chosen on those states:
floors of 1e-1 and 1e-5 took more iterations, a mu_0 floor of 1e-5 instead of 1e-3 changed no iterate, and a
limit of 10 discarded warm starts that would have converged in 11 to 15 iterations. Inexact early QPs (a looser
QP tolerance while ||p_i||_inf is large, the QP re-solved at ``qp_tolerance`` before a step may pass the test) were
tried on the same states and left out: they saved interior-point iterations but added SQP iterations, and most
settings of the looser tolerance and its switch-over step lost converged plans.
"""

from __future__ import annotations

import dataclasses
import time
from collections import namedtuple
from dataclasses import dataclass, field

import numba
import numpy as np

from srmpc.mpc.compiled_step import cycles_to_us, read_cycle_counter
from srmpc.mpc.nmpc.kkt_residual import KktResidual, kkt_residuals, scaled_residual
from srmpc.mpc.nmpc.nonlinear_constraints import vehicle_frames
from srmpc.mpc.nmpc.sqp_kernels import (
    SAFETY_SLACK_UPPER,
    NlpConstants,
    Subproblem,
    allocate_scratch,
    anderson_point,
    infeasibility,
    initial_point,
    linearize_subproblem,
    objective,
    point_parts,
    point_size,
    qp_candidate,
    screen,
    warm_start_memory,
)
from srmpc.mpc.problem import KinematicBicycle, LtvMpcQp, OcpConfig, OcpStepData
from srmpc.mpc.solvers import (
    RICCATI_IPM_MAX_ITERATIONS,
    STATUS_SOLVED,
    RiccatiInteriorPointSolver,
    allocate_compact,
    solve_compact,
)
from srmpc.value_checks import NON_NEGATIVE, POSITIVE, Interval, check_fields

STATUS_CONVERGED = "converged"
STATUS_MAX_ITERATIONS = "max_iterations"
STATUS_LINE_SEARCH_FAILED = "line_search_failed"
STATUS_QP_FAILED = "qp_failed"
STATUS_STALLED = "stalled"
STATUSES = (STATUS_CONVERGED, STATUS_MAX_ITERATIONS, STATUS_LINE_SEARCH_FAILED, STATUS_QP_FAILED, STATUS_STALLED)
"""The statuses by ``_sqp``'s status code (their index)."""
_CONVERGED, _MAX_ITERATIONS, _LINE_SEARCH_FAILED, _QP_FAILED, _STALLED = range(5)

SUBPROBLEM_WARM_START_MU = 1e-3
"""Lowest complementarity mu_0 of a warm-started subproblem (objective units; module doc, step 1)."""
SUBPROBLEM_WARM_CENTRALITY = 0.5
"""Each warm pair starts with t_i z_i >= this fraction of mu_0 (dimensionless)."""
SUBPROBLEM_WARM_SLACK_FLOOR = 1e-3
"""Smallest starting slack t_i of a warm-started subproblem (constraint units: m, m/s, rad, m/s^2, ellipse norm)."""
SUBPROBLEM_WARM_STAGE_SHIFT = 0
"""The subproblems of one solve are at one instant: the warm start shifts nothing (stages)."""


@dataclass(frozen=True)
class NmpcSettings:
    """SQP tolerances and limits (module doc).

    Attributes:
        primal_tolerance: largest dynamics defect [m, rad, m/s] and constraint violation [ellipse
            norm, m, m/s, rad, m/s^2] of a converged plan.
        stationarity_tolerance: largest component of the QP step p at convergence (same units as
            the variables: m, rad, m/s, rad, m/s^2, ellipse norm).
        max_iterations: most SQP iterations (QP solves).
        armijo: eta, sufficient-decrease fraction of the merit's directional derivative.
        backtracking: alpha's factor per rejected trial step.
        min_step: smallest alpha tried before the line search gives up.
        descent_fraction: rho of the penalty update (module doc).
        penalty_margin: added to the penalty's lower bound when nu is raised [objective units].
        qp_tolerance: residual tolerance of the Riccati interior-point QP solves.
        screening_norm: a vehicle's collision (safety) row is left out of a QP while its exact
            ellipse norm stays at or above this value over the whole iterate and its slacks are 0
            (dimensionless, ellipse-norm units; module doc).
        anderson_depth: m, the most past steps Anderson acceleration combines (0: off; module doc).
        qp_warm_start: start each QP after the first from the current iterate and the previous QP's multipliers
            (module doc, step 1; the default); False: every QP starts cold, as in the revisions before it:
            ``benchmarks/nmpc_initial_guess.py`` measures both.
        qp_warm_start_iterations: interior-point iterations a warm-started QP may take before it is solved again
            from the cold start (the safeguard; at most ``RICCATI_IPM_MAX_ITERATIONS``).
        stall_iterations: K, the solve stops (status ``stalled``, not converged) after K consecutive line searches
            that accepted a step length alpha <= ``stall_step_length`` (module doc, stall test); 0: off, the solve runs
            to ``max_iterations``. ``benchmarks/nmpc_initial_guess.py`` measures K = 3 (the default) paired with the
            solve without it (``stall_test_vs_without``).
        stall_step_length: largest accepted step length alpha that counts toward the stall test (dimensionless,
            in (0, 1)).
    """

    primal_tolerance: float = 1e-6
    stationarity_tolerance: float = 1e-4
    max_iterations: int = 50
    armijo: float = 1e-4
    backtracking: float = 0.5
    min_step: float = 1e-8
    descent_fraction: float = 0.1
    penalty_margin: float = 1.0
    qp_tolerance: float = 1e-7
    screening_norm: float = 3.0
    anderson_depth: int = 5
    qp_warm_start: bool = True
    qp_warm_start_iterations: int = 15
    stall_iterations: int = 3
    stall_step_length: float = 0.0625

    def __post_init__(self) -> None:
        check_fields(self, primal_tolerance=POSITIVE, stationarity_tolerance=POSITIVE,
                     max_iterations=Interval(low=1), armijo=Interval(0.0, 1.0, low_open=True, high_open=True),
                     backtracking=Interval(0.0, 1.0, low_open=True, high_open=True), min_step=POSITIVE,
                     descent_fraction=Interval(0.0, 1.0, high_open=True), penalty_margin=NON_NEGATIVE,
                     qp_tolerance=POSITIVE, screening_norm=Interval(low=1.0, low_open=True),
                     anderson_depth=Interval(low=0),
                     qp_warm_start_iterations=Interval(1, RICCATI_IPM_MAX_ITERATIONS),
                     stall_iterations=Interval(low=0),
                     stall_step_length=Interval(0.0, 1.0, low_open=True, high_open=True))
        if not isinstance(self.qp_warm_start, bool):
            raise ValueError(f"qp_warm_start={self.qp_warm_start!r}: must be true or false")


@dataclass
class NmpcResult:
    """A plan from ``NmpcSolver.solve`` and its diagnostics.

    Attributes:
        states, inputs: x_0..N (N + 1, 4), u_0..N-1 (N, 2).
        collision_slacks: s_j (V_obs,); safety_slacks: sigma_kj (N, V_obs).
        objective: F at the plan (module doc).
        status: ``converged``, ``max_iterations``, ``line_search_failed``, ``qp_failed`` or ``stalled``.
        iterations: QPs solved.
        primal_infeasibility: theta_inf at the plan.
        stationarity: ||p||_inf of the last QP step.
        merit: phi_nu at the plan, penalty: nu.
        qp_times_s: wall time of each QP solve [s] (the CPU's cycle counter); qp_iterations: interior-point
            iterations.
        step_lengths: the line search's alpha per iteration.
        step_norms: ||p||_inf of each QP step (the stationarity measure per iteration).
        qp_rows: vehicle rows (collision + safety) in each QP after screening.
        accelerated_steps: iterations that took the Anderson point instead of the full SQP step.
        solve_time_s: wall time of the whole solve [s] (the SQP; not the KKT residual's evaluation).
        kkt: the NLP's KKT residual at the plan with the last QP's multipliers (``kkt_residual``; NaN residuals
            when the last QP failed); a diagnostic beside the convergence test, not part of it.
    """

    states: np.ndarray
    inputs: np.ndarray
    collision_slacks: np.ndarray
    safety_slacks: np.ndarray
    objective: float
    status: str
    iterations: int
    primal_infeasibility: float
    stationarity: float
    merit: float
    penalty: float
    qp_times_s: list[float] = field(default_factory=list)
    qp_iterations: list[int] = field(default_factory=list)
    step_lengths: list[float] = field(default_factory=list)
    step_norms: list[float] = field(default_factory=list)
    qp_rows: list[int] = field(default_factory=list)
    accelerated_steps: int = 0
    solve_time_s: float = 0.0
    kkt: KktResidual | None = None

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED

    @property
    def first_input(self) -> np.ndarray:
        return self.inputs[0]


@dataclass
class NlpPoint:
    """A point of the NLP (an SQP iterate) w: states (N + 1, 4), inputs (N, 2), slacks (2 V_obs,) = (s_j, then the
    safety rows' s'_j), sigmas (N, V_obs)."""

    states: np.ndarray
    inputs: np.ndarray
    slacks: np.ndarray
    sigmas: np.ndarray


SqpSettings = namedtuple("SqpSettings", [
    "primal_tolerance", "stationarity_tolerance", "max_iterations", "armijo", "backtracking", "min_step",
    "descent_fraction", "penalty_margin", "anderson_depth", "stall_iterations", "stall_step_length"])
"""``NmpcSettings``' SQP part, as ``_sqp`` reads it."""
QpSettings = namedtuple("QpSettings", ["constants", "tolerance", "max_iterations", "warm_start",
                                       "warm_start_settings"])
"""The Riccati solver's ``SolverConstants`` and settings (``RiccatiInteriorPointSolver``)."""
SubproblemWarmStart = namedtuple("SubproblemWarmStart", ["previous_rows", "previous_counts", "sources", "scratch_z"])
"""What the warm start of the next QP needs (``warm_start_memory``): the last QP's collision and safety rows'
vehicles (2, V) and their numbers (2,); scratch (2V,) and (m,)."""
SqpRecord = namedtuple("SqpRecord", ["qp_cycles", "qp_iterations", "qp_rows", "step_norms", "step_lengths",
                                     "iterates", "images"])
"""Per iteration (max_iterations,): the QP's cycles, interior-point iterations and rows, ||p||_inf, alpha;
Anderson's rings of the last m + 1 pairs (w, G(w)) (m + 1, len(w) at V slots)."""


@numba.njit(cache=True, error_model="numpy", inline="always")
def _line_search(w, step, candidate, value_full, merit, derivative, penalty, settings, n_obs, frames, qp, nlp,
                 scratch, trial):
    """Backtracking alpha = 1, b, b^2, ... >= ``min_step`` until phi(w + alpha p) <= phi(w) + eta alpha D
    (module doc, step 3; the full step is the QP's point itself); the trial point in ``trial``. Returns
    (accepted, alpha, F, theta_1, theta_inf, phi) of the last trial."""
    horizon = qp.linearization_inputs.shape[0]
    alpha, trial_value, trial_theta_1, trial_theta_inf, trial_merit = 1.0, value_full, 0.0, 0.0, 0.0
    while alpha >= settings.min_step:
        if alpha == 1.0:
            trial[:] = candidate
            trial_value = value_full
        else:
            for i in range(w.shape[0]):
                trial[i] = w[i] + alpha * step[i]
            trial_value = objective(trial, horizon, n_obs, qp.tracking_reference, qp.last_input, nlp, scratch.terms)
        trial_theta_1, trial_theta_inf = infeasibility(trial, horizon, n_obs, qp.measured_state, frames, nlp, scratch)
        trial_merit = trial_value + penalty * trial_theta_1
        if trial_merit <= merit + settings.armijo * alpha * derivative + 1e-12 * abs(merit):
            return True, alpha, trial_value, trial_theta_1, trial_theta_inf, trial_merit
        alpha *= settings.backtracking
    return False, alpha, trial_value, trial_theta_1, trial_theta_inf, trial_merit


@numba.njit(cache=True, error_model="numpy", inline="always")
def _remember_pair(iterates, images, oldest, stored, w, image):
    """Append (w, G(w)) to Anderson's rings (m + 1 slots; the oldest pair is dropped when full); returns the
    new (oldest slot, pairs stored)."""
    capacity = iterates.shape[0]
    slot = (oldest + stored) % capacity
    if stored < capacity:
        stored += 1
    else:
        oldest = (oldest + 1) % capacity
    iterates[slot, :w.shape[0]] = w
    images[slot, :w.shape[0]] = image
    return oldest, stored


@numba.njit(cache=True, error_model="numpy", inline="always")
def _solve_subproblem(w, horizon, n_obs, frames, nlp, scratch, qp, qp_settings, workspace, memory, compact, record,
                      iteration, candidate, warm):
    """Step 1 (module doc): the QP subproblem linearized about w (screened rows), solved by the Riccati interior
    point (warm from w and the previous QP's multipliers when asked to and the previous QP was solved), its point
    w_QP into ``candidate``; the QP's cycles, iterations and rows into ``record`` at ``iteration``; its rows'
    vehicles into ``warm`` (``SubproblemWarmStart``). Returns whether it was solved and its point is one of the
    NLP (else the warm-start memory is invalidated)."""
    n_collision, n_safety = screen(w, horizon, n_obs, frames, nlp, scratch, qp.collision_rows, qp.safety_rows)
    n_rows = linearize_subproblem(w, horizon, n_obs, frames, n_collision, n_safety, nlp, qp)
    started = read_cycle_counter()
    if qp_settings.warm_start and memory.valid[0]:
        warm_start_memory(w, horizon, n_obs, qp, n_collision, n_safety, warm.previous_rows, warm.previous_counts,
                          memory, warm.sources, warm.scratch_z)
    qp_status, qp_iterations, solution = solve_compact(qp, n_rows, qp.measured_state, qp_settings, workspace,
                                                       memory, compact)
    record.qp_cycles[iteration] = read_cycle_counter() - started
    record.qp_iterations[iteration] = qp_iterations
    record.qp_rows[iteration] = n_rows
    warm.previous_rows[0, :n_collision] = qp.collision_rows[:n_collision]
    warm.previous_rows[1, :n_safety] = qp.safety_rows[:n_safety]
    warm.previous_counts[0], warm.previous_counts[1] = n_collision, n_safety
    if qp_status != STATUS_SOLVED:
        return False
    if not qp_candidate(w, horizon, n_obs, solution, n_collision, n_safety, qp, candidate):
        memory.valid[0] = False
        return False
    return True


@numba.njit(cache=True, error_model="numpy", inline="always")
def _step_norm(w, candidate, step):
    """Step 2 (module doc): the step p = w_QP - w into ``step``; returns ||p||_inf."""
    stationarity = 0.0
    for i in range(w.shape[0]):
        step[i] = candidate[i] - w[i]
        stationarity = max(stationarity, abs(step[i]))
    return stationarity


@numba.njit(cache=True, error_model="numpy", inline="always")
def _penalty_update(w, step, candidate, value, theta_1, penalty, settings, n_obs, qp, nlp, scratch, backward):
    """Step 3's penalty update (module doc; F quadratic: exact first- and second-order terms). Returns (F(w + p),
    nu, D, phi_nu(w))."""
    horizon = qp.linearization_inputs.shape[0]
    value_full = objective(candidate, horizon, n_obs, qp.tracking_reference, qp.last_input, nlp, scratch.terms)
    for i in range(w.shape[0]):
        backward[i] = w[i] + -1.0 * step[i]  # w - p, computed as w + alpha p with alpha = -1
    value_backward = objective(backward, horizon, n_obs, qp.tracking_reference, qp.last_input, nlp, scratch.terms)
    gradient_step = 0.5 * (value_full - value_backward)
    model_decrease = value_full - value
    if theta_1 > 0.0:
        required = model_decrease / ((1.0 - settings.descent_fraction) * theta_1)
        if penalty < required:
            penalty = required + settings.penalty_margin
    derivative = gradient_step - penalty * theta_1
    merit = value + penalty * theta_1
    return value_full, penalty, derivative, merit


@numba.njit(cache=True, error_model="numpy", inline="always")
def _anderson_trial(record, oldest, stored, n_obs, frames, qp, nlp, scratch, accelerated):
    """Step 4 (module doc): Anderson's point of the stored pairs, projected into the boxes, into ``accelerated``;
    returns its (F, theta_1, theta_inf)."""
    horizon = qp.linearization_inputs.shape[0]
    anderson_point(record.iterates, record.images, oldest, stored, horizon, n_obs, qp.measured_state, nlp,
                   accelerated)
    value = objective(accelerated, horizon, n_obs, qp.tracking_reference, qp.last_input, nlp, scratch.terms)
    theta_1, theta_inf = infeasibility(accelerated, horizon, n_obs, qp.measured_state, frames, nlp, scratch)
    return value, theta_1, theta_inf


@numba.njit(cache=True, error_model="numpy")
def _sqp(others, n_obs, initial_states, initial_inputs, nlp, settings, qp, qp_settings, workspace, memory,
         compact, scratch, record, w):
    """The SQP of the module doc from the guess, steps 1-4 in order, on the QP subproblem's arrays ``qp`` (whose
    measured state, last input and tracking reference are set). Leaves the last iterate in w; returns (status
    code, iterations, line searches, F, theta_1, theta_inf, ||p||_inf, nu, accelerated steps)."""
    horizon = initial_inputs.shape[0]
    size = point_size(horizon, n_obs)
    candidate, step, trial, backward, accelerated = (np.empty(size), np.empty(size), np.empty(size),
                                                     np.empty(size), np.empty(size))
    frames = np.empty((horizon + 1, n_obs, 4))
    vehicle_frames(others, n_obs, frames)
    initial_point(qp.measured_state, frames, n_obs, initial_states, initial_inputs, nlp, scratch, w)
    value = objective(w, horizon, n_obs, qp.tracking_reference, qp.last_input, nlp, scratch.terms)
    theta_1, theta_inf = infeasibility(w, horizon, n_obs, qp.measured_state, frames, nlp, scratch)
    penalty, stationarity, status = 0.0, np.inf, _MAX_ITERATIONS
    iterations, line_searches, accelerated_steps = 0, 0, 0
    short_steps = 0  # consecutive accepted steps with alpha <= stall_step_length (the stall test)
    oldest, stored = 0, 0  # Anderson's pairs: the ring's oldest slot and the pairs it holds
    memory.valid[0] = False  # the first QP starts cold
    n_slots = qp.collision_rows.shape[0]
    warm = SubproblemWarmStart(np.zeros((2, n_slots), dtype=np.int64), np.zeros(2, dtype=np.int64),
                               np.empty(2 * n_slots, dtype=np.int64), np.empty(memory.z.shape[0]))
    for _ in range(settings.max_iterations):
        solved = _solve_subproblem(w, horizon, n_obs, frames, nlp, scratch, qp, qp_settings, workspace, memory,
                                   compact, record, iterations, candidate, warm)  # 1.
        iterations += 1
        if not solved:
            status = _QP_FAILED
            break
        stationarity = _step_norm(w, candidate, step)  # 2. convergence at w
        record.step_norms[iterations - 1] = stationarity
        if theta_inf <= settings.primal_tolerance and stationarity <= settings.stationarity_tolerance:
            status = _CONVERGED
            break
        value_full, penalty, derivative, merit = _penalty_update(w, step, candidate, value, theta_1, penalty,
                                                                 settings, n_obs, qp, nlp, scratch, backward)  # 3.
        accepted, alpha, trial_value, trial_theta_1, trial_theta_inf, trial_merit = _line_search(
            w, step, candidate, value_full, merit, derivative, penalty, settings, n_obs, frames, qp, nlp, scratch,
            trial)
        record.step_lengths[line_searches] = alpha if accepted else 0.0
        line_searches += 1
        if not accepted:
            status = _LINE_SEARCH_FAILED
            break
        if (alpha == 1.0 and trial_theta_inf <= settings.primal_tolerance
                and stationarity <= settings.stationarity_tolerance):  # 2. convergence at w + p
            w[:] = trial
            value, theta_1, theta_inf = trial_value, trial_theta_1, trial_theta_inf
            status = _CONVERGED
            break
        if alpha < 1.0:  # 4. Anderson's point replaces the full step if its merit is lower
            oldest, stored = 0, 0
        else:
            oldest, stored = _remember_pair(record.iterates, record.images, oldest, stored, w, candidate)
            if stored >= 2 and settings.anderson_depth > 0:
                anderson = _anderson_trial(record, oldest, stored, n_obs, frames, qp, nlp, scratch, accelerated)
                if anderson[0] + penalty * anderson[1] < trial_merit:
                    trial[:] = accelerated
                    trial_value, trial_theta_1, trial_theta_inf = anderson
                    accelerated_steps += 1
        w[:] = trial
        value, theta_1, theta_inf = trial_value, trial_theta_1, trial_theta_inf
        short_steps = short_steps + 1 if alpha <= settings.stall_step_length else 0  # the stall test
        if settings.stall_iterations > 0 and short_steps >= settings.stall_iterations:
            status = _STALLED
            break
    return status, iterations, line_searches, value, theta_1, theta_inf, stationarity, penalty, accelerated_steps


class NmpcSolver:
    """SQP for the nonlinear OCP (module doc); one instance per OCP configuration.

    Args:
        config: the LTV-MPC's OCP configuration (cost, bounds, horizon, geometry).
        settings: tolerances and limits.
    """

    def __init__(self, config: OcpConfig | None = None, settings: NmpcSettings | None = None) -> None:
        self.config = config or OcpConfig()
        self.settings = settings or NmpcSettings()
        config, settings = self.config, self.settings
        horizon, n_slots = config.horizon, config.max_vehicles
        self.qp = LtvMpcQp(dataclasses.replace(config, max_vehicles=2 * n_slots))
        self.model = KinematicBicycle(config.bicycle)
        # the planner's warm start shifts the last solution by one control step, but the QPs of one SQP solve are
        # all at the same instant: an unshifted warm start from the current iterate (module doc, step 1)
        self.qp_solver = RiccatiInteriorPointSolver(
            tolerance=settings.qp_tolerance, max_iterations=RICCATI_IPM_MAX_ITERATIONS,
            warm_start=settings.qp_warm_start,
            warm_start_settings=(SUBPROBLEM_WARM_START_MU, SUBPROBLEM_WARM_CENTRALITY, SUBPROBLEM_WARM_SLACK_FLOOR,
                                 SUBPROBLEM_WARM_STAGE_SHIFT, int(settings.qp_warm_start_iterations)))
        self.qp_solver.bind(self.qp)
        geometry, weights = config.geometry, config.weights
        self.nlp = NlpConstants(
            tuple(self.model.kernel_args), np.asarray(geometry.circle_offsets_m, dtype=np.float64),
            np.asarray(geometry.collision_semi_axes_m, dtype=np.float64),
            np.asarray(geometry.safety_semi_axes_m, dtype=np.float64), np.asarray(weights.state, dtype=np.float64),
            np.asarray(weights.input, dtype=np.float64), np.asarray(weights.input_rate, dtype=np.float64),
            np.array([weights.collision_slack_linear, weights.collision_slack_quadratic, weights.safety_slack_linear,
                      weights.safety_slack_quadratic], dtype=np.float64),
            np.array([-np.inf, config.lateral_bounds_m[0], -np.inf, config.speed_bounds_mps[0]]),
            np.array([np.inf, config.lateral_bounds_m[1], np.inf, config.speed_bounds_mps[1]]),
            np.array([config.steering_bounds_rad[0], config.acceleration_bounds_mps2[0]]),
            np.array([config.steering_bounds_rad[1], config.acceleration_bounds_mps2[1]]),
            float(settings.screening_norm))
        qp = self.qp
        self._subproblem = Subproblem(
            qp.measured_state, qp.last_input, qp.tracking_reference, qp.linearization_inputs, qp.next_states,
            qp.state_matrices, qp.input_matrices, qp.affine_offsets, qp.collision_coefficients,
            qp.collision_row_lower, qp.safety_slack_upper, np.zeros((horizon + 1, 2 * n_slots, 4)),
            np.zeros((horizon, 2 * n_slots)), np.zeros(n_slots, dtype=np.int64), np.zeros(n_slots, dtype=np.int64))
        self._sqp_settings = SqpSettings(
            float(settings.primal_tolerance), float(settings.stationarity_tolerance), int(settings.max_iterations),
            float(settings.armijo), float(settings.backtracking), float(settings.min_step),
            float(settings.descent_fraction), float(settings.penalty_margin), int(settings.anderson_depth),
            int(settings.stall_iterations), float(settings.stall_step_length))
        solver = self.qp_solver
        self._qp_settings = QpSettings(solver.constants, solver.tolerance, solver.max_iterations, solver.warm_start,
                                       tuple(solver.warm_start_settings))
        self._scratch = allocate_scratch(horizon, n_slots)
        self._compact = allocate_compact(horizon, 2 * n_slots)
        iterations, size = max(settings.max_iterations, 1), point_size(horizon, n_slots)
        self._record = SqpRecord(np.zeros(iterations, dtype=np.uint64), np.zeros(iterations, dtype=np.int64),
                                 np.zeros(iterations, dtype=np.int64), np.zeros(iterations), np.zeros(iterations),
                                 np.zeros((settings.anderson_depth + 1, size)),
                                 np.zeros((settings.anderson_depth + 1, size)))
        cycles_to_us(np.zeros(0))  # calibrates the cycle counter once, before the first timed solve

    def _check(self, step: OcpStepData) -> None:
        """The kernels do not check bounds: the step's horizon and vehicle count against the OCP's (its arrays'
        shapes against each other are ``OcpStepData``'s own check)."""
        if step.horizon != self.config.horizon:
            raise ValueError(f"the step's horizon N = {step.horizon} is not the OCP's {self.config.horizon}")
        if step.n_observed > self.config.max_vehicles:
            raise ValueError(f"{step.n_observed} vehicles exceed max_vehicles={self.config.max_vehicles}")

    def _frames(self, others: np.ndarray) -> np.ndarray:
        frames = np.empty(others.shape)
        vehicle_frames(others, others.shape[1], frames)
        return frames

    def _point(self, w: np.ndarray, n_obs: int) -> NlpPoint:
        return NlpPoint(*point_parts(w, self.config.horizon, n_obs))

    # ------------------------------------------------------------------ NLP functions
    def initial_point(self, step: OcpStepData) -> NlpPoint:
        """The guess (the step's ``linearization_states`` and ``linearization_inputs``) clipped into the boxes,
        x_0 = x_hat, the smallest feasible slacks (module doc)."""
        self._check(step)
        n_obs = step.n_observed
        w = np.empty(point_size(self.config.horizon, n_obs))
        initial_point(step.measured_state, self._frames(step.predicted_others), n_obs, step.linearization_states,
                      step.linearization_inputs, self.nlp, self._scratch, w)
        return self._point(w, n_obs)

    def evaluate(self, point: NlpPoint, step: OcpStepData) -> tuple[float, float, float]:
        """(F, theta_1, theta_inf) at ``point`` (module doc), as the SQP evaluates them, for the step's x_hat, u_hat,
        x^ref and predicted vehicles (its guess is not read)."""
        self._check(step)
        horizon, n_obs = self.config.horizon, step.n_observed
        w = np.concatenate([np.ravel(point.states), np.ravel(point.inputs), np.ravel(point.slacks),
                            np.ravel(point.sigmas)]).astype(np.float64)
        if w.size != point_size(horizon, n_obs):
            raise ValueError(f"the point has {w.size} values, not {point_size(horizon, n_obs)}")
        frames = self._frames(step.predicted_others)
        value = objective(w, horizon, n_obs, step.tracking_reference, step.last_input, self.nlp, self._scratch.terms)
        theta_1, theta_inf = infeasibility(w, horizon, n_obs, step.measured_state, frames, self.nlp, self._scratch)
        return float(value), float(theta_1), float(theta_inf)

    # ------------------------------------------------------------------ SQP
    def solve(self, step: OcpStepData) -> NmpcResult:
        """Solve the NLP from the initial guess (module doc): the step's ``linearization_states`` and
        ``linearization_inputs`` are the guess, its x_hat, u_hat, x^ref and predicted vehicles (V_obs <=
        ``config.max_vehicles``) the problem's, as for the QP (``OcpStepData``).

        ``qp`` keeps the last subproblem (its stage-wise arrays; ``qp_solver.solve(qp)`` solves it again).
        """
        start = time.perf_counter()
        self._check(step)
        others, initial_states, initial_inputs = (step.predicted_others, step.linearization_states,
                                                  step.linearization_inputs)
        n_obs = step.n_observed
        qp = self.qp
        qp.measured_state[:] = step.measured_state
        qp.last_input[:] = step.last_input
        qp.tracking_reference[:] = step.tracking_reference
        w = np.empty(point_size(self.config.horizon, n_obs))
        record = self._record
        (status, iterations, line_searches, value, theta_1, theta_inf, stationarity, penalty,
         accelerated_steps) = _sqp(
            others, n_obs, initial_states, initial_inputs, self.nlp, self._sqp_settings, self._subproblem,
            self._qp_settings, self.qp_solver.workspace, self.qp_solver.memory, self._compact, self._scratch, record, w)
        elapsed = time.perf_counter() - start
        if iterations:
            qp.n_observed = int(record.qp_rows[iterations - 1])
            qp.stagewise_data_changed()  # the stage-wise arrays changed (as after ``LtvMpcQp.update``)
        kkt = self._kkt_residual(w, n_obs, others, status, iterations, theta_inf)
        point = self._point(w, n_obs)
        steps = iterations - (status == _QP_FAILED)
        return NmpcResult(
            point.states, point.inputs, point.slacks[:n_obs].copy(), point.sigmas.copy(), float(value),
            STATUSES[status], int(iterations), float(theta_inf), float(stationarity),
            float(value + penalty * theta_1), float(penalty),
            qp_times_s=(cycles_to_us(record.qp_cycles[:iterations]) * 1e-6).tolist(),
            qp_iterations=record.qp_iterations[:iterations].tolist(),
            step_lengths=record.step_lengths[:line_searches].tolist(),
            step_norms=record.step_norms[:steps].tolist(), qp_rows=record.qp_rows[:iterations].tolist(),
            accelerated_steps=int(accelerated_steps), solve_time_s=elapsed, kkt=kkt)

    def _kkt_residual(self, w: np.ndarray, n_obs: int, others: np.ndarray, status: int, iterations: int,
                      theta_inf: float) -> KktResidual:
        """``kkt_residual``'s residual at the plan w with the multipliers of the last QP (still in the Riccati solver's
        workspace; read only, so the next solve is unchanged)."""
        if status == _QP_FAILED or not iterations:
            return KktResidual.unavailable(theta_inf)
        subproblem = self._subproblem
        residuals = kkt_residuals(w, n_obs, subproblem.last_input, subproblem.tracking_reference, self._frames(others),
                                  self.nlp, self.qp_solver.workspace, int(self._record.qp_rows[iterations - 1]),
                                  subproblem.sigma_upper, subproblem.collision_rows, subproblem.safety_rows)
        stationarity, complementarity, multiplier_norm, inequality_norm, n_equalities, n_inequalities = residuals
        return scaled_residual(stationarity, complementarity, theta_inf, multiplier_norm, inequality_norm,
                               n_equalities, n_inequalities)


__all__ = ["KktResidual", "NlpPoint", "NmpcResult", "NmpcSettings", "NmpcSolver", "SAFETY_SLACK_UPPER"]
