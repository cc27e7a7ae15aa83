"""The one controller factory: the scenario's env and ``controller`` for it, from a composed config.

The evaluation stage, the trajectory figure, the episode videos and the latency benchmark all build their
controllers here, so a controller is built one way wherever it runs. It sits above ``config`` (it reads the
composed :class:`~srmpc.config.schema.Config`) and below ``stages``.

- :func:`make_env`: the scenario on ``evaluation.simulator``;
- :func:`build_controller`: lane keeping, LTV-MPC, SRMPC, NMPC or a trained policy, from the config's plain values;
- :func:`planner_ocp`: the OCP that LTV-MPC and SRMPC share (``planner`` applied to the scenario);
- :func:`policy_file`, :func:`load_policy`: the policy a controller runs, from its file.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np

from srmpc import SCENARIO_ID
from srmpc.config.compose import ConfigError
from srmpc.config.schema import Config, ControllerName, SimulatorName
from srmpc.controllers import Controller
from srmpc.controllers.lane_keeping import LaneKeepingController, LaneKeepingGains
from srmpc.controllers.ltv_mpc import LtvMpcController
from srmpc.controllers.nmpc import POLICY_GUESSES, NmpcController
from srmpc.controllers.policy import PolicyController
from srmpc.controllers.scenario_ocp import ocp_config
from srmpc.controllers.srmpc import SceneSource, SrmpcController
from srmpc.mpc.nmpc import NmpcSolver
from srmpc.mpc.planner import LtvMpcPlanner
from srmpc.mpc.problem import CollisionGeometry, OcpConfig, TrackingWeights, lane_keeping_tracking_reference
from srmpc.scenario import road
from srmpc.sim.constants import SimConstants
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.simulator import TwinSimulator
from srmpc.sim.single_env import HighwayEnvStartTwinEnv, TwinScenarioEnv
from srmpc.sim.state import SceneState

REPOSITORY = Path(__file__).resolve().parents[1]
"""The repository root: default policy files are its results/training/<agent>/policy.pt, from any directory."""


def planner_ocp(config: Config) -> tuple[OcpConfig, float]:
    """The OCP of ``planner`` for the scenario, and y_ref [m] (shared by LTV-MPC and SRMPC)."""
    scenario, planner = config.scenario, config.planner
    scale = planner.slack_price_scale  # a common factor on the four slack prices (1: exactly the listed ones)
    weights = TrackingWeights(
        state=tuple(planner.state_weights), input=tuple(planner.input_weights),
        input_rate=tuple(planner.input_rate_weights),
        collision_slack_linear=scale * planner.collision_slack_linear,
        collision_slack_quadratic=scale * planner.collision_slack_quadratic,
        safety_slack_linear=scale * planner.safety_slack_linear,
        safety_slack_quadratic=scale * planner.safety_slack_quadratic,
    )
    geometry = CollisionGeometry(
        n_ego_circles=planner.n_ego_circles,
        safety_margin_longitudinal_m=planner.safety_margin_longitudinal_m,
        safety_margin_lateral_m=planner.safety_margin_lateral_m,
    )
    ocp = ocp_config(scenario, planner.horizon_steps, planner.max_vehicles, weights, geometry)
    return ocp, float(road.LANE_CENTERS[road.RIGHT_LANE])


def _default_policy_path(agent: str, path: str | None) -> Path:
    """``path``, or unset, ``agent``'s designated training output results/training/<agent>/policy.pt."""
    return Path(path) if path else REPOSITORY / "results" / "training" / agent / "policy.pt"


def policy_file(config: Config) -> tuple[Path, str, str] | None:
    """(file, agent, config key) of the policy the controller runs or rolls out; None when it runs none."""
    controller = config.controller
    if controller.name is ControllerName.nmpc and controller.initial_guess not in POLICY_GUESSES:
        return None
    if controller.name not in (ControllerName.policy, ControllerName.srmpc, ControllerName.nmpc):
        return None
    key = "controller.policy_path" if controller.policy_path else "controller.policy"
    return _default_policy_path(controller.policy, controller.policy_path), controller.policy, key


def load_policy(config: Config) -> MlpPolicy:
    """The deterministic actor (TanhNormal mode) of the policy the controller runs (:func:`policy_file`)."""
    scenario = config.scenario
    file, agent, key = policy_file(config)
    if not file.is_file():
        value = config.controller.policy_path or agent
        raise ConfigError(f"{key}={value!r}: no such policy file {str(file)!r} (train first: stage=train "
                          f"agent={agent})")
    low = np.array([-scenario.steering_max_rad, scenario.acceleration_min_mps2])
    high = np.array([scenario.steering_max_rad, scenario.acceleration_max_mps2])
    return PolicyController.from_policy_file(file, low, high).policy


def scene_source(env: gymnasium.Env) -> SceneSource:
    """SRMPC's copy of the live scene: the twin's own state, or a twin copy of the highway-env scene."""
    scenario_env = env.unwrapped
    if isinstance(scenario_env, TwinScenarioEnv):
        simulator = scenario_env.simulator
        return lambda: (simulator.state, simulator.constants)

    def copy_of_highway_env() -> tuple[SceneState, SimConstants]:
        twin = TwinSimulator.from_highway_env([scenario_env], threads=1)
        return twin.state, twin.constants

    return copy_of_highway_env


def build_controller(config: Config, env: gymnasium.Env) -> Controller:
    """The controller named by ``controller.name`` for ``env``, built from the config's plain values."""
    scenario, controller = config.scenario, config.controller
    name = controller.name
    if name is ControllerName.lane_keeping:
        return LaneKeepingController(
            scenario.steering_max_rad, scenario.acceleration_min_mps2, scenario.acceleration_max_mps2,
            LaneKeepingGains(target_speed_mps=scenario.reward.vx_ref_mps),
        )
    if name is ControllerName.policy:
        return PolicyController(load_policy(config))
    ocp, y_ref = planner_ocp(config)
    tracking = lane_keeping_tracking_reference(ocp.horizon, y_ref, scenario.reward.vx_ref_mps,
                                               control_period_s=ocp.control_period_s)
    planner = LtvMpcPlanner(ocp, config.planner.solver)
    if name is ControllerName.ltv_mpc:
        return LtvMpcController(planner, tracking)
    if name is ControllerName.srmpc:
        return SrmpcController(load_policy(config), planner, scene_source(env), tracking, controller.srmpc)
    if name is ControllerName.nmpc:
        if controller.initial_guess not in POLICY_GUESSES:
            return NmpcController(NmpcSolver(ocp), planner, tracking, controller.initial_guess)
        return NmpcController(NmpcSolver(ocp), planner, tracking, controller.initial_guess, load_policy(config),
                              scene_source(env))
    raise ConfigError(f"controller={name.value}: not implemented")


def make_env(config: Config) -> gymnasium.Env:
    """The scenario on ``evaluation.simulator``."""
    if config.evaluation.simulator is SimulatorName.twin:
        return TwinScenarioEnv(config.scenario)
    if config.evaluation.simulator is SimulatorName.twin_highway_env_resets:
        return HighwayEnvStartTwinEnv(config.scenario)
    return gymnasium.make(SCENARIO_ID, params=config.scenario)


def make_env_and_controller(config: Config) -> tuple[gymnasium.Env, Controller]:
    """The scenario on ``evaluation.simulator`` and ``controller`` for it: what an evaluation,
    and each of its worker processes, builds once."""
    env = make_env(config)
    try:
        return env, build_controller(config, env)
    except Exception:
        env.close()
        raise
