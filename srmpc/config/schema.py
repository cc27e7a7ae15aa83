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
from srmpc.controllers.srmpc import MAX_RELINEARIZATIONS, SrmpcSettings
from srmpc.scenario.observation import SLOT_COUNT
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.value_checks import NON_NEGATIVE, TEXT, Interval, Vector, at_least, check_fields


class Stage(Enum):
    """What ``python -m srmpc`` does."""

    evaluate = "evaluate"
    """Run closed-loop evaluation episodes of ``evaluation.controller``."""
    train = "train"
    """Train ``agent`` (PPO or PPO-L-SI) on the batched simulator; resumes from its checkpoint."""
    train_sb3 = "train_sb3"
    """Train Stable-Baselines3's PPO with ``agent``'s hyperparameters on the same simulator (srmpc.sb3_ppo)."""


class ControllerName(Enum):
    """Controllers that evaluation can run."""

    lane_keeping = "lane_keeping"
    """IDM + lane-centre steering baseline (srmpc.controllers.lane_keeping)."""
    ltv_mpc = "ltv_mpc"
    """LTV-MPC with the ``planner`` settings (srmpc.controllers.ltv_mpc)."""
    ppo_lsi = "ppo_lsi"
    """The trained PPO-L-SI actor's deterministic action (``evaluation.policy_path``)."""
    ppo = "ppo"
    """The trained PPO actor's deterministic action (``evaluation.policy_path``)."""
    srmpc = "srmpc"
    """SRMPC: the LTV-MPC (``planner``) linearized about the ``srmpc.policy``'s rollout (srmpc.controllers.srmpc)."""


class PolicyName(Enum):
    """A trained agent whose actor SRMPC rolls out."""

    ppo_lsi = "ppo_lsi"
    """PPO-L-SI (the paper's safe policy)."""
    ppo = "ppo"
    """PPO (ablation: an unconstrained policy's reference)."""


AgentConfig = PPOHyperparameters
"""PPO / PPO-L-SI hyperparameters (srmpc.agents.hyperparameters, every field documented there)."""


@dataclass
class PlannerConfig:
    """LTV-MPC settings (paper section "MPC for Automated Driving"); see srmpc/mpc/ocp.py for the math.

    Input bounds come from the scenario's action ranges; road and speed bounds from its geometry.
    """

    horizon_steps: int = 25
    """Prediction horizon N (25 x 0.2 s = 5 s)."""
    solver: str = "riccati_ipm"
    """QP solver: riccati_ipm (default, structure-exploiting interior point), piqp_native, osqp_native,
    or via qpsolvers osqp, clarabel, piqp, proxqp."""
    max_vehicles: int = 6
    """Other-vehicle slots in the QP (the scenario observes at most 6, so at least 6)."""
    state_weights: list[float] = field(default_factory=lambda: [0.0, 0.5, 20.0, 0.5])
    """Q diagonal for (x [1/m^2], y [1/m^2], heading [1/rad^2], speed [s^2/m^2]); x is not tracked."""
    input_weights: list[float] = field(default_factory=lambda: [50.0, 0.05])
    """R diagonal for (steering [1/rad^2], acceleration [s^4/m^2])."""
    input_rate_weights: list[float] = field(default_factory=lambda: [500.0, 0.2])
    """S diagonal on input differences (the first against the last applied input)."""
    collision_slack_linear: float = 1.0e4
    """Linear penalty on the per-vehicle collision slack (ellipse-norm units)."""
    collision_slack_quadratic: float = 1.0e5
    """Quadratic penalty on the per-vehicle collision slack."""
    safety_slack_linear: float = 50.0
    """Linear penalty on the per-stage safety-region slack (cheaper: entered only if necessary)."""
    safety_slack_quadratic: float = 500.0
    """Quadratic penalty on the safety-region slack."""
    slack_price_scale: float = 1.0
    """Common factor on the four slack prices above [dimensionless], in (0, 1]: the QP uses
    scale x collision_slack_linear, ... , scale x safety_slack_quadratic. 1 keeps the listed prices; below 1
    both soft constraints get cheaper against the tracking cost, so the planner enters the safety region and
    keeps collision slack sooner (conf/planner/paper_operating_point.yaml: the paper's LTV-MPC row)."""
    n_ego_circles: int = 2
    """Circles covering the ego (>= 2)."""
    safety_margin_longitudinal_m: float = 8.0
    """Safety-region semi-major axis minus the collision ellipse's [m]."""
    safety_margin_lateral_m: float = 0.3
    """Safety-region semi-minor axis minus the collision ellipse's [m]."""

    def __post_init__(self) -> None:
        from srmpc.mpc.solvers import available_solvers

        check_fields(
            self, horizon_steps=at_least(2), solver=TEXT, max_vehicles=at_least(SLOT_COUNT),
            state_weights=Vector(NON_NEGATIVE, length=4), input_weights=Vector(NON_NEGATIVE, length=2),
            input_rate_weights=Vector(NON_NEGATIVE, length=2), collision_slack_linear=NON_NEGATIVE,
            collision_slack_quadratic=NON_NEGATIVE, safety_slack_linear=NON_NEGATIVE,
            safety_slack_quadratic=NON_NEGATIVE, slack_price_scale=Interval(0.0, 1.0, low_open=True),
            n_ego_circles=at_least(2),
            safety_margin_longitudinal_m=NON_NEGATIVE, safety_margin_lateral_m=NON_NEGATIVE,
        )
        if self.solver not in available_solvers():
            raise ValueError(f"solver={self.solver!r}: unknown QP solver; available: {', '.join(available_solvers())}")


