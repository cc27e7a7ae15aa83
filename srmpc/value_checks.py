"""What each field of the schema accepts, checked in the dataclasses' ``__post_init__``.

Every field of a schema dataclass that is not a bool, an enum or a nested dataclass declares its
values with :func:`check_fields`: an :class:`Interval` for a number (always finite), a :class:`Vector`
for a list of numbers, :data:`TEXT` for a string. Whether a number must be an integer and whether it
may be null comes from the field's annotation (``int``, ``float | None``, ``list[int]``). A bad value
raises ``ValueError("<field>=<value>: <expectation>")``; ``srmpc.config.compose`` puts the path in
front, so the CLI names the full key (``agent.actor_lr=nan: must be a finite number > 0``).

The declarations are kept per class (:func:`declared_checks`), so a test can walk every leaf of the
composed schema and try values outside what it declares.
"""

from __future__ import annotations

import math
import numbers
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any, Union

__all__ = ["Interval", "Vector", "Text", "TEXT", "POSITIVE", "NON_NEGATIVE", "NON_POSITIVE", "FINITE",
           "UNIT_INTERVAL", "DISCOUNT", "at_least", "check_fields", "declared_checks"]


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


@dataclass(frozen=True)
class Interval:
    """A finite number in [low, high]; either end may be open or absent (infinite)."""

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    def contains(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return math.isfinite(value) and above and below

    def describe(self, integer: bool) -> str:
        kind = "an integer" if integer else "a finite number"
        low, high = math.isfinite(self.low), math.isfinite(self.high)
        if low and high:
            left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
            return f"{kind} in {left}{_number(self.low)}, {_number(self.high)}{right}"
        if low:
            return f"{kind} {'>' if self.low_open else '>='} {_number(self.low)}"
        if high:
            return f"{kind} {'<' if self.high_open else '<='} {_number(self.high)}"
        return kind

    def problem(self, value: Any, integer: bool) -> str | None:
        """None if ``value`` is acceptable, else what it must be."""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return f"must be {self.describe(integer)}"
        if integer and not isinstance(value, numbers.Integral):
            return f"must be {self.describe(integer)}"
        if not self.contains(float(value)):
            return f"must be {self.describe(integer)}"
        return None


@dataclass(frozen=True)
class Vector:
    """A list of numbers, each in ``each``: exactly ``length`` of them, or at least ``min_length``."""

    each: Interval
    length: int | None = None
    min_length: int = 0

    def describe(self, integer: bool) -> str:
        kind = "integers" if integer else "finite numbers"
        if self.length is not None:
            size = f"a list of {self.length}"
        else:
            size = "a non-empty list of" if self.min_length == 1 else f"a list of at least {self.min_length}"
        each = self.each.describe(integer).removeprefix("an integer").removeprefix("a finite number").strip()
        return f"{size} {kind}" + (f", each {each}" if each else "")

    def problem(self, value: Any, integer: bool) -> str | None:
        expectation = f"must be {self.describe(integer)}"
        if isinstance(value, str | bytes) or not isinstance(value, Sequence):
            return expectation
        if (self.length is not None and len(value) != self.length) or len(value) < self.min_length:
            return expectation
        if any(self.each.problem(item, integer) for item in value):
            return expectation
        return None


@dataclass(frozen=True)
class Text:
    """A string with at least one non-blank character."""

    def problem(self, value: Any, integer: bool) -> str | None:
        if not isinstance(value, str) or not value.strip():
            return "must be a non-empty string"
        return None


Check = Interval | Vector | Text

POSITIVE = Interval(low=0.0, low_open=True)
NON_NEGATIVE = Interval(low=0.0)
NON_POSITIVE = Interval(high=0.0)
FINITE = Interval()
UNIT_INTERVAL = Interval(0.0, 1.0)
"""Probabilities, weights in [0, 1], a discount that may be 0."""
DISCOUNT = Interval(0.0, 1.0, low_open=True)
"""A discount factor in (0, 1]."""
TEXT = Text()


def at_least(low: float) -> Interval:
    """[low, inf)."""
    return Interval(low=low)


_DECLARED: dict[type, dict[str, Check]] = {}


@cache
def _annotation(cls: type, name: str) -> tuple[bool, bool]:
    """(integer, optional) of field ``name``: an int (or list of ints), and whether None is allowed."""
    hint = typing.get_type_hints(cls)[name]
    args = typing.get_args(hint)
    optional = typing.get_origin(hint) in (Union, types.UnionType) and type(None) in args
    if optional:
        hint = next(a for a in args if a is not type(None))
    if typing.get_origin(hint) in (list, tuple):
        hint = typing.get_args(hint)[0]
    return hint is int, optional


def check_fields(instance: Any, **checks: Check) -> None:
    """Check each named field of the dataclass ``instance``; raise ``ValueError`` naming the first bad one."""
    cls = type(instance)
    _DECLARED.setdefault(cls, {}).update(checks)
    for name, check in checks.items():
        value = getattr(instance, name)
        integer, optional = _annotation(cls, name)
        if value is None:
            problem = None if optional else "must not be null"
        else:
            problem = check.problem(value, integer)
        if problem is not None:
            if optional and value is not None:
                problem += " or null"
            raise ValueError(f"{name}={value!r}: {problem}")


def declared_checks(cls: type) -> dict[str, Check]:
    """The checks ``cls`` declared through :func:`check_fields` (filled when an instance is first built)."""
    return dict(_DECLARED.get(cls, {}))
