"""The scenario's OCP (srmpc/controllers/scenario_ocp.py) takes its time step from the scenario.

The planner's prediction model must hold one input for the scenario's control period (1 / policy
frequency) and integrate it in the scenario's sub-steps, as the plant does: then its one-step
prediction of the ego equals the twin's step, at any policy frequency.
"""

import numpy as np
import pytest

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import planner_ocp
from srmpc.mpc.problem import KinematicBicycle
from tests.twin_scenes import ego_state, hand_built_twin


@pytest.mark.parametrize(("policy_hz", "simulation_hz"), [(5, 15), (10, 30), (15, 15)])
def test_the_ocp_time_step_is_the_scenario_control_period(policy_hz, simulation_hz):
    overrides = [f"scenario.policy_frequency_hz={policy_hz}", f"scenario.simulation_frequency_hz={simulation_hz}"]
    config = to_objects(compose_config(overrides))
    ocp, _ = planner_ocp(config)
    assert ocp.control_period_s == config.scenario.control_period_s == 1.0 / policy_hz
    assert ocp.bicycle.n_substeps == simulation_hz // policy_hz

    twin = hand_built_twin(ego=(100.0, 8.0, 0.0, 22.0), policy_frequency_hz=policy_hz,
                           simulation_frequency_hz=simulation_hz)
    state, action = ego_state(twin), np.array([0.02, 1.5])
    twin.step(action[None])
    np.testing.assert_allclose(KinematicBicycle(ocp.bicycle).step(state, action), ego_state(twin), atol=1e-9)
