"""Structured-config schema of ``conf/``. Registered in Hydra's ConfigStore as ``config_schema``.

A wrong type, an unknown key or a bad enum value in any YAML file or override is rejected at
composition, naming the key; so is a value outside what the field declares in its ``__post_init__``
(``srmpc.value_checks``: finite numbers in a range, list lengths, non-empty strings). The entry
points convert these nodes into the plain dataclasses that library code takes (``OmegaConf.to_object``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from hydra.core.config_store import ConfigStore

from srmpc.agents.hyperparameters import PPOHyperparameters
from srmpc.controllers.nmpc import POLICY_GUESSES, NmpcInitialGuess
from srmpc.controllers.srmpc import SrmpcSettings, variant_of
from srmpc.mpc.problem import MAX_EGO_CIRCLES, MAX_HORIZON_STEPS, MAX_VEHICLE_SLOTS, OcpConfig
from srmpc.mpc.solvers import DEFAULT_SOLVER
from srmpc.scenario.observation import SLOT_COUNT
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.value_checks import NON_NEGATIVE, TEXT, Interval, Vector, at_least, check_fields


class Stage(Enum):
    """What ``python -m srmpc`` does."""

    evaluate = "evaluate"
    """Run closed-loop evaluation episodes of ``controller``."""
    train = "train"
    """Train ``agent`` (PPO or PPO-L-SI) on the batched simulator; resumes from its checkpoint."""
    train_sb3 = "train_sb3"
    """Train Stable-Baselines3's PPO with ``agent``'s hyperparameters on the same simulator (srmpc.sb3_ppo)."""


class ControllerName(Enum):
    """Controllers that evaluation can run (``conf/controller/<name>.yaml``)."""

    lane_keeping = "lane_keeping"
    """IDM + lane-centre steering baseline (srmpc.controllers.lane_keeping)."""
    policy = "policy"
    """A trained agent's actor, its deterministic action (``controller.policy``: ppo_lsi, ppo, ppo_sb3, ...)."""
    ltv_mpc = "ltv_mpc"
    """LTV-MPC with the ``planner`` settings (srmpc.controllers.ltv_mpc)."""
    srmpc = "srmpc"
    """SRMPC: the LTV-MPC (``planner``) linearized about ``controller.policy``'s rollout (``controller.srmpc``)."""
    nmpc = "nmpc"
    """NMPC: the ``planner``'s OCP on the exact model solved to convergence by SQP (srmpc.controllers.nmpc),
    started from ``controller.initial_guess``."""


@dataclass
class ControllerConfig:
    """The controller that drives the ego, with what it needs (``conf/controller/``): the policy it runs or rolls
    out, SRMPC's settings, the NMPC's initial guess. The planner settings are ``planner``'s, shared by LTV-MPC,
    SRMPC and the NMPC. The defaults are SRMPC's (the paper's); each option of conf/controller/ sets every field."""

    name: ControllerName = ControllerName.srmpc
    """Which controller."""
    policy: str | None = "ppo_lsi"
    """The trained agent whose deterministic actor the controller runs (``policy``) or rolls out (``srmpc``; the
    ``nmpc`` from ``rollout`` or ``best_of_two``): ppo_lsi (the paper's), ppo, ppo_sb3, ppo_lsi_rss, ...; null for
    the controllers that run none (lane_keeping, ltv_mpc)."""
    policy_path: str | None = None
    """Its policy.pt; null means results/training/<policy>/policy.pt."""
    srmpc: SrmpcSettings | None = field(default_factory=SrmpcSettings)
    """SRMPC's settings (srmpc.controllers.srmpc.SrmpcSettings; all defaults = the paper's Algorithm 1); set for
    ``srmpc`` only."""
    initial_guess: NmpcInitialGuess | None = None
    """Where the NMPC's SQP starts each step: constant_velocity, shifted (the previous plan), rollout (the policy's),
    best_of_two (srmpc.controllers.nmpc); set for ``nmpc`` only."""

    def __post_init__(self) -> None:
        check_fields(self, policy=TEXT, policy_path=TEXT)
        name = self.name.value
        runs_policy = self.name in (ControllerName.policy, ControllerName.srmpc) or (
            self.name is ControllerName.nmpc and self.initial_guess in POLICY_GUESSES)
        if runs_policy and self.policy is None:
            raise ValueError(f"policy=null: controller {name} runs a policy; set controller.policy=<agent>")
        if self.name in (ControllerName.lane_keeping, ControllerName.ltv_mpc) and (self.policy or self.policy_path):
            raise ValueError(f"policy={self.policy}: controller {name} runs no policy; leave controller.policy null")
        if (self.srmpc is None) == (self.name is ControllerName.srmpc):
            raise ValueError(f"srmpc={'null' if self.srmpc is None else 'set'}: SRMPC's settings belong to "
                             f"controller=srmpc only (this is controller={name})")
        if (self.initial_guess is None) == (self.name is ControllerName.nmpc):
            raise ValueError(f"initial_guess={getattr(self.initial_guess, 'value', 'null')}: the initial guess "
                             f"belongs to controller=nmpc only (this is controller={name})")


