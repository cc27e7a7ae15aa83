"""The NMPC (SQP on the exact OCP) against its own definitions and against CasADi + IPOPT.

The committed states (``tests/data/nmpc_states.npz``) are 5 closed-loop planner inputs recorded by
``benchmarks/nmpc_initial_guess.py`` (light: 3 observed vehicles; dense: 6, two of them with the
safety region entered), with the SRMPC policy's rollout and the constant-velocity guess.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from srmpc.mpc.nmpc import NlpPoint, NmpcSettings, NmpcSolver
from srmpc.mpc.nmpc.nonlinear_constraints import linearize_ellipse_rows, min_ellipse_norms, vehicle_frames
from srmpc.mpc.nmpc.sqp_kernels import next_state, pairwise_sum
from srmpc.mpc.problem import OcpConfig, OcpStepData, collision_norms, nonlinear_plan_cost
from srmpc.mpc.solvers import (
    RiccatiInteriorPointSolver,
    allocate_compact,
    allocate_memory,
    allocate_workspace,
    solve_compact,
)

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


def stored_step(states, i, guess):
    """Stored state i with ``guess``'s initial trajectory as the step's data."""
    ego, last_input, others, tracking = planner_inputs(states, i)
    return OcpStepData(ego, states[f"{guess}_states"][i], states[f"{guess}_inputs"][i], tracking, last_input, others)


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
    frames = np.empty(others.shape)
    vehicle_frames(others, 2, frames)
    coefficients, lower, norms = np.empty((horizon, 2, 3)), np.empty((horizon, 2)), np.empty((horizon, 2))
    linearize_ellipse_rows(states, frames, 2, offsets, axes, coefficients, lower, norms)
    step = 1e-6
    for coordinate in range(3):
        plus, minus = states.copy(), states.copy()
        plus[:, coordinate] += step
        minus[:, coordinate] -= step
        norm_plus, norm_minus = np.empty((horizon, 2)), np.empty((horizon, 2))
        min_ellipse_norms(plus, frames, 2, offsets, axes, norm_plus)
        min_ellipse_norms(minus, frames, 2, offsets, axes, norm_minus)
        # central differences of a smooth function: error O(step^2) ~ 1e-10 plus round-off ~1e-10
        np.testing.assert_allclose(coefficients[..., coordinate], (norm_plus - norm_minus) / (2 * step), atol=1e-7)
    np.testing.assert_allclose(lower, 1.0 - norms + np.einsum("kjc,kc->kj", coefficients, states[1:, :3]),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("guess", ["rollout", "cv"])
def test_converged_plan_is_feasible_and_costs_the_nonlinear_plan_cost(states, solver, guess):
    """At convergence the plan satisfies the NLP's constraints and F = ``nonlinear_plan_cost`` of its inputs."""
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        result = solver.solve(stored_step(states, i, guess))
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
    result = limited.solve(OcpStepData(ego, states["cv_states"][2], states["cv_inputs"][2], tracking, last_input,
                                       others))
    assert result.status == "max_iterations" and result.iterations == 1 and not result.converged


def test_nmpc_agrees_with_ipopt_from_the_same_guess(states, solver):
    """CasADi + IPOPT (exact Hessian, independent model code) reaches the same plan from the policy's rollout,
    and started at the NMPC's plan it stays there (the NMPC's plan is a KKT point of IPOPT's NLP)."""
    casadi_reference = pytest.importorskip(
        "srmpc.mpc.nmpc.casadi_reference", reason="CasADi is not installed (pip install -e '.[nmpc]')")
    reference = casadi_reference.IpoptReference(solver.config)
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        n = others.shape[1]
        step = OcpStepData(ego, states["rollout_states"][i], states["rollout_inputs"][i], tracking, last_input, others)
        result = solver.solve(step)
        start = solver.initial_point(step)
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


