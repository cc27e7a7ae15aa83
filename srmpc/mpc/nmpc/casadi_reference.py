"""The NMPC's NLP written independently in CasADi and solved by IPOPT (the reference for ``sqp``).

Same problem as ``sqp``'s module doc, written from the definitions, not from our linearizations:
the 3-sub-step explicit-Euler bicycle with highway-env's speed clipping (``problem.vehicle_model``, as
``if_else``), and per stage k = 1..N, vehicle j and ego circle c the smooth constraints

    g_{E_kj}(p_c(x_k)) + s_j >= 1,    g_{E'_kj}(p_c(x_k)) + sigma_kj >= 1,

which are ``min_c g + slack >= 1`` written circle by circle. IPOPT uses the exact Hessian of the
Lagrangian (CasADi's algorithmic differentiation), MUMPS, one thread.

CasADi is an optional dependency (``pip install -e '.[nmpc]'``); importing this module without it
raises ImportError.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from srmpc.mpc.problem import OcpConfig

IPOPT_TOLERANCE = 1e-9
"""IPOPT's overall NLP error tolerance ``tol`` (scaled KKT residual, dimensionless)."""
IPOPT_MAX_ITERATIONS = 1000
"""IPOPT's ``max_iter``."""
WARM_START_OPTIONS = {"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-8, "ipopt.bound_push": 1e-10,
                      "ipopt.bound_frac": 1e-10}
"""IPOPT started at a given point with a small barrier parameter mu_0 (objective units) and bound push
(the variables' units): a KKT point stays where it is, so this certifies another solver's solution."""


@dataclass
class IpoptResult:
    """IPOPT's plan: states (N + 1, 4), inputs (N, 2), slacks s (V,), sigma (N, V), F, status text,
    success flag, iterations, wall time of the solver call [s]; IPOPT's primal and dual infeasibility
    (``inf_pr``, ``inf_du`` of its iteration log: unscaled constraint violation, scaled Lagrangian gradient)
    at its last iterate."""

    states: np.ndarray
    inputs: np.ndarray
    collision_slacks: np.ndarray
    safety_slacks: np.ndarray
    objective: float
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    primal_infeasibility: float = float("nan")
    dual_infeasibility: float = float("nan")


def _ellipse_norm(px, py, other, semi_axes):
    dx, dy = px - other[0], py - other[1]
    cos_h, sin_h = ca.cos(other[2]), ca.sin(other[2])
    longitudinal = cos_h * dx + sin_h * dy
    lateral = -sin_h * dx + cos_h * dy
    return ca.sqrt((longitudinal / semi_axes[0]) ** 2 + (lateral / semi_axes[1]) ** 2)


def _discrete_bicycle(config: OcpConfig):
    """f(x, u): ``n_substeps`` explicit-Euler steps of the kinematic bicycle (``problem.vehicle_model``)."""
    bicycle = config.bicycle
    x = ca.SX.sym("x", 4)
    u = ca.SX.sym("u", 2)
    h, half_length = bicycle.substep_s, bicycle.length_m / 2.0
    state = x
    for _ in range(bicycle.n_substeps):
        v = state[3]
        beta = ca.atan(0.5 * ca.tan(u[0]))
        accel = ca.if_else(ca.logic_and(v > bicycle.max_speed_mps, u[1] > bicycle.max_speed_mps - v),
                           bicycle.max_speed_mps - v,
                           ca.if_else(ca.logic_and(v < bicycle.min_speed_mps, u[1] < bicycle.min_speed_mps - v),
                                      bicycle.min_speed_mps - v, u[1]))
        state = ca.vertcat(state[0] + h * v * ca.cos(state[2] + beta), state[1] + h * v * ca.sin(state[2] + beta),
                           state[2] + h * v * ca.sin(beta) / half_length, v + h * accel)
    return ca.Function("f", [x, u], [state])


