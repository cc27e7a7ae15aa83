"""Compose ``conf/`` outside ``@hydra.main`` (tests, DVC stages) and turn config errors into one line."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException, MissingConfigException
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from srmpc.config.schema import Stage, register_schema

CONFIG_DIR = Path(__file__).resolve().parents[2] / "conf"
"""The repository's ``conf/`` directory."""


class ConfigError(ValueError):
    """A configuration problem, with a one-line message naming the key and the bad value."""


def describe_config_error(error: BaseException) -> str:
    """One line naming the key and the bad value of a Hydra/OmegaConf composition error."""
    if isinstance(error, ConfigError):
        return str(error)
    if isinstance(error, MissingConfigException) or "Could not find" in str(error):
        text = str(error)
        missing = re.search(r"Could not find '([^']+)'", text)
        options = re.findall(r"^\t(\S+)$", text.split("Config search path")[0], flags=re.MULTILINE)
        if missing:
            group, _, choice = missing.group(1).rpartition("/")
            available = f" (available: {', '.join(options)})" if options else ""
            where = f"in group '{group}'" if group else "at the top level"
            return f"invalid choice {group + '=' if group else ''}{choice}: no option '{choice}' {where}{available}"
        return text.splitlines()[0]
    cause = error.__cause__ if isinstance(error.__cause__, OmegaConfBaseException) else error
    if isinstance(cause, OmegaConfBaseException):
        message = (getattr(cause, "msg", None) or str(cause)).splitlines()[0]
        key = getattr(cause, "full_key", None)
        if key in RENAMED:
            return f"{key}: {key} is gone; write {RENAMED[key]}"
        return f"{key}: {message}" if key else message
    return str(error).splitlines()[0]


RENAMED = {
    "evaluation.controller": "controller=<name> (lane_keeping, policy, ltv_mpc, srmpc, nmpc)",
    "evaluation.policy_path": "controller.policy_path (or controller.policy=<agent>)",
    "srmpc.policy": "controller.policy",
    "srmpc.policy_path": "controller.policy_path",
    "srmpc.variant": "nothing: the run's name is its experiment",
    "srmpc.selection": "controller.srmpc.selection",
    "srmpc.prediction": "controller.srmpc.prediction",
    "srmpc.relinearizations": "controller.srmpc.relinearizations",
    "srmpc.tracking": "controller.srmpc.tracking",
    "srmpc": "controller=srmpc controller.srmpc.<field>=<value> (a variant: +experiment=variants/<name>)",
    "policy": "controller.policy=<agent>",
}
"""Keys and groups that moved into ``controller`` (conf/controller/), each with what to write now."""
OLD_CONTROLLERS = {
    "ppo": "controller=policy controller.policy=ppo", "ppo_lsi": "controller=policy controller.policy=ppo_lsi",
    "nmpc": "controller=nmpc controller.initial_guess=shifted",
    "nmpc_constant_velocity": "controller=nmpc controller.initial_guess=constant_velocity",
    "nmpc_rollout": "controller=nmpc controller.initial_guess=rollout",
    "nmpc_best_of_two": "controller=nmpc controller.initial_guess=best_of_two",
}
"""The old ``evaluation.controller`` values with no controller of that name, and what to write now."""


def refuse_old_spellings(overrides: Sequence[str]) -> None:
    """Raise :class:`ConfigError` naming the new spelling for an override of a key or group that moved
    (:data:`RENAMED`): ``evaluation.controller=nmpc_rollout`` -> ``controller=nmpc
    controller.initial_guess=rollout``."""
    for override in overrides:
        key, _, value = override.lstrip("+~").partition("=")
        new = RENAMED.get(key)
        if new is None:
            continue
        if key == "evaluation.controller":
            new = OLD_CONTROLLERS.get(value, f"controller={value}")
        raise ConfigError(f"{override}: {key} is gone; write {new}")


