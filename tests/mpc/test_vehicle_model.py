"""The prediction model is exactly the plant (highway-env's Vehicle.step, 3 sub-steps)."""

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

from srmpc.mpc.problem import KinematicBicycle

RNG = np.random.default_rng(0)


def random_states_and_inputs(n: int, speed_range=(0.0, 38.0)):
    states = np.column_stack([
        RNG.uniform(-50, 500, n), RNG.uniform(-2, 10, n), RNG.uniform(-0.4, 0.4, n),
        RNG.uniform(*speed_range, n)])
    inputs = np.column_stack([RNG.uniform(-0.1, 0.1, n), RNG.uniform(-5, 5, n)])
    return states, inputs


def highway_env_control_step(state, control, n_substeps=3, substep_s=1 / 15):
    vehicle = Vehicle(None, state[:2].copy(), heading=state[2], speed=state[3])
    for _ in range(n_substeps):
        vehicle.act({"steering": control[0], "acceleration": control[1]})
        vehicle.step(substep_s)
    return np.array([*vehicle.position, vehicle.heading, vehicle.speed])


@pytest.mark.parametrize("speed_range", [(0.0, 38.0), (39.9, 45.0)])
def test_step_matches_highway_env_vehicle(speed_range):
    model = KinematicBicycle()
    states, inputs = random_states_and_inputs(50, speed_range)
    for state, control in zip(states, inputs, strict=True):
        np.testing.assert_allclose(model.step(state, control),
                                   highway_env_control_step(state, control), atol=1e-10)


def numerical_jacobians(model, state, control, eps=1e-6):
    a = np.empty((4, 4))
    b = np.empty((4, 2))
    for i in range(4):
        d = np.zeros(4)
        d[i] = eps
        a[:, i] = (model.step(state + d, control) - model.step(state - d, control)) / (2 * eps)
    for i in range(2):
        d = np.zeros(2)
        d[i] = eps
        b[:, i] = (model.step(state, control + d) - model.step(state, control - d)) / (2 * eps)
    return a, b


@pytest.mark.parametrize("speed_range", [(0.5, 38.0), (41.0, 45.0)])
def test_jacobians_match_finite_differences(speed_range):
    model = KinematicBicycle()
    states, inputs = random_states_and_inputs(40, speed_range)
    if speed_range[0] > 40:  # clipping branch: a > v_max - v, away from the kink
        inputs[:, 1] = RNG.uniform(0.0, 5.0, len(inputs))
    for state, control in zip(states, inputs, strict=True):
        _, a, b = model.step_with_jacobians(state, control)
        a_num, b_num = numerical_jacobians(model, state, control)
        np.testing.assert_allclose(a, a_num, atol=1e-7, rtol=1e-6)
        np.testing.assert_allclose(b, b_num, atol=1e-7, rtol=1e-6)


def test_linearize_and_rollout_agree_with_step():
    model = KinematicBicycle()
    _, inputs = random_states_and_inputs(25)
    x0 = np.array([0.0, 4.0, 0.0, 22.0])
    states = model.rollout(x0, inputs)
    for k in range(25):
        np.testing.assert_allclose(states[k + 1], model.step(states[k], inputs[k]), atol=1e-12)
    next_states, a, b, c = model.linearize(states, inputs)
    np.testing.assert_allclose(next_states, states[1:], atol=1e-12)
    # the affine model is exact at the linearization point
    affine = np.einsum("kij,kj->ki", a, states[:-1]) + np.einsum("kij,kj->ki", b, inputs) + c
    np.testing.assert_allclose(affine, states[1:], atol=1e-9)
