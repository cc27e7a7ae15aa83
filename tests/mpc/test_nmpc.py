"""The NMPC (SQP on the exact OCP) against its own definitions and against CasADi + IPOPT.

The committed states (``tests/data/nmpc_states.npz``) are 5 closed-loop planner inputs recorded by
``benchmarks/nmpc_initial_guess.py`` (light: 3 observed vehicles; dense: 6, two of them with the
safety region entered), with the SRMPC policy's rollout and the constant-velocity guess.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from srmpc.mpc.nmpc import NmpcSettings, NmpcSolver
from srmpc.mpc.nonlinear_constraints import linearize_ellipse_rows, min_ellipse_norms
from srmpc.mpc.nonlinear_cost import nonlinear_plan_cost
from srmpc.mpc.ocp import OcpConfig

STATES = Path(__file__).parent.parent / "data" / "nmpc_states.npz"

OBJECTIVE_TOLERANCE = 1e-3
"""|F - F_ipopt| / max(1, |F|); largest measured 2.4e-4 (IPOPT's slacks at ~1e-8, not 0, cost w_col,1 = 1e4)."""
FIRST_INPUT_TOLERANCE = 1e-3
"""max |u_0 - u_0'| [rad, m/s^2]; largest measured 7.8e-5 (the SQP stops at ||p||_inf <= 1e-4)."""
TRAJECTORY_TOLERANCE = 1e-2
"""max |x_k - x_k'| [m, rad, m/s]; largest measured 2.2e-4."""
KKT_DRIFT_TOLERANCE = 1e-3
"""IPOPT started at the NMPC's plan moves it at most this far [m, rad, m/s]; largest measured 8e-5."""


@pytest.fixture(scope="module")
def states() -> dict[str, np.ndarray]:
    with np.load(STATES) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def solver() -> NmpcSolver:
    return NmpcSolver(OcpConfig())


def planner_inputs(states, i):
    n = int(states["n_observed"][i])
    return states["ego"][i], states["last_input"][i], states["others"][i][:, :n], states["tracking"][i]


def test_ellipse_rows_are_the_gradient_of_the_exact_norm():
    """Row coefficients = d/d(x, y, psi) of min_c g (central differences), row lower = 1 - g + n^T x^r."""
    rng = np.random.default_rng(3)
    config = OcpConfig()
    offsets = np.asarray(config.geometry.circle_offsets_m)
    axes = np.asarray(config.geometry.safety_semi_axes_m)
    horizon = 5
    states = np.column_stack([rng.uniform(0, 30, horizon + 1), rng.uniform(0, 8, horizon + 1),
                              rng.uniform(-0.2, 0.2, horizon + 1), rng.uniform(15, 25, horizon + 1)])
    others = np.stack([rng.uniform(0, 30, (horizon + 1, 2)), rng.uniform(0, 8, (horizon + 1, 2)),
                       rng.uniform(-0.1, 0.1, (horizon + 1, 2)), rng.uniform(15, 25, (horizon + 1, 2))], axis=-1)
    coefficients, lower, norms = np.empty((horizon, 2, 3)), np.empty((horizon, 2)), np.empty((horizon, 2))
    linearize_ellipse_rows(states, others, 2, offsets, axes, coefficients, lower, norms)
    step = 1e-6
    for coordinate in range(3):
        plus, minus = states.copy(), states.copy()
        plus[:, coordinate] += step
        minus[:, coordinate] -= step
        norm_plus, norm_minus = np.empty((horizon, 2)), np.empty((horizon, 2))
        min_ellipse_norms(plus, others, 2, offsets, axes, norm_plus)
        min_ellipse_norms(minus, others, 2, offsets, axes, norm_minus)
        # central differences of a smooth function: error O(step^2) ~ 1e-10 plus round-off ~1e-10
        np.testing.assert_allclose(coefficients[..., coordinate], (norm_plus - norm_minus) / (2 * step), atol=1e-7)
    np.testing.assert_allclose(lower, 1.0 - norms + np.einsum("kjc,kc->kj", coefficients, states[1:, :3]),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("guess", ["rollout", "cv"])
def test_converged_plan_is_feasible_and_costs_the_nonlinear_plan_cost(states, solver, guess):
    """At convergence the plan satisfies the NLP's constraints and F = ``nonlinear_plan_cost`` of its inputs."""
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        result = solver.solve(ego, last_input, others, tracking, states[f"{guess}_states"][i],
                              states[f"{guess}_inputs"][i])
        assert result.converged, (i, result.status)
        assert result.primal_infeasibility <= solver.settings.primal_tolerance
        assert result.step_norms[-1] <= solver.settings.stationarity_tolerance
        assert result.iterations == len(result.qp_times_s) <= solver.settings.max_iterations
        np.testing.assert_allclose(result.states, solver.model.rollout(ego, result.inputs), atol=1e-5)
        exact = nonlinear_plan_cost(solver.config, solver.model, ego, result.inputs, tracking, last_input, others)
        # the plan's slacks equal the exact violations up to the primal tolerance 1e-6 (x 1e4 weight); measured 4e-9
        assert result.objective == pytest.approx(exact, rel=1e-6, abs=1e-4)


def test_iteration_limit_is_a_status_not_an_error(states):
    ego, last_input, others, tracking = planner_inputs(states, 2)
    limited = NmpcSolver(OcpConfig(), NmpcSettings(max_iterations=1))
    result = limited.solve(ego, last_input, others, tracking, states["cv_states"][2], states["cv_inputs"][2])
    assert result.status == "max_iterations" and result.iterations == 1 and not result.converged


def test_nmpc_agrees_with_ipopt_from_the_same_guess(states, solver):
    """CasADi + IPOPT (exact Hessian, independent model code) reaches the same plan from the policy's rollout,
    and started at the NMPC's plan it stays there (the NMPC's plan is a KKT point of IPOPT's NLP)."""
    casadi_reference = pytest.importorskip(
        "srmpc.mpc.casadi_reference", reason="CasADi is not installed (pip install -e '.[nmpc]')")
    reference = casadi_reference.IpoptReference(solver.config)
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        n = others.shape[1]
        result = solver.solve(ego, last_input, others, tracking, states["rollout_states"][i],
                              states["rollout_inputs"][i])
        start = solver.initial_point(ego, others, states["rollout_states"][i], states["rollout_inputs"][i])
        ipopt = reference.solve(ego, last_input, others, tracking, start.states, start.inputs, start.slacks[:n],
                                start.sigmas)
        assert result.converged and ipopt.success, (i, result.status, ipopt.status)
        assert abs(result.objective - ipopt.objective) <= OBJECTIVE_TOLERANCE * max(1.0, abs(ipopt.objective))
        np.testing.assert_allclose(result.inputs[0], ipopt.inputs[0], atol=FIRST_INPUT_TOLERANCE)
        np.testing.assert_allclose(result.states, ipopt.states, atol=TRAJECTORY_TOLERANCE)
        warm = reference.solve(ego, last_input, others, tracking, result.states, result.inputs,
                               result.collision_slacks, result.safety_slacks, warm=True)
        assert warm.success
        np.testing.assert_allclose(warm.states, result.states, atol=KKT_DRIFT_TOLERANCE)


def test_anderson_acceleration_reaches_the_plain_sqp_plan(states, solver):
    """The accelerated iteration (default) converges to the same plan as the plain Gauss-Newton SQP."""
    plain = NmpcSolver(OcpConfig(), NmpcSettings(anderson_depth=0))
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        guess = states["cv_states"][i], states["cv_inputs"][i]
        accelerated = solver.solve(ego, last_input, others, tracking, *guess)
        reference = plain.solve(ego, last_input, others, tracking, *guess)
        assert accelerated.converged and reference.converged and reference.accelerated_steps == 0
        # both stop within ||p||_inf <= 1e-4 of the same KKT point; measured: states 2.0e-4, first input 7.1e-5
        np.testing.assert_allclose(accelerated.states, reference.states, atol=1e-3)
        np.testing.assert_allclose(accelerated.inputs[0], reference.inputs[0], atol=1e-4)