def with_experiment_name(cfg: DictConfig, experiment: str | None) -> DictConfig:
    """``cfg`` named by the ``+experiment=<path>`` it was composed with (``experiment``: Hydra's choice), its run's
    identity. A published experiment, one under a question folder (conf/experiment/<question>/<name>.yaml) other
    than :data:`NOT_EVALUATIONS`, evaluates into results/evaluation/<question>/<name>_<traffic>/ unless
    ``evaluation.output_dir`` says otherwise."""
    if cfg.get("experiment") not in (None, experiment):
        raise ConfigError(f"experiment={cfg.experiment}: the run's name is its +experiment=<path>, not set by hand")
    cfg.experiment = experiment
    question = experiment.split("/")[0] if experiment and "/" in experiment else None
    if question and question not in NOT_EVALUATIONS and Stage(cfg.stage) is Stage.evaluate \
            and cfg.evaluation.output_dir is None:
        cfg.evaluation.output_dir = f"{EVALUATION_ROOT}/{experiment}_{cfg.scenario.traffic}"
    return cfg


EVALUATION_ROOT = "results/evaluation"
"""Where published experiments evaluate into (:func:`with_experiment_name`)."""
NOT_EVALUATIONS = ("training",)
"""Question folders of conf/experiment/ that hold trainings (pipelines/train_runs.py), not evaluations."""


def compose_config(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides``, named by its experiment
    (:func:`with_experiment_name`); raise :class:`ConfigError` on any problem."""
    refuse_old_spellings(overrides)
    register_schema()
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=list(overrides), return_hydra_config=True)
        experiment = cfg.hydra.runtime.choices.get("experiment")
        with open_dict(cfg):
            del cfg["hydra"]
        with_experiment_name(cfg, experiment)
    except (HydraException, OmegaConfBaseException) as error:
        raise ConfigError(describe_config_error(error)) from error
    except AssertionError as error:  # OmegaConf: an override below a node that is null (controller.srmpc.x, not srmpc)
        raise ConfigError(f"{' '.join(overrides)}: sets a key below a field that is null here (controller.srmpc.* "
                          "needs controller=srmpc)") from error
    to_objects(cfg)  # validate values now, not halfway through a run
    return cfg


def _instantiate(node: DictConfig, path: str) -> Any:
    for key in node:
        child = node._get_node(key)
        if isinstance(child, DictConfig) and dataclasses.is_dataclass(OmegaConf.get_type(child)):
            _instantiate(child, f"{path}{key}.")
    try:
        return OmegaConf.to_object(node)
    except ValueError as error:
        raise ConfigError(f"{path}{str(error).splitlines()[0]}") from error
    except OmegaConfBaseException as error:
        raise ConfigError(describe_config_error(error)) from error


def to_objects(cfg: DictConfig) -> Any:
    """The composed config as the schema's dataclasses; value errors name the full key."""
    return _instantiate(cfg, "")


def recorded_config(container: dict) -> dict:
    """The composed config (a plain container) as a run records it in its ``config.yaml``: without
    ``scenario.safety_index.rss`` and ``.kind`` where the index is the paper's, since nothing then depends on
    them (and results recorded before the RSS index existed keep their config.yaml)."""
    safety_index = (container.get("scenario") or {}).get("safety_index")
    kind = safety_index.get("kind", "paper") if isinstance(safety_index, dict) else None
    if getattr(kind, "value", kind) != "paper":
        return container
    scenario = dict(container["scenario"])
    scenario["safety_index"] = {k: v for k, v in safety_index.items() if k not in ("kind", "rss")}
    return {**container, "scenario": scenario}


def recorded_yaml(cfg: DictConfig) -> str:
    """The ``config.yaml`` text of a run of the composed ``cfg`` (resolved; see :func:`recorded_config`)."""
    return OmegaConf.to_yaml(recorded_config(OmegaConf.to_container(cfg, resolve=True)))
