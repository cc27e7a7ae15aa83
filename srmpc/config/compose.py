"""Compose ``conf/`` outside ``@hydra.main`` (tests, DVC stages) and turn config errors into one line."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.errors import HydraException, MissingConfigException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from srmpc.config.schema import register_schema

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
        return f"{key}: {message}" if key else message
    return str(error).splitlines()[0]


def compose_config(overrides: Sequence[str] = (), config_name: str = "config") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides``; raise :class:`ConfigError` on any problem."""
    register_schema()
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=list(overrides))
    except (HydraException, OmegaConfBaseException) as error:
        raise ConfigError(describe_config_error(error)) from error
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