@pytest.mark.parametrize("guess", ["rollout", "cv"])
def test_warm_started_subproblems_converge_as_the_cold(states, guess):
    """QPs after the first warm-started (``qp_warm_start``, the default) converge to the same tolerance as
    cold-started ones, to the same plan, in fewer interior-point iterations after the first QP (which starts cold either
    way)."""
    solver = NmpcSolver(OcpConfig())
    assert solver.settings.qp_warm_start
    cold = NmpcSolver(OcpConfig(), NmpcSettings(qp_warm_start=False))
    warm_later, cold_later = 0, 0
    for i in range(states["ego"].shape[0]):
        step = stored_step(states, i, guess)
        warm_result, cold_result = solver.solve(step), cold.solve(step)
        assert warm_result.converged and cold_result.converged, (i, warm_result.status, cold_result.status)
        for result in (warm_result, cold_result):
            assert result.primal_infeasibility <= solver.settings.primal_tolerance
            assert result.step_norms[-1] <= solver.settings.stationarity_tolerance
        assert warm_result.qp_iterations[0] == cold_result.qp_iterations[0], i  # the first QP is cold in both
        np.testing.assert_allclose(warm_result.inputs[0], cold_result.inputs[0], atol=FIRST_INPUT_TOLERANCE)
        np.testing.assert_allclose(warm_result.states, cold_result.states, atol=TRAJECTORY_TOLERANCE)
        warm_later += sum(warm_result.qp_iterations[1:])
        cold_later += sum(cold_result.qp_iterations[1:])
    assert warm_later < 0.8 * cold_later, (warm_later, cold_later)


@pytest.mark.parametrize(("field", "value", "message"), [
    ("qp_warm_start", "yes", "qp_warm_start='yes': must be true or false"),
    ("qp_warm_start_iterations", 0, "qp_warm_start_iterations=0: must be an integer in [1, 50]"),
])
def test_bad_warm_start_setting_is_one_line(field, value, message):
    with pytest.raises(ValueError) as raised:
        NmpcSettings(**{field: value})
    assert str(raised.value) == message


@pytest.mark.parametrize("guess", ["rollout", "cv"])
def test_stall_test_converges_as_without(states, guess):
    """With the stall test on (``stall_iterations``), every stored state converges to the same tolerance, through the
    same iterates, to the same plan as without it (it ends only solves that are not converging)."""
    with_test = NmpcSolver(OcpConfig())
    assert with_test.settings.stall_iterations == 3
    without = NmpcSolver(OcpConfig(), NmpcSettings(stall_iterations=0))
    for i in range(states["ego"].shape[0]):
        step = stored_step(states, i, guess)
        result, reference = with_test.solve(step), without.solve(step)
        assert result.converged and reference.converged, (i, result.status, reference.status)
        assert result.primal_infeasibility <= with_test.settings.primal_tolerance
        assert result.step_norms[-1] <= with_test.settings.stationarity_tolerance
        assert (result.iterations, result.step_lengths) == (reference.iterations, reference.step_lengths), i
        np.testing.assert_array_equal(result.states, reference.states)
        np.testing.assert_array_equal(result.inputs, reference.inputs)


def test_stall_test_stops_a_crawling_solve(states):
    """An over-strict Armijo fraction (0.99) makes the SQP crawl with accepted steps alpha <= 1/16 to
    ``max_iterations``, as the benchmark's unconverged solves do; with K = 3 the solve stops after 3 such steps,
    status ``stalled``, through the same iterates."""
    crawling = NmpcSettings(armijo=0.99, max_iterations=8, stall_iterations=0)
    without = NmpcSolver(OcpConfig(), crawling)
    stalling = NmpcSolver(OcpConfig(), dataclasses.replace(crawling, stall_iterations=3))
    for i in (0, 2):
        ego, last_input, others, tracking = planner_inputs(states, i)
        step = OcpStepData(ego, states["cv_states"][i], states["cv_inputs"][i], tracking, last_input, others)
        reference, result = without.solve(step), stalling.solve(step)
        assert reference.status == "max_iterations" and max(reference.step_lengths) <= 1 / 16, reference.step_lengths
        assert result.status == "stalled" and not result.converged and result.iterations == 3
        assert result.step_lengths == reference.step_lengths[:3] and result.step_norms == reference.step_norms[:3]


