"""``python -m srmpc [overrides]``: the Hydra entry point.

Examples::

    python -m srmpc +experiment=smoke
    python -m srmpc +experiment=dense_traffic evaluation.episodes=100
    python -m srmpc +experiment=table/srmpc scenario=dense   # a published cell: results/evaluation/table/srmpc_dense
    python -m srmpc controller=nmpc controller.initial_guess=rollout
    python -m srmpc --cfg job              # print the composed config
    python -m srmpc stage=train agent=ppo_lsi   # train PPO-L-SI (agent=ppo: the baseline)
    python -m srmpc stage=train_sb3 agent=ppo agent.name=ppo_sb3   # Stable-Baselines3's PPO, same settings

Config errors (wrong type, unknown key, invalid choice, invalid value) exit with status 2 and one
line naming the key and the value (an output directory that cannot be created included), and so does
a run whose output directory another run is using (srmpc.output_lock: it names the holder's pid) or
whose ``tracking.uri`` cannot take a run: an HTTP server that does not answer within 5 s, a SQLite path
that is not a database (srmpc.tracking.check_tracking_store); any other
file that cannot be read or written (a corrupted policy.pt) exits with status 1 and one line naming
the path. SIGTERM ends the run cleanly: the MLflow run is marked FAILED and finished episodes
(evaluation) or the last completed iteration (training) stay on disk for a resume; after a SIGKILL the
next start of a run of the same name marks the dead process's run FAILED (srmpc.tracking).
"""

from __future__ import annotations

import json
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from srmpc.config.compose import ConfigError, compose_config, recorded_yaml, to_objects, with_experiment_name
from srmpc.config.schema import Config, Stage, controller_label, register_schema
from srmpc.errors import FileFault, JobFailed, describe_file_fault
from srmpc.numerics import SUMMARY_KEY, environment_record, mlflow_tags
from srmpc.output_folder import SUMMARY_NAME, atomic_write_text
from srmpc.output_lock import OutputDirectoryBusy, OutputDirectoryUnwritable, exclusive_output_dir
from srmpc.tracking import TrackingStoreUnusable, check_tracking_store, run_name, tracked_run

EXIT_CONFIG_ERROR = 2
EXIT_RUN_ERROR = 1


def _fail(message: str) -> None:
    print(f"srmpc: config error: {message}", file=sys.stderr)
    sys.exit(EXIT_CONFIG_ERROR)


def _refuse(error: Exception) -> None:
    """A run that cannot start (another run's output directory, a tracking server that does not answer)."""
    print(f"srmpc: error: {error}", file=sys.stderr)
    sys.exit(EXIT_CONFIG_ERROR)


def _raise_on_sigterm(signum, frame) -> None:
    raise SystemExit(128 + signum)


def stage_output_dir(config: Config, hydra_dir: Path) -> tuple[Path, str]:
    """(the directory the stage writes its results into, the config key that names it)."""
    if config.stage in (Stage.train, Stage.train_sb3):
        from srmpc.stages.train import training_dir

        return training_dir(config), "agent.output_dir"
    return (Path(config.evaluation.output_dir) if config.evaluation.output_dir else hydra_dir), "evaluation.output_dir"


def _shown_path(path: Path) -> str:
    """``path`` relative to the working directory (the repository root) when inside it, else absolute."""
    resolved = path.resolve()
    return str(resolved.relative_to(Path.cwd())) if resolved.is_relative_to(Path.cwd()) else str(resolved)


def tracked_run_name(config: Config, overrides: Sequence[str] = ()) -> str:
    """The run's MLflow name: its identity (``<experiment>_<traffic>``, its folder's name, or its stage, method and
    traffic), then the command-line ``overrides`` beyond it (srmpc.tracking.run_name)."""
    if config.stage is Stage.train_sb3:
        base, said = f"train-{config.agent.name}-sb3-{config.scenario.traffic}", ("agent", "agent.name")
    elif config.stage is Stage.train:
        base = f"train-{config.agent.name}-{config.agent.task.value}-{config.scenario.traffic}"
        said = ("agent", "agent.name", "agent.task")
    elif config.experiment:
        base, said = f"{config.experiment}_{config.scenario.traffic}", ()
    else:
        base = f"{config.stage.value}-{controller_label(config.controller)}-{config.scenario.traffic}"
        said = ("controller",)
    return run_name(base, overrides, said)


def logged_params(cfg: DictConfig) -> dict:
    """The composed config as its MLflow params' tree: resolved, every Enum spelled as the config files spell it
    (``controller.name: ltv_mpc``, not ``ControllerName.ltv_mpc``), so the params are the config's YAML values."""
    return OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)


