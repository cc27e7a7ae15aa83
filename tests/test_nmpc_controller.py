"""The NMPC controllers in closed loop
(``controller=nmpc controller.initial_guess=constant_velocity|shifted|rollout|best_of_two``)."""

from __future__ import annotations

import numpy as np
import pytest

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller, policy_file
from srmpc.controllers.nmpc import NmpcController, NmpcInitialGuess
from srmpc.sim.single_env import TwinScenarioEnv

STEPS = 12
"""Control steps per episode (2.4 s): short, the NMPC takes ~10 ms a step."""
GUESS = {guess.value: guess for guess in NmpcInitialGuess}
"""Where the SQP starts (srmpc/controllers/nmpc.py documents each)."""


@pytest.mark.parametrize("controller", sorted(GUESS))
def test_nmpc_controller_drives_short_dense_episodes(controller):
    config = to_objects(compose_config(["+experiment=dense_traffic", "tracking.enabled=false",
                                        "controller=nmpc", f"controller.initial_guess={controller}"]))
    env = TwinScenarioEnv(config.scenario)
    nmpc = build_controller(config, env)
    assert isinstance(nmpc, NmpcController) and nmpc.initial_guess is GUESS[controller]
    assert (policy_file(config) is None) == (controller in ("shifted", "constant_velocity"))
    low = np.array([-config.scenario.steering_max_rad, config.scenario.acceleration_min_mps2])
    high = np.array([config.scenario.steering_max_rad, config.scenario.acceleration_max_mps2])
    for seed in (0, 1):
        observation, _ = env.reset(seed=seed)
        nmpc.reset()
        steps = 0
        for _ in range(STEPS):
            action = nmpc.act(observation, env.unwrapped.measurement)
            assert np.all(np.isfinite(action)) and np.all(action >= low - 1e-9) and np.all(action <= high + 1e-9)
            observation, _, terminated, truncated, _ = env.step(action)
            steps += 1
            if terminated or truncated:
                break
        outcomes = nmpc.episode_outcomes()
        assert outcomes["solved"] + outcomes["shifted_previous"] + outcomes["emergency_brake"] == steps
        solved_by_guess = (outcomes["solved_from_policy"] + outcomes["solved_from_shifted"]
                           + outcomes["solved_from_lane_following"])
        assert solved_by_guess == outcomes["solved"] >= steps - 2  # the SQP converges on nearly every step
        if nmpc.initial_guess is NmpcInitialGuess.constant_velocity:  # never the last plan, never the policy
            assert outcomes["solved_from_lane_following"] == outcomes["solved"]
        elif nmpc.initial_guess is NmpcInitialGuess.shifted:
            assert outcomes["solved_from_policy"] == 0 and outcomes["solved_from_shifted"] > 0
        else:
            assert outcomes["solved_from_policy"] > 0
