"""The structure-exploiting interior-point solver against Clarabel at tight tolerance."""

import numpy as np
import pytest

from srmpc.controllers.ltv_mpc import LtvMpcController
from srmpc.mpc import OcpConfig, StepOutcome
from srmpc.mpc.planner import LtvMpcPlanner
from srmpc.mpc.problem import LtvMpcQp, OcpStepData, lane_keeping_tracking_reference, predict_constant_velocity
from srmpc.mpc.solvers import make_solver
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.single_env import TwinScenarioEnv

FIRST_INPUT_TOLERANCE = 1e-3
"""Required agreement of u_0 with Clarabel [rad, m/s^2] (issue 4)."""


def random_qp(rng: np.random.Generator, n_others: int) -> LtvMpcQp:
    """The OCP linearized about a random input sequence among random nearby vehicles.

    Vehicles are placed within +-40 m of the ego on random lanes, some overlapping the ego's
    path, so that safety and collision slacks are used in a part of the instances.
    """
    config = OcpConfig()
    qp = LtvMpcQp(config)
    horizon = config.horizon
    ego = np.array([0.0, rng.uniform(-0.5, 8.5), rng.uniform(-0.05, 0.05), rng.uniform(15, 30)])
    inputs = np.column_stack([rng.uniform(-0.05, 0.05, horizon), rng.uniform(-2, 2, horizon)])
    states = qp.model.rollout(ego, inputs)
    others = np.column_stack([rng.uniform(-40, 40, n_others),
                              rng.choice([0.0, 4.0, 8.0], n_others) + rng.normal(0, 0.3, n_others),
                              rng.normal(0, 0.02, n_others), rng.uniform(15, 30, n_others)])
    qp.update(OcpStepData(ego, states, inputs,
                          lane_keeping_tracking_reference(horizon, speed_mps=rng.uniform(20, 30)),
                          rng.uniform([-0.1, -5], [0.1, 5]),
                          predict_constant_velocity(others, horizon, config.control_period_s)))
    return qp


def assert_agrees_with_clarabel(qp: LtvMpcQp) -> dict[str, float]:
    reference = make_solver("clarabel").solve(qp)
    assert reference.solved
    solution = make_solver("riccati_ipm").solve(qp)
    assert solution.solved, solution.status
    u0 = qp.split_solution(solution.z)[1][0]
    u0_reference = qp.split_solution(reference.z)[1][0]
    assert np.max(np.abs(u0 - u0_reference)) < FIRST_INPUT_TOLERANCE
    violation = qp.constraint_violation(solution.z)
    assert max(violation.values()) < 1e-6, violation
    objective, objective_reference = qp.objective(solution.z), qp.objective(reference.z)
    assert objective == pytest.approx(objective_reference, rel=1e-6, abs=1e-4)
    return violation


@pytest.mark.parametrize("seed", range(12))
def test_random_instances_agree_with_clarabel(seed):
    rng = np.random.default_rng(seed)
    assert_agrees_with_clarabel(random_qp(rng, n_others=int(rng.integers(0, 7))))


def test_instance_with_collision_slack_in_use():
    """A vehicle overlapping the ego now: the collision slack must be positive, as Clarabel's."""
    config = OcpConfig()
    qp = LtvMpcQp(config)
    ego = np.array([0.0, 4.0, 0.0, 25.0])
    inputs = np.zeros((config.horizon, 2))
    others = np.array([[2.0, 4.5, 0.0, 25.0], [30.0, 8.0, 0.0, 20.0]])
    qp.update(OcpStepData(ego, qp.model.rollout(ego, inputs), inputs,
                          lane_keeping_tracking_reference(config.horizon), np.zeros(2),
                          predict_constant_velocity(others, config.horizon, config.control_period_s)))
    assert_agrees_with_clarabel(qp)
    solution = make_solver("riccati_ipm").solve(qp)
    collision_slacks = qp.split_solution(solution.z)[2]
    assert collision_slacks[0] > 1e-3
    np.testing.assert_allclose(collision_slacks[qp.n_observed:], 0.0)


def test_benchmark_scene_qps_agree_with_clarabel():
    """QPs met in closed loop on the benchmark's first light and dense twin scenes.

    The dense episode (seed 1) ends in a collision at step 21, after several steps whose plans use
    the collision slack: those instances are checked too.
    """
    checked = 0
    for traffic, mean_spawn_gap_m, seed in (("light", 25.0, 0), ("dense", 15.0, 1)):
        env = TwinScenarioEnv(ScenarioParameters(traffic=traffic, mean_spawn_gap_m=mean_spawn_gap_m))
        env.reset(seed=seed)
        controller = LtvMpcController(LtvMpcPlanner(solver="riccati_ipm"))
        for step in range(60):
            scene = env.measurement
            action, report = controller.step(scene.ego, scene.others[scene.slot_vehicle[scene.slot_vehicle >= 0]])
            assert report.outcome is StepOutcome.SOLVED
            if step % 5 == 0:
                assert_agrees_with_clarabel(controller.planner.qp)
                checked += 1
            if env.step(action)[2]:  # terminated
                break
    assert checked >= 15


def test_infeasible_qp_is_reported_not_solved_and_planner_falls_back():
    """The ego 20 m beside the road: y_1 cannot reach the lateral bounds in one step."""
    config = OcpConfig()
    qp = LtvMpcQp(config)
    ego = np.array([0.0, 30.0, 0.0, 20.0])
    inputs = np.zeros((config.horizon, 2))
    qp.update(OcpStepData(ego, qp.model.rollout(ego, inputs), inputs,
                          lane_keeping_tracking_reference(config.horizon), np.zeros(2),
                          np.zeros((config.horizon + 1, 0, 4))))
    solution = make_solver("riccati_ipm").solve(qp)
    assert not solution.solved
    assert solution.z is None
    planner = LtvMpcPlanner(config, solver="riccati_ipm")
    plan = planner.plan(ego, np.empty((0, 4)), np.zeros(2))
    assert plan.outcome is StepOutcome.EMERGENCY_BRAKE