def run(cfg: DictConfig, output_dir: Path, overrides: Sequence[str] = ()) -> dict:
    """Run the composed config's stage; returns the stage's summary. The stage's output directory is
    this process's alone for the run (srmpc.output_lock): a second run into it is refused before the
    MLflow run starts. ``overrides``: the command line's (Hydra's task overrides), which the run's name carries
    beyond its experiment (:func:`tracked_run_name`)."""
    config: Config = to_objects(cfg)
    config_yaml = recorded_yaml(cfg)
    tracking = config.tracking
    run_name = tracked_run_name(config, overrides)
    from srmpc.fanout import settings_from_environment
    from srmpc.sweep import in_multirun, prepare_tracking_store

    fanout = settings_from_environment() if config.stage is Stage.evaluate else None  # SRMPC_FANOUT: one line

    # A sweep's jobs, or trainings side by side (pipelines/train_runs.py), start together: the first
    # creates the MLflow store (and, in a sweep, the experiment) under a lock; two creators would collide.
    if tracking.enabled:
        check_tracking_store(tracking.uri)  # before the output directory is touched
    prepare_tracking_store(tracking, ensure_experiment=in_multirun())
    stage_dir, stage_dir_key = stage_output_dir(config, output_dir)
    with exclusive_output_dir(stage_dir, stage_dir_key), tracked_run(
        tracking.enabled, tracking.uri, tracking.artifact_location, tracking.experiment_name, run_name,
        logged_params(cfg), config_yaml,
    ) as active_run:
        active_run.set_tags({"output_dir": _shown_path(stage_dir)})  # pipelines/mlflow_import.py keys runs by it
        active_run.set_tags(mlflow_tags(environment_record()))
        if config.stage is Stage.evaluate:
            from srmpc.stages.evaluate import run_evaluation

            summary = run_evaluation(config, config_yaml, stage_dir, active_run, fanout=fanout)
        elif config.stage is Stage.train:
            from srmpc.stages.train import run_training

            summary = run_training(config, OmegaConf.to_container(cfg, resolve=True), active_run)
        elif config.stage is Stage.train_sb3:
            from srmpc.stages.train_sb3 import run_sb3_training

            summary = run_sb3_training(config, OmegaConf.to_container(cfg, resolve=True), active_run)
        else:
            raise ConfigError(f"stage={config.stage.value}: no runner")
        return record_environment(summary, stage_dir / SUMMARY_NAME, active_run)


def record_environment(summary: dict, summary_path: Path, active_run) -> dict:
    """``summary`` with the process's numeric environment (srmpc.numerics: the pin, the CPU, the libraries'
    versions) under its own key, written back to the stage's ``summary.json`` and logged again. The stage
    wrote the file without it: the environment describes the machine, not the result, and comparisons of
    results (golden hashes, pipelines.reproduction_check) leave the key out."""
    record = environment_record()
    summary = {**summary, SUMMARY_KEY: record}
    atomic_write_text(summary_path, json.dumps(summary, indent=2) + "\n")
    active_run.log_artifact(summary_path)
    return summary


register_schema()


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    signal.signal(signal.SIGTERM, _raise_on_sigterm)
    try:
        with_experiment_name(cfg, HydraConfig.get().runtime.choices.get("experiment"))
        summary = run(cfg, Path(HydraConfig.get().runtime.output_dir), HydraConfig.get().overrides.task)
    except (ConfigError, OutputDirectoryUnwritable) as error:
        _fail(str(error))
    except (OutputDirectoryBusy, TrackingStoreUnusable) as error:  # refused before anything is written
        _refuse(error)
    except (FileFault, OSError) as error:  # an unreadable policy.pt, an unwritable output directory
        print(f"srmpc: error: {describe_file_fault(error)}", file=sys.stderr)
        sys.exit(EXIT_RUN_ERROR)
    except JobFailed as error:  # SRMPC_FANOUT: a shard's job failed (its log named)
        print(f"srmpc: error: {error}", file=sys.stderr)
        sys.exit(EXIT_RUN_ERROR)
    from srmpc.result_table import print_result

    print_result(cfg, summary, Path(HydraConfig.get().runtime.output_dir))


def _plain_overrides(args: list[str]) -> list[str] | None:
    """The overrides to validate up front, or None when Hydra flags make that Hydra's job."""
    if any(arg.startswith("-") for arg in args):
        return None
    return [arg for arg in args if not arg.lstrip("+~").startswith("hydra")]


def main() -> None:
    overrides = _plain_overrides(sys.argv[1:])
    if overrides is not None:
        try:
            tracking = compose_config(overrides).tracking
        except ConfigError as error:
            _fail(str(error))
        if tracking.enabled:  # before Hydra creates its run directory
            try:
                check_tracking_store(tracking.uri)
            except TrackingStoreUnusable as error:
                _refuse(error)
    from srmpc.sweep import sweep_jobs

    for number, job in enumerate(sweep_jobs(sys.argv[1:])):  # -m: every job's config, before any job starts
        try:
            compose_config(job)
        except ConfigError as error:
            _fail(f"sweep job #{number} ({' '.join(job)}): {error}")
    hydra_main()


if __name__ == "__main__":
    main()
