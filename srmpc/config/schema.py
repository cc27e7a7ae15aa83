"""Structured-config schema of ``conf/``. Registered in Hydra's ConfigStore as ``config_schema``.

A wrong type, an unknown key or a bad enum value in any YAML file or override is rejected at
composition, naming the key. The entry points convert these nodes into the plain dataclasses
that library code takes (``OmegaConf.to_object``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from hydra.core.config_store import ConfigStore

from srmpc.agents.hyperparameters import PPOHyperparameters
from srmpc.scenario.parameters import ScenarioParameters


class Stage(Enum):
    """What ``python -m srmpc`` does."""

    evaluate = "evaluate"
    """Run closed-loop evaluation episodes of ``evaluation.controller``."""
    train = "train"
    """Train ``agent`` (PPO or PPO-L-SI) on the batched simulator; resumes from its checkpoint."""


class ControllerName(Enum):
    """Controllers that evaluation can run."""

    lane_keeping = "lane_keeping"
    """IDM + lane-centre steering baseline (srmpc.controllers.lane_keeping)."""


AgentConfig = PPOHyperparameters
"""PPO / PPO-L-SI hyperparameters (srmpc.agents.hyperparameters, every field documented there)."""


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
