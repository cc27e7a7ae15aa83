"""Fallback chain and closed-loop physics of the LTV-MPC controller."""

import numpy as np
import pytest

from srmpc.mpc import LtvMpcController, StepOutcome
from srmpc.mpc.solvers import QpSolution, make_solver
from srmpc.mpc.synthetic_traffic import SyntheticHighway


class FailingAfter:
    """Wraps a solver; every solve from call number ``first_failure`` on fails."""

    name = "failing"

    def __init__(self, first_failure: int) -> None:
        self.inner = make_solver("riccati_ipm")
        self.first_failure = first_failure
        self.calls = 0

    def reset(self) -> None:
        self.inner.reset()

    def solve(self, qp, warm_start=None):
        self.calls += 1
        if self.calls >= self.first_failure:
            return QpSolution(False, "forced failure", None)
        return self.inner.solve(qp, warm_start)


def run_scene(controller, scene, steps):
    outcomes, crashed, offroad = [], False, False
    for _ in range(steps):
        ego, others = scene.observe()
        action, report = controller.act(ego, others)
        outcomes.append(report.outcome)
        result = scene.step(action)
        if result.crashed or result.offroad:
            crashed, offroad = result.crashed, result.offroad
            break
    return outcomes, crashed, offroad


def test_forced_failure_walks_the_fallback_chain():
    solver = FailingAfter(first_failure=4)
    controller = LtvMpcController(solver=solver)
    horizon = controller.config.horizon
    scene = SyntheticHighway(others=np.empty((0, 4)), ego_lane=2)
    outcomes, crashed, offroad = run_scene(controller, scene, 3 + horizon + 5)
    assert outcomes[:3] == [StepOutcome.SOLVED] * 3
    assert outcomes[3:3 + horizon - 1] == [StepOutcome.SHIFTED_PREVIOUS] * (horizon - 1)
    assert set(outcomes[3 + horizon - 1:]) == {StepOutcome.EMERGENCY_BRAKE}
    assert controller.outcome_counts["emergency_brake"] == 6
    assert not crashed and not offroad


def test_failure_at_first_step_brakes_and_holds_lane():
    controller = LtvMpcController(solver=FailingAfter(first_failure=1))
    scene = SyntheticHighway(others=np.empty((0, 4)), ego_lane=1, ego_speed_m_s=25.0)
    scene.ego[1] = 4.6  # off-centre: the lane hold steers back
    outcomes, _, _ = run_scene(controller, scene, 40)
    assert set(outcomes) == {StepOutcome.EMERGENCY_BRAKE}
    assert scene.ego[3] < 0.5
    assert abs(scene.ego[1] - 4.0) < 0.3


def test_no_traffic_settles_on_right_lane_at_reference_speed():
    controller = LtvMpcController()
    scene = SyntheticHighway(others=np.empty((0, 4)), ego_lane=0, ego_speed_m_s=20.0)
    outcomes, crashed, offroad = run_scene(controller, scene, 150)
    assert not crashed and not offroad
    assert set(outcomes) == {StepOutcome.SOLVED}
    x, y, heading, speed = scene.ego
    assert abs(y - 8.0) < 0.05
    assert abs(speed - 25.0) < 0.1
    assert abs(heading) < 1e-3


def test_slower_leader_with_free_left_lane_no_collision():
    leader = np.array([[40.0, 8.0, 0.0, 18.0]])
    controller = LtvMpcController()
    scene = SyntheticHighway(others=leader, ego_lane=2, ego_speed_m_s=25.0)
    gaps = []
    for _ in range(400):
        ego, others = scene.observe()
        action, _ = controller.act(ego, others)
        result = scene.step(action)
        assert not result.crashed and not result.offroad
        same_lane = abs(scene.ego[1] - scene.others[0, 1]) < 2.0
        if same_lane and scene.others[0, 0] > scene.ego[0]:
            gaps.append(scene.others[0, 0] - scene.ego[0] - 5.0)
    overtook = scene.ego[0] > scene.others[0, 0]
    assert overtook or min(gaps) > 5.0  # bumper-to-bumper gap [m]


@pytest.mark.slow
@pytest.mark.parametrize("spacing_m", [24.0, 15.0])
@pytest.mark.parametrize("seed", range(5))
def test_traffic_episodes_without_collision(spacing_m, seed):
    controller = LtvMpcController()
    scene = SyntheticHighway(n_others=40, mean_spacing_m=spacing_m, seed=seed)
    outcomes, crashed, offroad = run_scene(controller, scene, 400)
    assert not crashed and not offroad
    assert outcomes.count(StepOutcome.SOLVED) >= 0.99 * len(outcomes)
