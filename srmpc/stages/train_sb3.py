"""``stage=train_sb3``: Stable-Baselines3's PPO with ``agent``'s hyperparameters (srmpc.sb3_ppo), tracked in MLflow.

The output directory is chosen and claimed as ``stage=train``'s (``srmpc.stages.train``): default
``results/training/<agent.name>/seed_<agent.seed>``; its ``config.yaml`` is the agent and scenario config plus
``implementation: stable-baselines3==<version>``. Files: ``last.zip`` + ``last_state.pt`` (checkpoint; a rerun
resumes from it), ``policy.pt``, ``metrics.csv`` (``stage=train``'s columns) and ``summary.json``.
"""

from __future__ import annotations

import json

from srmpc.agents.checkpoint import POLICY_NAME
from srmpc.agents.hyperparameters import TrainTask
from srmpc.agents.report import read_metrics, summarize_training
from srmpc.config.compose import ConfigError
from srmpc.config.schema import Config
from srmpc.output_folder import CONFIG_NAME, SUMMARY_NAME, atomic_write_text
from srmpc.stages.train import claim_training_dir, training_dir, training_identity_yaml
from srmpc.tracking import Run


def run_sb3_training(config: Config, cfg_container: dict, run: Run) -> dict:
    """Train (or resume) SB3's PPO into ``training_dir(config)``; returns the summary written to summary.json."""
    from srmpc.sb3_ppo.training import IMPLEMENTATION, train_sb3_ppo

    hp = config.agent
    if hp.constrained:
        raise ConfigError(f"agent.constrained={hp.constrained}: stage=train_sb3 trains plain PPO (use agent=ppo)")
    if hp.task is not TrainTask.twin_highway:
        raise ConfigError(f"agent.task={hp.task.value}: stage=train_sb3 trains on the twin only (twin_highway)")
    output_dir = training_dir(config)
    identity = training_identity_yaml(cfg_container) + f"implementation: {IMPLEMENTATION}\n"
    claim_training_dir(output_dir, identity)
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(output_dir / CONFIG_NAME, identity)
    except OSError as error:
        raise ConfigError(f"agent.output_dir={output_dir}: cannot write there ({error.strerror or error})") from error
    run.set_tags({"implementation": IMPLEMENTATION})
    metrics_csv = train_sb3_ppo(config.scenario, hp, output_dir, run)
    summary = summarize_training(read_metrics(metrics_csv))
    summary["name"] = hp.name
    summary["implementation"] = IMPLEMENTATION
    atomic_write_text(output_dir / SUMMARY_NAME, json.dumps(summary, indent=2) + "\n")
    run.log_metrics({f"final/{k}": v for k, v in summary.items() if isinstance(v, int | float)})
    for name in (POLICY_NAME, metrics_csv.name, SUMMARY_NAME):
        run.log_artifact(output_dir / name)
    return summary
