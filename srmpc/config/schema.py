"""Structured-config schema of ``conf/``. Registered in Hydra's ConfigStore as ``config_schema``.

A wrong type, an unknown key or a bad enum value in any YAML file or override is rejected at
composition, naming the key. The entry points convert these nodes into the plain dataclasses
that library code takes (``OmegaConf.to_object``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from hydra.core.config_store import ConfigStore

from srmpc.scenario.parameters import ScenarioParameters


class Stage(Enum):
    """What ``python -m srmpc`` does."""

    evaluate = "evaluate"
    """Run closed-loop evaluation episodes of ``evaluation.controller``."""


class ControllerName(Enum):
    """Controllers that evaluation can run."""

    lane_keeping = "lane_keeping"
    """IDM + lane-centre steering baseline (srmpc.controllers.lane_keeping)."""


@dataclass
class AgentConfig:
    """PPO / PPO-L-SI hyperparameters (consumed by the training stage)."""

    name: str = "ppo_lsi"
    """Run label: "ppo" or "ppo_lsi"."""
    constrained: bool = True
    """PPO-L-SI (True): cost critic, SI cost and state-dependent multiplier lambda(s). PPO: False."""
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    """Hidden layer widths of actor, critics and multiplier network (paper: small for real time)."""
    gamma: float = 0.99
    """Reward discount factor."""
    cost_gamma: float = 0.99
    """Cost discount factor gamma_c."""
    gae_lambda: float = 0.95
    """GAE lambda for both advantages."""
    clip_epsilon: float = 0.2
    """PPO ratio clip."""
    entropy_coef: float = 0.0
    """Entropy bonus weight."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 1e-3
    """Adam learning rate of both critics."""
    multiplier_lr: float = 1e-4
    """Adam learning rate of lambda(s) (slower schedule than the actor)."""
    multiplier_update_every: int = 5
    """Iterations between multiplier updates."""
    lambda_max: float = 50.0
    """Cap of lambda(s): the paper's 'infinite' multiplier threshold."""
    total_frames: int = 20_000_000
    """Environment steps of training."""
    frames_per_batch: int = 32_768
    """Environment steps collected per iteration."""
    minibatch_size: int = 4096
    """SGD minibatch size."""
    epochs: int = 10
    """SGD passes over each batch."""
    seed: int = 0
    """Training seed."""


@dataclass
class PlannerConfig:
    """LTV-MPC settings (consumed by the planner)."""

    horizon_steps: int = 25
    """Prediction horizon N (25 x 0.2 s = 5 s)."""
    solver: str = "piqp"
    """QP solver: one of the names srmpc.mpc lists (checked when the planner is built)."""


@dataclass
class EvaluationConfig:
    """Closed-loop evaluation."""

    controller: ControllerName = ControllerName.lane_keeping
    """Which controller drives the ego."""
    episodes: int = 1000
    """Number of episodes (paper: 1000 per traffic level)."""
    seed: int = 0
    """Episode i is reset with seed + i."""
    output_dir: str | None = None
    """Where episodes.csv and summary.json go; null means Hydra's run directory. Rerunning into a
    directory that holds a partial run of the same config resumes it."""


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


@dataclass
class Config:
    """Root of the composed configuration."""

    stage: Stage = Stage.evaluate
    scenario: ScenarioParameters = field(default_factory=ScenarioParameters)
    agent: AgentConfig = field(default_factory=AgentConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    evaluation: EvaluationConfig = field(default_factory=EvaluationConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)


def register_schema() -> None:
    """Store the schema in Hydra's ConfigStore (idempotent)."""
    ConfigStore.instance().store(name="config_schema", node=Config)
