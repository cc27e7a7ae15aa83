"""Nonlinear MPC: the LTV-MPC's OCP on the exact model, solved to a KKT tolerance by SQP.

The NLP (same cost, bounds and horizon as the LTV-MPC's QP, ``ocp.py``; no linearization)::

    min  F(w) = sum_{k=1..N} ||x_k - x^ref_k||_Q^2 + sum_{k=0..N-1} ||u_k||_R^2
                + ||u_0 - u_hat||_S^2 + sum_{k=1..N-1} ||u_k - u_{k-1}||_S^2
                + sum_j (w_col,1 s_j + w_col,2 s_j^2) + sum_{k,j} (w_safe,1 sigma_kj + w_safe,2 sigma_kj^2)
    s.t. x_0 = x_hat,  x_{k+1} = f(x_k, u_k)                 (exact 3-sub-step bicycle, ``vehicle_model``)
         min_c g_{E_kj}(p_c(x_k))  + s_j      >= 1,  s_j >= 0      (collision, ``nonlinear_constraints``)
         min_c g_{E'_kj}(p_c(x_k)) + sigma_kj >= 1,  sigma_kj >= 0  (safety region)
         y, v boxes on x_1..N; delta, a boxes on u_0..N-1,

w = (x, u, s, sigma). At a solution F equals ``nonlinear_cost.nonlinear_plan_cost`` of its inputs.

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
   and gives the step p_i = w_QP - w_i.
2. **Convergence (KKT).** p_i = 0 solves the QP at w_i exactly when w_i is a KKT point of the
   NLP (the QP's constraints are the NLP's linearization at w_i and the reduced Hessian is
   positive definite), so ||p_i||_inf is the stationarity measure (the Riccati solver returns no
   multipliers). Converged: primal infeasibility theta_inf(w) (largest dynamics defect
   |x_{k+1} - f(x_k, u_k)| and constraint violation) <= ``primal_tolerance`` and
   ||p_i||_inf <= ``stationarity_tolerance``, either at w_i, or at w_i + p_i when the full step
   was taken (theta measured there, the stationarity at w_i).
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
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from srmpc.mpc.nonlinear_constraints import linearize_ellipse_rows, min_ellipse_norms
from srmpc.mpc.ocp import OcpConfig
from srmpc.mpc.qp_builder import LtvMpcQp
from srmpc.mpc.solvers import RiccatiInteriorPointSolver
from srmpc.mpc.vehicle_model import KinematicBicycle

SAFETY_SLACK_UPPER = 10.0
"""Upper box of the safety slacks sigma_kj in the QP subproblem (ellipse-norm units, dimensionless).
Never active at an NLP solution (sigma = max(0, 1 - g') <= 1); it only bounds the QP's interior."""

STATUS_CONVERGED = "converged"
STATUS_MAX_ITERATIONS = "max_iterations"
STATUS_LINE_SEARCH_FAILED = "line_search_failed"
STATUS_QP_FAILED = "qp_failed"


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


@dataclass
class NmpcResult:
    """A plan from ``NmpcSolver.solve`` and its diagnostics.

    Attributes:
        states, inputs: x_0..N (N + 1, 4), u_0..N-1 (N, 2).
        collision_slacks: s_j (V_obs,); safety_slacks: sigma_kj (N, V_obs).
        objective: F at the plan (module doc).
        status: ``converged``, ``max_iterations``, ``line_search_failed`` or ``qp_failed``.
        iterations: QPs solved.
        primal_infeasibility: theta_inf at the plan.
        stationarity: ||p||_inf of the last QP step.
        merit: phi_nu at the plan, penalty: nu.
        qp_times_s: wall time of each QP solve [s]; qp_iterations: interior-point iterations.
        step_lengths: the line search's alpha per iteration.
        step_norms: ||p||_inf of each QP step (the stationarity measure per iteration).
        qp_rows: vehicle rows (collision + safety) in each QP after screening.
        accelerated_steps: iterations that took the Anderson point instead of the full SQP step.
        solve_time_s: wall time of the whole solve [s].
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

    @property
    def converged(self) -> bool:
        return self.status == STATUS_CONVERGED

    @property
    def first_input(self) -> np.ndarray:
        return self.inputs[0]


@dataclass
class _Point:
    """An SQP iterate w: states (N + 1, 4), inputs (N, 2), slacks (2 V_obs,) = (s_j, then the safety
    rows' s'_j), sigmas (N, V_obs)."""

    states: np.ndarray
    inputs: np.ndarray
    slacks: np.ndarray
    sigmas: np.ndarray

    def plus(self, step: _Point, alpha: float) -> _Point:
        return _Point(self.states + alpha * step.states, self.inputs + alpha * step.inputs,
                      self.slacks + alpha * step.slacks, self.sigmas + alpha * step.sigmas)

    def minus(self, other: _Point) -> _Point:
        return _Point(self.states - other.states, self.inputs - other.inputs,
                      self.slacks - other.slacks, self.sigmas - other.sigmas)

    def flat(self) -> np.ndarray:
        return np.concatenate([self.states.ravel(), self.inputs.ravel(), self.slacks, self.sigmas.ravel()])

    def unflat(self, flat: np.ndarray) -> _Point:
        """A point shaped like this one from ``flat`` (the layout of ``flat()``)."""
        parts, start = [], 0
        for array in (self.states, self.inputs, self.slacks, self.sigmas):
            parts.append(flat[start:start + array.size].reshape(array.shape).copy())
            start += array.size
        return _Point(*parts)

    def max_abs(self) -> float:
        return max(np.abs(self.states).max(), np.abs(self.inputs).max(),
                   np.abs(self.slacks).max(initial=0.0), np.abs(self.sigmas).max(initial=0.0))


class NmpcSolver:
    """SQP for the nonlinear OCP (module doc); one instance per OCP configuration.

    Args:
        config: the LTV-MPC's OCP configuration (cost, bounds, horizon, geometry).
        settings: tolerances and limits.
    """

    def __init__(self, config: OcpConfig | None = None, settings: NmpcSettings | None = None) -> None:
        self.config = config or OcpConfig()
        self.settings = settings or NmpcSettings()
        self.qp = LtvMpcQp(dataclasses.replace(self.config, max_vehicles=2 * self.config.max_vehicles))
        self.model = KinematicBicycle(self.config.bicycle)
        self.qp_solver = RiccatiInteriorPointSolver(tolerance=self.settings.qp_tolerance)
        geometry = self.config.geometry
        self.circle_offsets = np.asarray(geometry.circle_offsets_m, dtype=np.float64)
        self.collision_semi_axes = np.asarray(geometry.collision_semi_axes_m, dtype=np.float64)
        self.safety_semi_axes = np.asarray(geometry.safety_semi_axes_m, dtype=np.float64)
        weights = self.config.weights
        self._q = np.asarray(weights.state, dtype=np.float64)
        self._r = np.asarray(weights.input, dtype=np.float64)
        self._s = np.asarray(weights.input_rate, dtype=np.float64)
        config = self.config
        self._input_lower = np.array([config.steering_bounds_rad[0], config.acceleration_bounds_m_s2[0]])
        self._input_upper = np.array([config.steering_bounds_rad[1], config.acceleration_bounds_m_s2[1]])
        self._state_lower = np.array([-np.inf, config.lateral_bounds_m[0], -np.inf, config.speed_bounds_m_s[0]])
        self._state_upper = np.array([np.inf, config.lateral_bounds_m[1], np.inf, config.speed_bounds_m_s[1]])

    # ------------------------------------------------------------------ NLP functions
    def objective(self, point: _Point, tracking_reference: np.ndarray, last_input: np.ndarray, n_obs: int) -> float:
        """F(w) of the module doc (slots >= 2 V_obs are empty and zero)."""
        weights = self.config.weights
        error = point.states[1:] - tracking_reference[1:]
        rates = np.diff(np.vstack([last_input[None, :], point.inputs]), axis=0)
        slacks, sigmas = point.slacks, point.sigmas
        return float(np.sum(self._q * error**2) + np.sum(self._r * point.inputs**2) + np.sum(self._s * rates**2)
                     + weights.collision_slack_linear * slacks.sum()
                     + weights.collision_slack_quadratic * np.sum(slacks**2)
                     + weights.safety_slack_linear * sigmas.sum()
                     + weights.safety_slack_quadratic * np.sum(sigmas**2))

    def infeasibility(self, point: _Point, measured_state: np.ndarray, others: np.ndarray,
                      n_obs: int) -> tuple[float, float]:
        """(theta_1, theta_inf): l1 and max norms of the dynamics defects and constraint violations."""
        next_states = self.model.linearize(point.states, point.inputs)[0]
        parts = [np.abs(point.states[1:] - next_states).ravel(), np.abs(point.states[0] - measured_state),
                 np.maximum(self._state_lower - point.states[1:], 0.0).ravel(),
                 np.maximum(point.states[1:] - self._state_upper, 0.0).ravel(),
                 np.maximum(self._input_lower - point.inputs, 0.0).ravel(),
                 np.maximum(point.inputs - self._input_upper, 0.0).ravel()]
        if n_obs:
            collision, safety = self._norms(point.states, others, n_obs)
            parts.append(np.maximum(1.0 - collision - point.slacks[None, :n_obs], 0.0).ravel())
            parts.append(np.maximum(1.0 - safety - point.sigmas - point.slacks[None, n_obs:], 0.0).ravel())
            parts.append(np.maximum(-point.slacks, 0.0))
            parts.append(np.maximum(-point.sigmas, 0.0).ravel())
        violations = np.concatenate(parts)
        return float(violations.sum()), float(violations.max(initial=0.0))

    def _norms(self, states: np.ndarray, others: np.ndarray, n_obs: int) -> tuple[np.ndarray, np.ndarray]:
        horizon = self.config.horizon
        collision = np.empty((horizon, n_obs))
        safety = np.empty((horizon, n_obs))
        min_ellipse_norms(states, others, n_obs, self.circle_offsets, self.collision_semi_axes, collision)
        min_ellipse_norms(states, others, n_obs, self.circle_offsets, self.safety_semi_axes, safety)
        return collision, safety

    def initial_point(self, measured_state: np.ndarray, others: np.ndarray, initial_states: np.ndarray,
                      initial_inputs: np.ndarray) -> _Point:
        """The guess clipped into the boxes, x_0 = x_hat, the smallest feasible slacks (module doc)."""
        horizon = self.config.horizon
        n_obs = others.shape[1]
        states = np.clip(np.array(initial_states, dtype=np.float64), self._state_lower, self._state_upper)
        states[0] = measured_state
        inputs = np.clip(np.array(initial_inputs, dtype=np.float64), self._input_lower, self._input_upper)
        slacks = np.zeros(2 * n_obs)
        sigmas = np.zeros((horizon, n_obs))
        if n_obs:
            collision, safety = self._norms(states, others, n_obs)
            slacks[:n_obs] = np.maximum(1.0 - collision, 0.0).max(axis=0)
            sigmas[:] = np.maximum(1.0 - safety, 0.0)
        return _Point(states, inputs, slacks, sigmas)

    # ------------------------------------------------------------------ SQP
    def _screen(self, point: _Point, others: np.ndarray, n_obs: int) -> tuple[np.ndarray, np.ndarray]:
        """Vehicles whose collision / safety rows enter the QP at ``point`` (module doc, screening)."""
        if not n_obs:
            empty = np.zeros(0, dtype=np.int64)
            return empty, empty
        collision, safety = self._norms(point.states, others, n_obs)
        threshold = self.settings.screening_norm
        keep_collision = (collision.min(axis=0) < threshold) | (point.slacks[:n_obs] > 0.0)
        keep_safety = ((safety.min(axis=0) < threshold) | (point.slacks[n_obs:] > 0.0)
                       | (point.sigmas > 0.0).any(axis=0))
        return np.flatnonzero(keep_collision), np.flatnonzero(keep_safety)

    def _solve_subproblem(self, point: _Point, measured_state, last_input, tracking_reference, others,
                          n_obs, result: NmpcResult) -> _Point | None:
        """The QP linearized about ``point`` (module doc, step 1); its solution, or None if it failed."""
        qp = self.qp
        collision_rows, safety_rows = self._screen(point, others, n_obs)
        n_collision, n_rows = collision_rows.size, collision_rows.size + safety_rows.size
        row_others = np.ascontiguousarray(others[:, np.concatenate([collision_rows, safety_rows])])
        qp.update(measured_state, point.states, point.inputs, tracking_reference, last_input, row_others)
        if n_rows:
            norms = np.empty((self.config.horizon, n_rows))
            linearize_ellipse_rows(point.states, row_others, n_collision, self.circle_offsets,
                                   self.collision_semi_axes, qp.collision_coefficients, qp.collision_row_lower, norms)
            linearize_ellipse_rows(point.states, row_others[:, n_collision:], safety_rows.size, self.circle_offsets,
                                   self.safety_semi_axes, qp.collision_coefficients[:, n_collision:],
                                   qp.collision_row_lower[:, n_collision:], norms)
            qp.safety_slack_upper[:, :n_collision] = 0.0
            qp.safety_slack_upper[:, n_collision:n_rows] = SAFETY_SLACK_UPPER
        start = time.perf_counter()
        solution = self.qp_solver.solve(qp)
        result.qp_times_s.append(time.perf_counter() - start)
        result.qp_iterations.append(int(solution.iterations or 0))
        result.qp_rows.append(n_rows)
        if not solution.solved:
            return None
        states, inputs, qp_slacks, qp_sigmas = qp.split_solution(solution.z)
        slacks, sigmas = point.slacks.copy(), point.sigmas.copy()
        slacks[collision_rows] = qp_slacks[:n_collision]
        slacks[n_obs + safety_rows] = qp_slacks[n_collision:n_rows]
        sigmas[:, safety_rows] = qp_sigmas[:, n_collision:n_rows]
        return _Point(states, inputs, slacks, sigmas)

    def _anderson(self, history, point: _Point, measured_state: np.ndarray) -> _Point | None:
        """w_AA = G_i - dG gamma, gamma = argmin ||f_i - dF gamma||_2 over the last pairs (w, G(w)), f = G(w) - w;
        projected into the boxes (module doc, step 4). None with fewer than two pairs or depth 0."""
        if len(history) < 2 or self.settings.anderson_depth == 0:
            return None
        iterates = np.stack([w for w, _ in history], axis=1)
        images = np.stack([g for _, g in history], axis=1)
        residuals = images - iterates
        residual_differences = np.diff(residuals, axis=1)
        gamma = np.linalg.lstsq(residual_differences, residuals[:, -1], rcond=None)[0]
        flat = images[:, -1] - np.diff(images, axis=1) @ gamma
        accelerated = point.unflat(flat)
        accelerated.states[0] = measured_state
        accelerated.states[1:] = np.clip(accelerated.states[1:], self._state_lower, self._state_upper)
        np.clip(accelerated.inputs, self._input_lower, self._input_upper, out=accelerated.inputs)
        np.maximum(accelerated.slacks, 0.0, out=accelerated.slacks)
        np.maximum(accelerated.sigmas, 0.0, out=accelerated.sigmas)
        return accelerated

    def solve(self, measured_state: np.ndarray, last_input: np.ndarray, predicted_others: np.ndarray,
              tracking_reference: np.ndarray, initial_states: np.ndarray, initial_inputs: np.ndarray) -> NmpcResult:
        """Solve the NLP from the initial guess (module doc).

        Args:
            measured_state: x_hat (4,); last_input: u_hat (2,).
            predicted_others: (N + 1, V_obs, 4) other vehicles, V_obs <= ``config.max_vehicles``.
            tracking_reference: (N + 1, 4) x^ref (row 0 unused).
            initial_states, initial_inputs: the guess (N + 1, 4), (N, 2).
        """
        start = time.perf_counter()
        settings = self.settings
        measured_state = np.asarray(measured_state, dtype=np.float64)
        last_input = np.asarray(last_input, dtype=np.float64)
        tracking_reference = np.asarray(tracking_reference, dtype=np.float64)
        others = np.ascontiguousarray(predicted_others, dtype=np.float64)
        n_obs = others.shape[1]
        if n_obs > self.config.max_vehicles:
            raise ValueError(f"{n_obs} vehicles exceed max_vehicles={self.config.max_vehicles}")
        point = self.initial_point(measured_state, others, initial_states, initial_inputs)
        objective = self.objective(point, tracking_reference, last_input, n_obs)
        theta_1, theta_inf = self.infeasibility(point, measured_state, others, n_obs)
        penalty = 0.0
        stationarity = np.inf
        result = NmpcResult(point.states, point.inputs, point.slacks, point.sigmas, objective, STATUS_MAX_ITERATIONS,
                            0, theta_inf, stationarity, objective, penalty)
        status = STATUS_MAX_ITERATIONS
        history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=settings.anderson_depth + 1)
        for _ in range(settings.max_iterations):
            candidate = self._solve_subproblem(point, measured_state, last_input, tracking_reference, others,
                                               n_obs, result)
            result.iterations += 1
            if candidate is None:
                status = STATUS_QP_FAILED
                break
            step = candidate.minus(point)
            stationarity = step.max_abs()
            result.step_norms.append(stationarity)
            if theta_inf <= settings.primal_tolerance and stationarity <= settings.stationarity_tolerance:
                status = STATUS_CONVERGED
                break
            # penalty update (module doc, step 3); F quadratic: exact first/second-order terms
            objective_full = self.objective(candidate, tracking_reference, last_input, n_obs)
            objective_back = self.objective(point.plus(step, -1.0), tracking_reference, last_input, n_obs)
            gradient_step = 0.5 * (objective_full - objective_back)
            model_decrease = objective_full - objective
            if theta_1 > 0.0:
                required = model_decrease / ((1.0 - settings.descent_fraction) * theta_1)
                if penalty < required:
                    penalty = required + settings.penalty_margin
            derivative = gradient_step - penalty * theta_1
            merit = objective + penalty * theta_1
            alpha = 1.0
            accepted = False
            while alpha >= settings.min_step:
                trial = candidate if alpha == 1.0 else point.plus(step, alpha)
                trial_objective = objective_full if alpha == 1.0 else self.objective(
                    trial, tracking_reference, last_input, n_obs)
                trial_theta_1, trial_theta_inf = self.infeasibility(trial, measured_state, others, n_obs)
                trial_merit = trial_objective + penalty * trial_theta_1
                if trial_merit <= merit + settings.armijo * alpha * derivative + 1e-12 * abs(merit):
                    accepted = True
                    break
                alpha *= settings.backtracking
            result.step_lengths.append(alpha if accepted else 0.0)
            if not accepted:
                status = STATUS_LINE_SEARCH_FAILED
                break
            if (alpha == 1.0 and trial_theta_inf <= settings.primal_tolerance
                    and stationarity <= settings.stationarity_tolerance):
                point, objective, theta_1, theta_inf = trial, trial_objective, trial_theta_1, trial_theta_inf
                status = STATUS_CONVERGED
                break
            # Anderson acceleration of the full-step iteration (module doc, step 4)
            if alpha < 1.0:
                history.clear()
            else:
                history.append((point.flat(), candidate.flat()))
                accelerated = self._anderson(history, point, measured_state)
                if accelerated is not None:
                    aa_objective = self.objective(accelerated, tracking_reference, last_input, n_obs)
                    aa_theta_1, aa_theta_inf = self.infeasibility(accelerated, measured_state, others, n_obs)
                    if aa_objective + penalty * aa_theta_1 < trial_merit:
                        trial, trial_objective, trial_theta_1, trial_theta_inf = (
                            accelerated, aa_objective, aa_theta_1, aa_theta_inf)
                        result.accelerated_steps += 1
            point, objective, theta_1, theta_inf = trial, trial_objective, trial_theta_1, trial_theta_inf
        result.states, result.inputs = point.states, point.inputs
        result.collision_slacks = point.slacks[:n_obs].copy()
        result.safety_slacks = point.sigmas.copy()
        result.objective, result.status, result.primal_infeasibility = objective, status, theta_inf
        result.stationarity, result.penalty = stationarity, penalty
        result.merit = objective + penalty * theta_1
        result.solve_time_s = time.perf_counter() - start
        return result


__all__ = ["NmpcResult", "NmpcSettings", "NmpcSolver", "SAFETY_SLACK_UPPER"]