def _cost_and_dynamics(config: OcpConfig, states, inputs, slacks, sigmas, measured, last_input, reference):
    """F (``sqp``'s module doc) and the equality constraints x_0 - x_hat, x_{k+1} - f(x_k, u_k) (4 (N + 1) rows)."""
    weights = config.weights
    f = _discrete_bicycle(config)
    q, r, s = (ca.DM(list(weights.state)), ca.DM(list(weights.input)), ca.DM(list(weights.input_rate)))
    cost = 0
    constraints = [states[:, 0] - measured]
    previous = last_input
    for k in range(config.horizon):
        cost += ca.dot(r, inputs[:, k] ** 2) + ca.dot(s, (inputs[:, k] - previous) ** 2)
        cost += ca.dot(q, (states[:, k + 1] - reference[:, k + 1]) ** 2)
        previous = inputs[:, k]
        constraints.append(states[:, k + 1] - f(states[:, k], inputs[:, k]))
    cost += weights.collision_slack_linear * ca.sum1(slacks) + weights.collision_slack_quadratic * ca.sumsqr(slacks)
    cost += weights.safety_slack_linear * ca.sum1(sigmas) + weights.safety_slack_quadratic * ca.sumsqr(sigmas)
    return cost, constraints


def _ellipse_constraints(config: OcpConfig, n_observed: int, states, slacks, sigmas, others) -> list:
    """Per stage k = 1..N, vehicle j and ego circle c: g_E + s_j and g_E' + sigma_kj (both >= 1; module doc)."""
    geometry, nv = config.geometry, n_observed
    constraints = []
    offsets = np.asarray(geometry.circle_offsets_m)
    for k in range(1, config.horizon + 1):
        px, py, psi = states[0, k], states[1, k], states[2, k]
        for j in range(nv):
            other = others[:, k * nv + j]
            sigma = sigmas[(k - 1) * nv + j]
            for d in offsets:
                cx, cy = px + float(d) * ca.cos(psi), py + float(d) * ca.sin(psi)
                constraints.append(_ellipse_norm(cx, cy, other, geometry.collision_semi_axes_m) + slacks[j])
                constraints.append(_ellipse_norm(cx, cy, other, geometry.safety_semi_axes_m) + sigma)
    return constraints


