"""Fallback chain and closed-loop physics of the LTV-MPC controller, on twin scenes of the scenario.

Hand-built scenes (exact ego and other vehicles) come from ``tests/twin_scenes.py``; traffic
episodes are the scenario's own random scenes (``TwinScenarioEnv``), driven by the scene-level
controller exactly as the evaluation drives it.
"""

import pytest

from srmpc.controllers.ltv_mpc import LtvMpcController
from srmpc.controllers.scenario_ocp import ocp_config
from srmpc.episode_loop import run_episode
from srmpc.mpc import CollisionGeometry, LtvMpcPlanner, OcpConfig, StepOutcome, TrackingWeights
from srmpc.mpc.solvers import QpSolution, make_solver
from srmpc.scenario import road
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.single_env import TwinScenarioEnv
from tests.twin_scenes import ego_state, hand_built_twin, observe, other_states


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


def run_scene(controller, twin, steps):
    """Drive the twin's ego with ``controller``; return (step outcomes, termination or "")."""
    outcomes = []
    for _ in range(steps):
        ego, others = observe(twin)
        action, report = controller.step(ego, others)
        outcomes.append(report.outcome)
        result = twin.step(action[None])
        if result.terminated[0]:
            return outcomes, result.termination(0)
    return outcomes, ""


def test_forced_failure_walks_the_fallback_chain():
    solver = FailingAfter(first_failure=4)
    controller = LtvMpcController(LtvMpcPlanner(solver=solver))
    horizon = controller.config.horizon
    twin = hand_built_twin(ego=(100.0, 8.0, 0.0, 25.0))
    outcomes, termination = run_scene(controller, twin, 3 + horizon + 5)
    assert outcomes[:3] == [StepOutcome.SOLVED] * 3
    assert outcomes[3:3 + horizon - 1] == [StepOutcome.SHIFTED_PREVIOUS] * (horizon - 1)
    assert set(outcomes[3 + horizon - 1:]) == {StepOutcome.EMERGENCY_BRAKE}
    assert controller.outcome_counts["emergency_brake"] == 6
    assert termination == ""


def test_failure_at_first_step_brakes_and_holds_lane():
    controller = LtvMpcController(LtvMpcPlanner(solver=FailingAfter(first_failure=1)))
    twin = hand_built_twin(ego=(100.0, 4.6, 0.0, 25.0))  # off-centre: the lane hold steers back
    outcomes, termination = run_scene(controller, twin, 40)
    assert termination == ""
    assert set(outcomes) == {StepOutcome.EMERGENCY_BRAKE}
    _, y, _, speed = ego_state(twin)
    assert abs(speed) < 0.5
    assert abs(y - 4.0) < 0.3


def test_no_traffic_settles_on_right_lane_at_reference_speed():
    controller = LtvMpcController()
    twin = hand_built_twin(ego=(100.0, 0.0, 0.0, 20.0))
    outcomes, termination = run_scene(controller, twin, 150)
    assert termination == ""
    assert set(outcomes) == {StepOutcome.SOLVED}
    x, y, heading, speed = ego_state(twin)
    assert abs(y - 8.0) < 0.05
    assert abs(speed - 25.0) < 0.1
    assert abs(heading) < 1e-3


def test_slower_leader_with_free_left_lane_no_collision():
    controller = LtvMpcController()
    twin = hand_built_twin(ego=(100.0, 8.0, 0.0, 25.0), others=[(140.0, 8.0, 0.0, 18.0)])
    gaps = []
    for _ in range(400):
        ego, others = observe(twin)
        action, _ = controller.step(ego, others)
        result = twin.step(action[None])
        assert not result.terminated[0], result.termination(0)
        ego, leader = ego_state(twin), other_states(twin)[0]
        same_lane = abs(ego[1] - leader[1]) < 2.0
        if same_lane and leader[0] > ego[0]:
            gaps.append(leader[0] - ego[0] - road.VEHICLE_LENGTH)
    overtook = ego[0] > leader[0]
    assert overtook or min(gaps) > 5.0  # bumper-to-bumper gap [m]


TRAFFIC_MEAN_SPAWN_GAP_M = {"light": 25.0, "dense": 15.0}
"""conf/scenario/{light,dense}.yaml."""
KNOWN_COLLISIONS = {
    ("light", 1): "the ego accelerates to ~32 m/s and cuts into the right lane onto a 19.7 m/s vehicle (step 47)",
    ("dense", 1): "the ego, boxed in on the middle lane, accelerates to ~28 m/s and cuts into the right lane "
                  "onto a 17 m/s vehicle (step 21)",
}
"""Episodes in which the LTV-MPC collides today (as in results/evaluation/twin/ltv_mpc_*, whose seed
s + 0 is the same scene): its plans keep a positive collision slack (about 0.6) for several steps
before. strict: a planner fix makes them pass and this list must then shrink."""


def _episode_params():
    for traffic in TRAFFIC_MEAN_SPAWN_GAP_M:
        for seed in range(5):
            reason = KNOWN_COLLISIONS.get((traffic, seed))
            marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
            yield pytest.param(traffic, seed, marks=marks, id=f"{traffic}-{seed}")


@pytest.mark.slow
@pytest.mark.parametrize(("traffic", "seed"), list(_episode_params()))
def test_traffic_episodes_without_collision(traffic, seed):
    params = ScenarioParameters(traffic=traffic, mean_spawn_gap_m=TRAFFIC_MEAN_SPAWN_GAP_M[traffic])
    config = OcpConfig()
    ocp = ocp_config(params, config.horizon, config.max_vehicles, TrackingWeights(), CollisionGeometry())
    controller = LtvMpcController(LtvMpcPlanner(ocp))
    metrics, reason, outcomes = run_episode(TwinScenarioEnv(params), controller, seed)
    assert reason == "truncated", f"episode ended by {reason} after {metrics.n_steps} steps"
    assert metrics.n_steps == params.episode_steps and metrics.event_cost == 0.0
    assert outcomes["solved"] >= 0.99 * metrics.n_steps