@pytest.mark.parametrize(("field", "value", "message"), [
    ("stall_iterations", -1, "stall_iterations=-1: must be an integer >= 0"),
    ("stall_step_length", 1.0, "stall_step_length=1.0: must be a finite number in (0, 1)"),
])
def test_bad_stall_setting_is_one_line(field, value, message):
    with pytest.raises(ValueError) as raised:
        NmpcSettings(**{field: value})
    assert str(raised.value) == message


def test_anderson_acceleration_reaches_the_plain_sqp_plan(states, solver):
    """The accelerated iteration (default) converges to the same plan as the plain Gauss-Newton SQP."""
    plain = NmpcSolver(OcpConfig(), NmpcSettings(anderson_depth=0))
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        guess = states["cv_states"][i], states["cv_inputs"][i]
        accelerated = solver.solve(OcpStepData(ego, *guess, tracking, last_input, others))
        reference = plain.solve(OcpStepData(ego, *guess, tracking, last_input, others))
        assert accelerated.converged and reference.converged and reference.accelerated_steps == 0
        # both stop within ||p||_inf <= 1e-4 of the same KKT point; measured: states 2.0e-4, first input 7.1e-5
        np.testing.assert_allclose(accelerated.states, reference.states, atol=1e-3)
        np.testing.assert_allclose(accelerated.inputs[0], reference.inputs[0], atol=1e-4)


def numpy_objective(solver, point, tracking_reference, last_input) -> float:
    """F(w) written with numpy arrays (the module doc's formula, as the numpy SQP of earlier revisions)."""
    weights = solver.config.weights
    q, r, s = np.asarray(weights.state), np.asarray(weights.input), np.asarray(weights.input_rate)
    error = point.states[1:] - tracking_reference[1:]
    rates = np.diff(np.vstack([last_input[None, :], point.inputs]), axis=0)
    slacks, sigmas = point.slacks, point.sigmas
    return float(np.sum(q * error**2) + np.sum(r * point.inputs**2) + np.sum(s * rates**2)
                 + weights.collision_slack_linear * slacks.sum() + weights.collision_slack_quadratic * np.sum(slacks**2)
                 + weights.safety_slack_linear * sigmas.sum() + weights.safety_slack_quadratic * np.sum(sigmas**2))


def numpy_infeasibility(solver, point, measured_state, others) -> tuple[float, float]:
    """(theta_1, theta_inf) with numpy: defects through ``KinematicBicycle.linearize``, the ellipse norms through
    ``collision.collision_norms`` (the norms of every circle, then the minimum)."""
    config, geometry, n_obs = solver.config, solver.config.geometry, others.shape[1]
    lower = np.array([-np.inf, config.lateral_bounds_m[0], -np.inf, config.speed_bounds_mps[0]])
    upper = np.array([np.inf, config.lateral_bounds_m[1], np.inf, config.speed_bounds_mps[1]])
    input_lower = np.array([config.steering_bounds_rad[0], config.acceleration_bounds_mps2[0]])
    input_upper = np.array([config.steering_bounds_rad[1], config.acceleration_bounds_mps2[1]])
    next_states = solver.model.linearize(point.states, point.inputs)[0]
    parts = [np.abs(point.states[1:] - next_states).ravel(), np.abs(point.states[0] - measured_state),
             np.maximum(lower - point.states[1:], 0.0).ravel(), np.maximum(point.states[1:] - upper, 0.0).ravel(),
             np.maximum(input_lower - point.inputs, 0.0).ravel(), np.maximum(point.inputs - input_upper, 0.0).ravel()]
    if n_obs:
        offsets = geometry.circle_offsets_m
        collision = collision_norms(point.states[1:], others[1:], offsets, geometry.collision_semi_axes_m).min(axis=2)
        safety = collision_norms(point.states[1:], others[1:], offsets, geometry.safety_semi_axes_m).min(axis=2)
        parts.append(np.maximum(1.0 - collision - point.slacks[None, :n_obs], 0.0).ravel())
        parts.append(np.maximum(1.0 - safety - point.sigmas - point.slacks[None, n_obs:], 0.0).ravel())
        parts.append(np.maximum(-point.slacks, 0.0))
        parts.append(np.maximum(-point.sigmas, 0.0).ravel())
    violations = np.concatenate(parts)
    return float(violations.sum()), float(violations.max(initial=0.0))


