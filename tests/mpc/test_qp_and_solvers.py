"""The QP's fixed pattern, its constraints at the solution, and solver agreement."""

import numpy as np
import pytest

from srmpc.mpc.problem import (
    LtvMpcQp,
    OcpConfig,
    OcpStepData,
    collision_norms,
    lane_keeping_tracking_reference,
    predict_constant_velocity,
)
from srmpc.mpc.solvers import SOLVER_FACTORIES, available_solvers, make_solver


def test_pattern_is_fixed_with_explicit_zeros(six_vehicles):
    config = OcpConfig()
    qp = LtvMpcQp(config)
    horizon = config.horizon
    patterns = []
    for n_vehicles in (6, 0, 3):  # empty slots write explicit zeros into the pattern
        ego = np.array([0.0, 8.0, 0.0, 25.0])
        inputs = np.zeros((horizon, 2))
        qp.update(OcpStepData(ego, qp.model.rollout(ego, inputs), inputs,
                              lane_keeping_tracking_reference(horizon), np.zeros(2),
                              predict_constant_velocity(six_vehicles[:n_vehicles], horizon, 0.2)))
        patterns.append([(m.indptr.copy(), m.indices.copy()) for m in (
            qp.equality_matrix, qp.inequality_matrix, qp.general_matrix)])
    for other in patterns[1:]:
        for (indptr_a, indices_a), (indptr_b, indices_b) in zip(patterns[0], other,
                                                                strict=True):
            np.testing.assert_array_equal(indptr_a, indptr_b)
            np.testing.assert_array_equal(indices_a, indices_b)
    assert np.sum(qp.inequality_matrix.data == 0.0) > 0  # zeros kept, not dropped


def test_general_form_equals_split_form(loaded_qp):
    qp = loaded_qp
    general = qp.general_matrix.toarray()
    n_eq, n_in = qp.n_equalities, qp.n_inequalities
    np.testing.assert_array_equal(general[:n_eq], qp.equality_matrix.toarray())
    np.testing.assert_array_equal(general[n_eq:n_eq + n_in], qp.inequality_matrix.toarray())
    np.testing.assert_array_equal(qp.general_lower[:n_eq], qp.equality_rhs)
    np.testing.assert_array_equal(qp.general_lower[n_eq:n_eq + n_in], qp.inequality_lower)
    box = general[n_eq + n_in:]
    np.testing.assert_array_equal(box @ qp.variable_lower.clip(-1e300, 1e300),
                                  qp.general_lower[n_eq + n_in:])


def test_unknown_solver_name_lists_available():
    with pytest.raises(ValueError, match="available: .*piqp_native.*clarabel"):
        make_solver("gurobi")
    assert set(available_solvers()) == set(SOLVER_FACTORIES)




def test_all_solvers_agree_on_first_input(loaded_qp):
    qp = loaded_qp
    reference = make_solver("clarabel").solve(qp)
    assert reference.solved
    u0_reference = qp.split_solution(reference.z)[1][0]
    for name in ("osqp", "piqp", "proxqp", "piqp_native", "osqp_native", "riccati_ipm", "riccati_ipm_cold"):
        solution = make_solver(name).solve(qp)
        assert solution.solved, name
        u0 = qp.split_solution(solution.z)[1][0]
        assert np.max(np.abs(u0 - u0_reference)) < 1e-3, name


@pytest.mark.parametrize("name", ["riccati_ipm", "piqp_native", "clarabel", "osqp_native"])
def test_constraints_hold_at_solution(loaded_qp, six_vehicles, name):
    qp = loaded_qp
    solution = make_solver(name).solve(qp)
    assert solution.solved
    tolerance = 1e-4 if name.startswith("osqp") else 1e-7
    violation = qp.constraint_violation(solution.z)
    assert violation["equality"] < tolerance
    assert violation["inequality"] < tolerance
    assert violation["box"] < tolerance
    states, inputs, collision_slacks, _ = qp.split_solution(solution.z)
    config = qp.config
    assert np.all(inputs[:, 0] <= config.steering_bounds_rad[1] + tolerance)
    assert np.all(np.abs(inputs[:, 1]) <= config.acceleration_bounds_mps2[1] + tolerance)
    assert np.all(states[1:, 1] >= config.lateral_bounds_m[0] - tolerance)
    assert np.all(states[1:, 1] <= config.lateral_bounds_m[1] + tolerance)
    # with no slack used, the linearized half-planes imply the true ellipse constraint for the
    # QP's own states
    assert np.max(collision_slacks) < 1e-4
    predicted = predict_constant_velocity(six_vehicles, config.horizon, 0.2)
    geometry = config.geometry
    norms = collision_norms(states, predicted, geometry.circle_offsets_m,
                            geometry.collision_semi_axes_m)
    assert norms[1:].min() >= 1.0 - 1e-4


def test_linearized_row_is_tangent_half_plane():
    """The half-plane row touches the ellipse's level set at the reference point."""
    config = OcpConfig(horizon=2, max_vehicles=1)
    qp = LtvMpcQp(config)
    ego = np.array([0.0, 8.0, 0.0, 20.0])
    other = np.array([[12.0, 8.0, 0.0, 20.0]])
    inputs = np.zeros((2, 2))
    states = qp.model.rollout(ego, inputs)
    qp.update(OcpStepData(ego, states, inputs, lane_keeping_tracking_reference(2), np.zeros(2),
                          predict_constant_velocity(other, 2, 0.2)))
    row = qp.inequality_matrix.toarray()[0]
    x1 = qp.layout.state_start[1]
    # straight behind: normal points backwards, only x and psi... psi term is zero at psi = 0
    assert row[x1] < 0 and abs(row[x1 + 1]) < 1e-12 and abs(row[x1 + 2]) < 1e-12
    a, _ = config.geometry.collision_semi_axes_m
    a_safe, _ = config.geometry.safety_semi_axes_m
    # front circle centre (x + 1.25) stays a' behind the other (at 12 + 20 * 0.2 m at stage 1)
    # without slack; sigma up to a'/a - 1 moves the boundary to a behind it
    boundary_x = qp.inequality_lower[0] / row[x1]
    np.testing.assert_allclose(boundary_x + 1.25, 16.0 - a_safe, atol=1e-9)
    np.testing.assert_allclose(qp.variable_upper[qp.layout.safety_slack_indices()[0, 0]],
                               a_safe / a - 1.0, atol=1e-9)


def test_step_data_names_the_field_of_a_wrong_shape():
    horizon = 3
    fields = dict(measured_state=np.zeros(4), linearization_states=np.zeros((horizon + 1, 4)),
                  linearization_inputs=np.zeros((horizon, 2)), tracking_reference=np.zeros((horizon + 1, 4)),
                  last_input=np.zeros(2), predicted_others=np.zeros((horizon + 1, 2, 4)))
    step = OcpStepData(**fields)
    assert (step.horizon, step.n_observed) == (horizon, 2)
    for name, wrong in (("measured_state", np.zeros(3)), ("linearization_states", np.zeros((horizon, 4))),
                        ("linearization_inputs", np.zeros(horizon)), ("tracking_reference", np.zeros((horizon, 4))),
                        ("last_input", np.zeros(4)), ("predicted_others", np.zeros((horizon, 2, 4)))):
        with pytest.raises(ValueError, match=f"OcpStepData.{name} must have shape"):
            OcpStepData(**{**fields, name: wrong})
    with pytest.raises(ValueError, match="horizon 3 is not the QP's N=25"):
        LtvMpcQp(OcpConfig()).update(step)
