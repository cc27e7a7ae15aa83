"""Every leaf of the composed schema refuses bad values at composition, naming its full key.

The leaves are found by walking the composed config, so a field added later is covered without a
test change; a leaf whose dataclass declares no check (``srmpc.value_checks.check_fields``)
fails :func:`test_every_leaf_declares_what_it_accepts`. Each leaf gets bad values of its kind (wrong
type, null, NaN, +-inf, empty strings, wrong list lengths, the values just outside its declared range)
and, through hypothesis, random values outside that range. The bulk goes through Hydra's override
parser and ``OmegaConf.update`` on one composed config (what ``compose_config`` does, without
re-reading ``conf/`` each time); :func:`test_compose_config_refuses_a_sample` sends a sample through
``compose_config`` itself.
"""

from __future__ import annotations

import copy
import enum
import math
import types
import typing
from dataclasses import dataclass
from typing import Any, Union

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from srmpc.config.compose import ConfigError, compose_config, describe_config_error, to_objects
from srmpc.value_checks import Interval, Text, Vector, declared_checks

BASE = compose_config([])  # builds every schema dataclass once, which records their declared checks


@dataclass(frozen=True)
class Leaf:
    key: str
    """Full dotted key, e.g. ``agent.actor_lr``."""
    owner: type
    """The dataclass the field belongs to."""
    name: str
    hint: Any
    """The field's annotation without ``None``."""
    optional: bool

    @property
    def check(self):
        return declared_checks(self.owner).get(self.name)

    @property
    def integer(self) -> bool:
        hint = typing.get_args(self.hint)[0] if typing.get_origin(self.hint) is list else self.hint
        return hint is int


def schema_leaves(node: DictConfig, prefix: str = "") -> list[Leaf]:
    owner = OmegaConf.get_type(node)
    hints = typing.get_type_hints(owner)
    leaves = []
    for name in node:
        child = node._get_node(name)
        if isinstance(child, DictConfig):
            leaves += schema_leaves(child, f"{prefix}{name}.")
            continue
        hint = hints[name]
        args = typing.get_args(hint)
        optional = typing.get_origin(hint) in (Union, types.UnionType) and type(None) in args
        if optional:
            hint = next(a for a in args if a is not type(None))
        leaves.append(Leaf(f"{prefix}{name}", owner, name, hint, optional))
    return leaves


LEAVES = schema_leaves(BASE)
IDS = [leaf.key for leaf in LEAVES]
PARSER = OverridesParser.create()


def render(value: Any) -> str:
    """``value`` as Hydra override text."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"
    if isinstance(value, list):
        return "[" + ",".join(render(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{render(v)}" for k, v in value.items()) + "}"
    raise TypeError(value)


def apply_override(key: str, value: Any) -> None:
    """Compose's path for one ``key=value`` override, on a copy of the composed config: parse, update, validate."""
    cfg = copy.deepcopy(BASE)
    override = PARSER.parse_overrides([f"{key}={render(value)}"])[0]
    try:
        OmegaConf.update(cfg, override.key_or_group, override.value(), merge=True)
    except OmegaConfBaseException as error:
        raise ConfigError(describe_config_error(error)) from error
    to_objects(cfg)


def assert_refused(leaf: Leaf, value: Any, via_compose: bool = False) -> None:
    with pytest.raises(ConfigError) as caught:
        if via_compose:
            compose_config([f"{leaf.key}={render(value)}"])
        else:
            apply_override(leaf.key, value)
    message = str(caught.value)
    assert leaf.key in message, f"{leaf.key}={render(value)}: message does not name the key: {message}"
    assert "\n" not in message


def outside(interval: Interval, integer: bool) -> list[float]:
    """The values just outside ``interval``: an open end itself, one step beyond a closed end."""
    values = []
    for end, is_open, direction in ((interval.low, interval.low_open, -1), (interval.high, interval.high_open, 1)):
        if math.isinf(end):
            continue
        if is_open:
            values.append(int(end) if integer and float(end).is_integer() else end)
        elif integer:
            values.append(math.floor(end) - 1 if direction < 0 else math.ceil(end) + 1)
        else:
            values += [math.nextafter(end, direction * math.inf), end + direction]
    return values