def random_point(rng, states, i, guess):
    """A point near recorded guess i, with boxes, dynamics and slack signs violated."""
    n, horizon = int(states["n_observed"][i]), states[f"{guess}_inputs"].shape[1]
    return NlpPoint(states[f"{guess}_states"][i] + rng.normal(0.0, [1.0, 0.5, 0.05, 1.0], (horizon + 1, 4)),
                    rng.uniform([-0.2, -8.0], [0.2, 8.0], (horizon, 2)), rng.uniform(-0.2, 1.0, 2 * n),
                    rng.uniform(-0.2, 1.0, (horizon, n)))


@pytest.mark.parametrize("guess", ["rollout", "cv"])
def test_compiled_nlp_functions_equal_the_numpy_formulas(states, solver, guess):
    """F, theta_1 and theta_inf of the compiled kernels (``NmpcSolver.evaluate``, as the SQP evaluates them) equal
    the numpy formulas on random points, and the initial point equals its numpy definition."""
    rng = np.random.default_rng(7)
    config = solver.config
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        for _ in range(20):
            point = random_point(rng, states, i, guess)
            value, theta_1, theta_inf = solver.evaluate(point, OcpStepData(
                ego, states[f"{guess}_states"][i], states[f"{guess}_inputs"][i], tracking, last_input, others))
            # measured: equal bit for bit (numpy's pairwise summation order, the same floating-point operations)
            assert value == pytest.approx(numpy_objective(solver, point, tracking, last_input), rel=1e-13)
            reference_1, reference_inf = numpy_infeasibility(solver, point, ego, others)
            assert theta_1 == pytest.approx(reference_1, rel=1e-13, abs=1e-15)
            assert theta_inf == pytest.approx(reference_inf, rel=1e-13, abs=1e-15)
        guess_states, guess_inputs = random_point(rng, states, i, guess).states, states[f"{guess}_inputs"][i]
        start = solver.initial_point(OcpStepData(ego, guess_states, guess_inputs, tracking, last_input, others))
        lower = [-np.inf, config.lateral_bounds_m[0], -np.inf, config.speed_bounds_mps[0]]
        upper = [np.inf, config.lateral_bounds_m[1], np.inf, config.speed_bounds_mps[1]]
        np.testing.assert_array_equal(start.states[1:], np.clip(guess_states[1:], lower, upper))
        np.testing.assert_array_equal(start.states[0], ego)
        np.testing.assert_array_equal(start.inputs, np.clip(guess_inputs, *np.transpose(
            [config.steering_bounds_rad, config.acceleration_bounds_mps2])))
        n, geometry = others.shape[1], config.geometry
        if n:
            norms = [collision_norms(start.states[1:], others[1:], geometry.circle_offsets_m, axes).min(axis=2)
                     for axes in (geometry.collision_semi_axes_m, geometry.safety_semi_axes_m)]
            np.testing.assert_allclose(start.slacks[:n], np.maximum(1.0 - norms[0], 0.0).max(axis=0), atol=1e-15)
            np.testing.assert_allclose(start.sigmas, np.maximum(1.0 - norms[1], 0.0), atol=1e-15)
        np.testing.assert_array_equal(start.slacks[n:], 0.0)