AgentConfig = PPOHyperparameters
"""PPO / PPO-L-SI hyperparameters (srmpc.agents.hyperparameters, every field documented there)."""


_OCP = OcpConfig()
"""The OCP's own defaults (srmpc/mpc/problem/ocp.py): the one place the planner's default numbers are written."""


@dataclass
class PlannerConfig:
    """LTV-MPC settings (paper section "MPC for Automated Driving"); see srmpc/mpc/problem/ocp.py for the math.

    Input bounds come from the scenario's action ranges; road and speed bounds from its geometry.
    Every default is the OCP's own (``OcpConfig``, ``TrackingWeights``, ``CollisionGeometry``), so
    ``conf/planner/ltv_mpc.yaml`` repeats none of them.
    """

    horizon_steps: int = _OCP.horizon
    """Prediction horizon N (25 x 0.2 s = 5 s); at most ``MAX_HORIZON_STEPS`` (srmpc/mpc/problem/ocp.py says why)."""
    solver: str = DEFAULT_SOLVER
    """QP solver: riccati_ipm (default, structure-exploiting interior point, warm-started), riccati_ipm_cold
    (the same, started cold at every step), piqp_native, osqp_native, or via qpsolvers osqp, clarabel, piqp,
    proxqp."""
    max_vehicles: int = _OCP.max_vehicles
    """Other-vehicle slots in the QP (the scenario observes at most 6, so at least 6; at most ``MAX_VEHICLE_SLOTS``)."""
    state_weights: list[float] = field(default_factory=lambda: list(_OCP.weights.state))
    """Q diagonal for (x [1/m^2], y [1/m^2], heading [1/rad^2], speed [s^2/m^2]); x is not tracked."""
    input_weights: list[float] = field(default_factory=lambda: list(_OCP.weights.input))
    """R diagonal for (steering [1/rad^2], acceleration [s^4/m^2])."""
    input_rate_weights: list[float] = field(default_factory=lambda: list(_OCP.weights.input_rate))
    """S diagonal on input differences (the first against the last applied input)."""
    collision_slack_linear: float = _OCP.weights.collision_slack_linear
    """Linear penalty on the per-vehicle collision slack (ellipse-norm units)."""
    collision_slack_quadratic: float = _OCP.weights.collision_slack_quadratic
    """Quadratic penalty on the per-vehicle collision slack."""
    safety_slack_linear: float = _OCP.weights.safety_slack_linear
    """Linear penalty on the per-stage safety-region slack (cheaper: entered only if necessary)."""
    safety_slack_quadratic: float = _OCP.weights.safety_slack_quadratic
    """Quadratic penalty on the safety-region slack."""
    slack_price_scale: float = 1.0
    """Common factor on the four slack prices above [dimensionless], in (0, 1]: the QP uses
    scale x collision_slack_linear, ... , scale x safety_slack_quadratic. 1 keeps the listed prices; below 1
    both soft constraints get cheaper against the tracking cost, so the planner enters the safety region and
    keeps collision slack sooner (conf/planner/paper_operating_point.yaml: the paper's LTV-MPC row)."""
    n_ego_circles: int = _OCP.geometry.n_ego_circles
    """Circles covering the ego (2 to ``MAX_EGO_CIRCLES``)."""
    safety_margin_longitudinal_m: float = _OCP.geometry.safety_margin_longitudinal_m
    """Safety-region semi-major axis minus the collision ellipse's [m]."""
    safety_margin_lateral_m: float = _OCP.geometry.safety_margin_lateral_m
    """Safety-region semi-minor axis minus the collision ellipse's [m]."""

    def __post_init__(self) -> None:
        from srmpc.mpc.solvers import available_solvers

        check_fields(
            self, horizon_steps=Interval(2, MAX_HORIZON_STEPS), solver=TEXT,
            max_vehicles=Interval(SLOT_COUNT, MAX_VEHICLE_SLOTS),
            state_weights=Vector(NON_NEGATIVE, length=4), input_weights=Vector(NON_NEGATIVE, length=2),
            input_rate_weights=Vector(NON_NEGATIVE, length=2), collision_slack_linear=NON_NEGATIVE,
            collision_slack_quadratic=NON_NEGATIVE, safety_slack_linear=NON_NEGATIVE,
            safety_slack_quadratic=NON_NEGATIVE, slack_price_scale=Interval(0.0, 1.0, low_open=True),
            n_ego_circles=Interval(2, MAX_EGO_CIRCLES),
            safety_margin_longitudinal_m=NON_NEGATIVE, safety_margin_lateral_m=NON_NEGATIVE,
        )
        if self.solver not in available_solvers():
            raise ValueError(f"solver={self.solver!r}: unknown QP solver; available: {', '.join(available_solvers())}")