@dataclass
class SrmpcConfig(SrmpcSettings):
    """SRMPC: which policy proposes the linearization reference, and the variant (``conf/srmpc/``).

    ``selection``, ``prediction`` and ``relinearizations`` are documented in
    ``srmpc.controllers.srmpc.SrmpcSettings``; the planner settings are ``planner``'s, shared with LTV-MPC.
    """

    policy: PolicyName = PolicyName.ppo_lsi
    """Whose deterministic actor is rolled out: ppo_lsi (the paper) or ppo."""
    policy_path: str | None = None
    """Its policy.pt; null means results/training/<policy>/policy.pt."""
    variant: str = "paper"
    """Name of the variant, used in run names and tables (the file name in conf/srmpc/)."""

    def __post_init__(self) -> None:
        check_fields(self, relinearizations=Interval(0, MAX_RELINEARIZATIONS), policy_path=TEXT, variant=TEXT)
        super().__post_init__()


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

    controller: ControllerName = ControllerName.srmpc
    """Which controller drives the ego."""
    simulator: SimulatorName = SimulatorName.twin
    """Where the episodes run. Episode i is reset with seed + i on either; the twin's draw for a seed
    differs from highway-env's (same distributions, own random streams)."""
    episodes: int = 1000
    """Number of episodes (paper: 1000 per traffic level)."""
    seed: int = 0
    """Episode i is reset with seed + i."""
    policy_path: str | None = None
    """policy.pt of the ppo / ppo_lsi controllers; null means results/training/<controller>/policy.pt."""
    output_dir: str | None = None
    """Where episodes.csv and summary.json go; null means Hydra's run directory. Rerunning into a
    directory that holds a partial run of the same config resumes it."""
    workers: int = 0
    """Processes that run the episodes (episode i still from seed + i, so the episodes do not depend on
    it): 0 means one per CPU core this process may use, 1 runs them in this process."""

    def __post_init__(self) -> None:
        check_fields(self, episodes=at_least(1), seed=NON_NEGATIVE, policy_path=TEXT, output_dir=TEXT,
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
    scenario: ScenarioParameters = field(default_factory=ScenarioParameters)
    agent: AgentConfig = field(default_factory=AgentConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    srmpc: SrmpcConfig = field(default_factory=SrmpcConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


def register_schema() -> None:
    """Store the schema in Hydra's ConfigStore (idempotent)."""
    ConfigStore.instance().store(name="config_schema", node=Config)