def test_pairwise_sum_is_numpys_sum():
    """The kernels' sums are numpy's ``np.sum`` bit for bit (its pairwise order), up to lengths well past the
    longest sum of the default OCP (~900 terms) and at any offset."""
    rng = np.random.default_rng(11)
    for length in [*range(0, 300), *rng.integers(300, 5000, 50)]:
        offset = int(rng.integers(0, 4))
        values = rng.normal(0.0, 1.0, offset + length) * 10.0 ** rng.uniform(-6, 6, offset + length)
        assert pairwise_sum(values, offset, length) == np.sum(values[offset:]), length


def test_next_state_is_the_model_step_bit_for_bit(solver):
    """The kernels' f(x, u) (trigonometry of the input hoisted out of the sub-steps) is ``KinematicBicycle.step``
    bit for bit, in both speed-clipping branches too."""
    rng = np.random.default_rng(5)
    model = solver.model
    bicycle = model.parameters
    for _ in range(2000):
        state = np.array([rng.uniform(0, 500), rng.uniform(-2, 14), rng.uniform(-0.5, 0.5),
                          rng.uniform(1.2 * bicycle.min_speed_mps, 1.2 * bicycle.max_speed_mps)])
        control = rng.uniform([-0.3, -8.0], [0.3, 8.0])
        following = np.empty(4)
        next_state(state, control, tuple(model.kernel_args), following)
        np.testing.assert_array_equal(following, model.step(state, control))


@pytest.mark.parametrize("warm", [True, False])
def test_compact_subproblem_is_the_full_qp_bit_for_bit(states, warm):
    """The SQP solves each QP on max(rows, 1) slots (``solve_compact``); the same QP on all 2V slots through
    ``RiccatiInteriorPointSolver.solve`` gives the same iterations, solution and warm-start memory, bit for bit."""
    solver = NmpcSolver(OcpConfig())
    horizon = solver.config.horizon
    for i in range(states["ego"].shape[0]):
        ego, last_input, others, tracking = planner_inputs(states, i)
        solver.solve(OcpStepData(ego, states["cv_states"][i], states["cv_inputs"][i], tracking, last_input, others))
        qp, rows = solver.qp, solver.qp.n_observed  # the last subproblem; the memory holds its solution
        # both sides start warm (from the copied memory, with the subproblems' unshifted warm start) or both cold
        full = RiccatiInteriorPointSolver(tolerance=solver.settings.qp_tolerance, warm_start=warm,
                                          warm_start_settings=solver.qp_solver.warm_start_settings)
        full.bind(qp)
        compact_memory = allocate_memory(horizon, 2 * solver.config.max_vehicles, solver.qp_solver.memory.z.size)
        for target in (full.memory, compact_memory):
            for mine, theirs in zip(target, solver.qp_solver.memory, strict=True):
                mine[...] = theirs
            target.valid[0] = warm
        expected = full.solve(qp)
        status, iterations, solution = solve_compact(
            solver._subproblem, rows, qp.measured_state, solver._qp_settings._replace(warm_start=warm),
            allocate_workspace(horizon, 2 * solver.config.max_vehicles), compact_memory,
            allocate_compact(horizon, 2 * solver.config.max_vehicles))
        assert expected.solved and status == 0 and iterations == expected.iterations, i
        assert full.last_started_warm == warm, i
        full_states, full_inputs, full_slacks, full_sigmas = qp.split_solution(expected.z)
        np.testing.assert_array_equal(solution.states, full_states)
        np.testing.assert_array_equal(solution.inputs, full_inputs)
        np.testing.assert_array_equal(solution.slacks[:rows], full_slacks[:rows])
        np.testing.assert_array_equal(solution.sigmas[:, :rows], full_sigmas[:, :rows])
        for mine, theirs in zip(compact_memory, full.memory, strict=True):
            np.testing.assert_array_equal(mine, theirs)