class SimulatorName(Enum):
    """Which simulator evaluation runs on."""

    twin = "twin"
    """The batched numba twin (srmpc.sim), identical step for step to highway-env and ~3000x faster."""
    highway_env = "highway_env"
    """srmpc/Highway-v0 on highway-env itself (the reference; ~28 steps/s)."""
    twin_highway_env_resets = "twin_highway_env_resets"
    """The twin, each episode starting from highway-env's own reset for its seed, copied into the twin
    (srmpc.sim.single_env.HighwayEnvStartTwinEnv): highway-env's start states at the twin's speed."""


@dataclass
class EvaluationConfig:
    """Closed-loop evaluation."""

    simulator: SimulatorName = SimulatorName.twin
    """Where the episodes run. Episode i is reset with seed + i on either; the twin's draw for a seed
    differs from highway-env's (same distributions, own random streams)."""
    episodes: int = 1000
    """Number of episodes (paper: 1000 per traffic level)."""
    seed: int = 0
    """Episode i is reset with seed + i."""
    output_dir: str | None = None
    """Where episodes.csv and summary.json go; null means results/evaluation/<experiment>_<traffic> for a run of
    ``+experiment=<experiment>``, else Hydra's run directory. Rerunning into a
    directory that holds a partial run of the same config resumes it."""
    workers: int = 0
    """Processes that run the episodes (episode i still from seed + i, so the episodes do not depend on
    it): 0 means one per CPU core this process may use, 1 runs them in this process."""

    def __post_init__(self) -> None:
        check_fields(self, episodes=at_least(1), seed=NON_NEGATIVE, output_dir=TEXT,
                     workers=NON_NEGATIVE)  # 0: one per core


@dataclass
class TrackingConfig:
    """MLflow tracking."""

    enabled: bool = True
    """Log runs to MLflow."""
    uri: str = "sqlite:///mlflow.db"
    """Tracking URI (default: SQLite file in the working directory, the repo root)."""
    artifact_location: str = "mlruns"
    """Artifact root for new experiments (relative paths are taken from the working directory)."""
    experiment_name: str = "srmpc"
    """MLflow experiment."""

    def __post_init__(self) -> None:
        check_fields(self, uri=TEXT, artifact_location=TEXT, experiment_name=TEXT)


@dataclass
class Config:
    """Root of the composed configuration."""

    stage: Stage = Stage.evaluate
    experiment: str | None = None
    """The run's identity: the ``+experiment=<path>`` it was started with (conf/experiment/<path>.yaml), filled in
    by the entry point (srmpc.config.compose.with_experiment_name), never set by hand; null without one."""
    scenario: ScenarioParameters = field(default_factory=ScenarioParameters)
    agent: AgentConfig = field(default_factory=AgentConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    controller: ControllerConfig = field(default_factory=ControllerConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)

    def __post_init__(self) -> None:
        check_fields(self, experiment=TEXT)


def controller_label(controller: ControllerConfig) -> str:
    """A short display name of a controller: ``ltv_mpc``, ``srmpc`` (its variant appended unless the paper's:
    ``srmpc-track_rollout``), ``policy-ppo_sb3``, ``nmpc-rollout``. A run's identity is its experiment, not this."""
    name = controller.name.value
    if controller.srmpc is not None:
        variant = variant_of(controller.srmpc)
        return name if variant == "paper" else f"{name}-{variant}"
    if controller.initial_guess is not None:
        return f"{name}-{controller.initial_guess.value}"
    return f"{name}-{controller.policy}" if controller.name is ControllerName.policy else name


def register_schema() -> None:
    """Store the schema in Hydra's ConfigStore (idempotent)."""
    ConfigStore.instance().store(name="config_schema", node=Config)
