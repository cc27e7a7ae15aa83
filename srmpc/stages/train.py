"""``stage=train``: train ``agent`` (PPO or PPO-L-SI) with checkpoints and resume, tracked in MLflow.

Files in the output directory (``agent.output_dir``, default
``results/training/<agent.name>/seed_<agent.seed>``):
``config.yaml`` (agent + scenario config the run belongs to), ``last.pt`` (checkpoint), ``policy.pt``
(the actor alone), ``metrics.csv`` (one row per iteration) and ``summary.json`` (the last 5% of
training, written at the end).

A run writes only into a directory it owns: one without training results, or one whose
``config.yaml`` has the same agent and scenario config (``training_identity_yaml``, which leaves out
:data:`RESUMABLE_OVERRIDES`); there it resumes from ``last.pt`` or, without one, starts over. A
directory with another config, or with results but no ``config.yaml``, is refused before anything is
written (:func:`claim_training_dir`), so committed results are never overwritten by a smoke run.
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml
from omegaconf import OmegaConf

from srmpc.agents.checkpoint import CHECKPOINT_NAME, POLICY_NAME
from srmpc.agents.hyperparameters import TrainTask
from srmpc.agents.report import read_metrics, summarize_training
from srmpc.config.compose import ConfigError, recorded_config
from srmpc.config.schema import Config
from srmpc.output_folder import CONFIG_NAME, SUMMARY_NAME, atomic_write_text
from srmpc.tracking import Run

RESUMABLE_OVERRIDES = ("total_frames", "checkpoint_every", "output_dir", "num_threads", "sim_threads")
"""Agent fields that may change between an interrupted run and its resume."""
RESULT_NAMES = (CHECKPOINT_NAME, POLICY_NAME, "metrics.csv", SUMMARY_NAME)  # metrics.csv: trainer.METRICS_CSV
"""Files of a training run besides its config.yaml."""


def training_dir(config: Config) -> Path:
    """``agent.output_dir``; unset, ``results/training/<agent.name>/seed_<agent.seed>``, or in a sweep
    (``-m``) the Hydra job's own directory, so the jobs of a seed sweep neither share one nor touch
    ``results/``."""
    from srmpc.sweep import in_multirun, job_output_dir

    if config.agent.output_dir:
        return Path(config.agent.output_dir)
    if in_multirun():
        return job_output_dir()
    return Path("results/training") / config.agent.name / f"seed_{config.agent.seed}"

def make_training_env(config: Config):
    """The batched TorchRL env of ``agent.task``."""
    hp = config.agent
    if hp.task is TrainTask.toy:
        from srmpc.agents.toy_env import ToyConstrainedEnv

        return ToyConstrainedEnv(hp.num_envs, seed=hp.seed)
    try:
        from srmpc.sim.torchrl_env import TwinHighwayEnv
    except ImportError as error:
        raise ConfigError(f"agent.task={hp.task.value}: the batched simulator is not available ({error})") from error
    return TwinHighwayEnv(config.scenario, num_envs=hp.num_envs, seed=hp.seed, threads=hp.sim_threads)


def training_identity_yaml(cfg_container: dict) -> str:
    """The config.yaml of a training run: agent (without :data:`RESUMABLE_OVERRIDES`) and scenario."""
    agent = {k: v for k, v in cfg_container["agent"].items() if k not in RESUMABLE_OVERRIDES}
    return OmegaConf.to_yaml(recorded_config({"agent": agent, "scenario": cfg_container["scenario"]}))


def claim_training_dir(output_dir: Path, identity: str) -> None:
    """Refuse ``output_dir`` unless it holds no training results or this config's; reads, never writes."""
    config_path = output_dir / CONFIG_NAME
    try:
        if config_path.is_file():
            if yaml.safe_load(config_path.read_text()) == yaml.safe_load(identity):
                return
            raise ConfigError(f"agent.output_dir={output_dir}: holds results of a different config ({config_path}); "
                              "choose another directory")
        present = [name for name in RESULT_NAMES if (output_dir / name).exists()]
    except (OSError, yaml.YAMLError) as error:
        raise ConfigError(f"agent.output_dir={output_dir}: cannot read {config_path} ({error})") from error
    if present:
        raise ConfigError(f"agent.output_dir={output_dir}: holds training results ({', '.join(present)}) without "
                          f"the {CONFIG_NAME} they belong to; choose another directory")


def run_training(config: Config, cfg_container: dict, run: Run, progress: bool = True) -> dict:
    """Train (or resume) into ``training_dir(config)``; returns the summary written to summary.json."""
    from srmpc.agents.trainer import METRICS_CSV, Trainer

    output_dir = training_dir(config)
    identity = training_identity_yaml(cfg_container)
    claim_training_dir(output_dir, identity)
    env = make_training_env(config)  # may still refuse the config: nothing is written before this
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(output_dir / CONFIG_NAME, identity)
    except OSError as error:
        env.close()
        raise ConfigError(f"agent.output_dir={output_dir}: cannot write there ({error.strerror or error})") from error
    trainer = Trainer(env, config.agent, output_dir, run, progress=progress)
    if trainer.resumed_from is not None:
        run.set_tags({"resumed_from_iteration": str(trainer.resumed_from)})
    try:
        trainer.train()
    finally:
        trainer.close()
    summary = summarize_training(read_metrics(output_dir / METRICS_CSV))
    summary["name"] = config.agent.name
    atomic_write_text(output_dir / SUMMARY_NAME, json.dumps(summary, indent=2) + "\n")
    run.log_metrics({f"final/{k}": v for k, v in summary.items() if isinstance(v, int | float)})
    for name in (POLICY_NAME, METRICS_CSV, SUMMARY_NAME):
        run.log_artifact(output_dir / name)
    return summary