def bad_values(leaf: Leaf) -> list[Any]:
    """Values of every kind that ``leaf`` must refuse."""
    values: list[Any] = [[1, 2], {"a": 1}]
    if not leaf.optional:
        values.append(None)
    check = leaf.check
    if leaf.hint is bool:
        return values + ["maybe", 0.5]
    if isinstance(leaf.hint, type) and issubclass(leaf.hint, enum.Enum):
        return values + ["no_such_option", 0.5]
    if isinstance(check, Text):
        return [[1, 2], {"a": 1}, "", "   "] + ([] if leaf.optional else [None])
    if isinstance(check, Vector):
        values = ["abc", {"a": 1}] + ([] if leaf.optional else [None])
        good = list(BASE_VALUES[leaf.key])
        size = check.length if check.length is not None else max(check.min_length, 1)
        item = good[0] if good else 1
        values.append([item] * (size + 1) if check.length is not None else [])
        if check.length is not None and size > 0:
            values.append([item] * (size - 1))
        bad_items = ["abc", math.nan, math.inf, -math.inf] + outside(check.each, leaf.integer)
        if leaf.integer:
            bad_items.append(1.5)
        for bad in bad_items:
            values.append([bad] + [item] * (size - 1))
        return values
    assert isinstance(check, Interval), f"{leaf.key}: no declared check"
    values += ["abc", True, math.nan, math.inf, -math.inf] + outside(check, leaf.integer)
    if leaf.integer:
        values.append(1.5)
    return values


BASE_VALUES = {leaf.key: OmegaConf.select(BASE, leaf.key) for leaf in LEAVES}


def test_every_leaf_declares_what_it_accepts():
    kinds = {}
    for leaf in LEAVES:
        if leaf.hint is bool or (isinstance(leaf.hint, type) and issubclass(leaf.hint, enum.Enum)):
            kinds[leaf.key] = "typed"  # OmegaConf refuses anything but its values
            continue
        assert leaf.check is not None, (
            f"{leaf.key}: {leaf.owner.__name__}.__post_init__ declares no check for {leaf.name!r} "
            "(srmpc.value_checks.check_fields)")
        kinds[leaf.key] = type(leaf.check).__name__
    assert len(LEAVES) >= 90 and {"agent.actor_lr", "planner.state_weights", "tracking.uri"} <= set(kinds)


def test_defaults_and_edge_values_the_runs_use_stay_valid():
    """Accepted, and kept as given: the composed config and its typed objects hold the override's value."""
    for override in ["agent.cost_gamma=0", "agent.multiplier_lr_final=null", "agent.multiplier_max_grad_norm=null",
                     "agent.seed=0", "evaluation.seed=0", "agent.entropy_coef=0", "agent.cost_threshold=0",
                     "scenario.vehicles_behind_ego=0", "controller.srmpc.relinearizations=0", "agent.gamma=1",
                     "agent.multiplier_lr_final=1e-6", "agent.multiplier_max_grad_norm=3", "planner.max_vehicles=6",
                     "scenario.safety_index.edge_d_min_m=0", "scenario.reward.speed_weight=1"]:
        parsed = PARSER.parse_overrides([override])[0]
        key, value = parsed.key_or_group, parsed.value()
        cfg = compose_config([override])
        typed = to_objects(cfg)
        for name in key.split("."):
            typed = getattr(typed, name)
        assert OmegaConf.select(cfg, key) == value and typed == value, (override, OmegaConf.select(cfg, key), typed)


@pytest.mark.parametrize("leaf", LEAVES, ids=IDS)
def test_each_leaf_refuses_bad_values_of_its_kind(leaf):
    for value in bad_values(leaf):
        assert_refused(leaf, value)


NUMERIC = [leaf for leaf in LEAVES if isinstance(leaf.check, Interval | Vector)]


def beyond(interval: Interval, integer: bool) -> st.SearchStrategy:
    """Random numbers outside ``interval`` (or none, when it is unbounded)."""
    options = []
    if math.isfinite(interval.low):
        if integer:
            options.append(st.integers(max_value=math.ceil(interval.low) - (0 if interval.low_open else 1),
                                       min_value=-10**12))
        else:
            options.append(st.floats(max_value=interval.low, exclude_max=not interval.low_open, min_value=-1e12))
    if math.isfinite(interval.high):
        if integer:
            options.append(st.integers(min_value=math.floor(interval.high) + (0 if interval.high_open else 1),
                                       max_value=10**12))
        else:
            options.append(st.floats(min_value=interval.high, exclude_min=not interval.high_open, max_value=1e12))
    if not integer:
        options.append(st.sampled_from([math.nan, math.inf, -math.inf]))
    return st.one_of(options) if options else st.nothing()


@pytest.mark.parametrize("leaf", NUMERIC, ids=lambda leaf: leaf.key)
@settings(max_examples=15, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_each_number_outside_its_range_is_refused(leaf, data):
    if isinstance(leaf.check, Interval):
        assert_refused(leaf, data.draw(beyond(leaf.check, leaf.integer)))
    else:
        good = list(BASE_VALUES[leaf.key]) or [1]
        position = data.draw(st.integers(0, len(good) - 1))
        good[position] = data.draw(beyond(leaf.check.each, leaf.integer))
        assert_refused(leaf, good)


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_compose_config_refuses_a_sample(data):
    leaf = data.draw(st.sampled_from(LEAVES))
    assert_refused(leaf, data.draw(st.sampled_from(bad_values(leaf))), via_compose=True)