def _variable_bounds(config: OcpConfig, n_variables: int) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) of w = (vec x, vec u, s, sigma): y and v boxes on x_1..N, delta and a boxes on u, slacks >= 0."""
    horizon = config.horizon
    lower = np.full(n_variables, -np.inf)
    upper = np.full(n_variables, np.inf)
    state_lower = np.full((4, horizon + 1), -np.inf)
    state_upper = np.full((4, horizon + 1), np.inf)
    state_lower[1, 1:], state_upper[1, 1:] = config.lateral_bounds_m
    state_lower[3, 1:], state_upper[3, 1:] = config.speed_bounds_mps
    n_states = 4 * (horizon + 1)
    lower[:n_states], upper[:n_states] = state_lower.ravel(order="F"), state_upper.ravel(order="F")
    input_lower = np.tile([config.steering_bounds_rad[0], config.acceleration_bounds_mps2[0]], horizon)
    input_upper = np.tile([config.steering_bounds_rad[1], config.acceleration_bounds_mps2[1]], horizon)
    lower[n_states:n_states + 2 * horizon], upper[n_states:n_states + 2 * horizon] = input_lower, input_upper
    lower[n_states + 2 * horizon:] = 0.0
    return lower, upper


class IpoptOcp:
    """The NLP for V_obs observed vehicles as a CasADi ``nlpsol`` with IPOPT (module doc)."""

    def __init__(self, config: OcpConfig, n_observed: int, tolerance: float = IPOPT_TOLERANCE,
                 max_iterations: int = IPOPT_MAX_ITERATIONS) -> None:
        self.config = config
        self.n_observed = n_observed
        horizon, nv = config.horizon, n_observed
        states = ca.SX.sym("x", 4, horizon + 1)
        inputs = ca.SX.sym("u", 2, horizon)
        slacks = ca.SX.sym("s", nv)
        sigmas = ca.SX.sym("sigma", nv * horizon)
        measured = ca.SX.sym("x_hat", 4)
        last_input = ca.SX.sym("u_hat", 2)
        reference = ca.SX.sym("x_ref", 4, horizon + 1)
        others = ca.SX.sym("others", 4, (horizon + 1) * nv)
        cost, constraints = _cost_and_dynamics(config, states, inputs, slacks, sigmas, measured, last_input,
                                               reference)
        n_equalities = 4 * (horizon + 1)
        constraints += _ellipse_constraints(config, nv, states, slacks, sigmas, others)
        variables = ca.vertcat(ca.vec(states), ca.vec(inputs), slacks, sigmas)
        parameters = ca.vertcat(measured, last_input, ca.vec(reference), ca.vec(others))
        g = ca.vertcat(*constraints)
        self.n_variables = variables.numel()
        self.evaluate = ca.Function("objective_and_constraints", [variables, parameters], [cost, g])
        """(w, p) -> (F, g): the NLP's functions, for checks."""
        self._lbg = np.concatenate([np.zeros(n_equalities), np.ones(g.numel() - n_equalities)])
        self._ubg = np.concatenate([np.zeros(n_equalities), np.full(g.numel() - n_equalities, np.inf)])
        self._lbx, self._ubx = _variable_bounds(config, self.n_variables)
        self._n_states = 4 * (horizon + 1)
        options = {"ipopt.tol": tolerance, "ipopt.max_iter": max_iterations, "ipopt.print_level": 0,
                   "print_time": False, "ipopt.sb": "yes"}
        nlp = {"x": variables, "p": parameters, "f": cost, "g": g}
        self.solver = ca.nlpsol("srmpc_nmpc", "ipopt", nlp, options)
        self.warm_solver = ca.nlpsol("srmpc_nmpc_warm", "ipopt", nlp, {**options, **WARM_START_OPTIONS})

    def solve(self, measured_state, last_input, predicted_others, tracking_reference, initial_states, initial_inputs,
              initial_slacks, initial_sigmas, warm: bool = False) -> IpoptResult:
        """Solve from the given primal guess (multipliers start at IPOPT's defaults); ``warm``: with
        ``WARM_START_OPTIONS`` (the guess is kept almost exactly as IPOPT's starting point)."""
        horizon, nv = self.config.horizon, self.n_observed
        others = np.asarray(predicted_others, dtype=np.float64).reshape(horizon + 1, nv, 4)
        parameters = np.concatenate([measured_state, last_input, np.asarray(tracking_reference).ravel(),
                                     others.ravel()])
        guess = np.concatenate([np.asarray(initial_states).ravel(), np.asarray(initial_inputs).ravel(),
                                np.asarray(initial_slacks).ravel(), np.asarray(initial_sigmas).ravel()])
        self.last_parameters, self.last_guess = parameters, guess
        start = time.perf_counter()
        solver = self.warm_solver if warm else self.solver
        out = solver(x0=guess, p=parameters, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg)
        elapsed = time.perf_counter() - start
        stats = solver.stats()
        w = np.asarray(out["x"]).ravel()
        n_states = self._n_states
        log = stats.get("iterations") or {}
        return IpoptResult(
            states=w[:n_states].reshape(horizon + 1, 4),
            inputs=w[n_states:n_states + 2 * horizon].reshape(horizon, 2),
            collision_slacks=w[n_states + 2 * horizon:n_states + 2 * horizon + nv],
            safety_slacks=w[n_states + 2 * horizon + nv:].reshape(horizon, nv),
            objective=float(out["f"]), status=str(stats["return_status"]), success=bool(stats["success"]),
            iterations=int(stats["iter_count"]), solve_time_s=elapsed,
            primal_infeasibility=float(log["inf_pr"][-1]) if log.get("inf_pr") else float("nan"),
            dual_infeasibility=float(log["inf_du"][-1]) if log.get("inf_du") else float("nan"))


class IpoptReference:
    """``IpoptOcp`` per number of observed vehicles, built on first use."""

    def __init__(self, config: OcpConfig | None = None, tolerance: float = IPOPT_TOLERANCE) -> None:
        self.config = config or OcpConfig()
        self.tolerance = tolerance
        self._problems: dict[int, IpoptOcp] = {}

    def problem(self, n_observed: int) -> IpoptOcp:
        if n_observed not in self._problems:
            self._problems[n_observed] = IpoptOcp(self.config, n_observed, self.tolerance)
        return self._problems[n_observed]

    def solve(self, measured_state, last_input, predicted_others, tracking_reference, initial_states, initial_inputs,
              initial_slacks, initial_sigmas, warm: bool = False) -> IpoptResult:
        n_observed = np.asarray(predicted_others).shape[1]
        return self.problem(n_observed).solve(measured_state, last_input, predicted_others, tracking_reference,
                                              initial_states, initial_inputs, initial_slacks, initial_sigmas, warm)

