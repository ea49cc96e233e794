"""How a setting is declared: default, meaning, unit and the rule its value must keep.

Every field of a settings group is declared with :func:`setting`. The same declaration gives
the dataclass default, the check that runs when a group is built (an error names the dotted
setting, the rule and the value), the node parameter's description and range, and the line of
``arm_planner.yaml``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from numbers import Integral, Real
from typing import Any

from nehmo_core.errors import InvalidValueError, UnknownNameError

__all__ = ["Rule", "check_group", "rule_of", "setting"]


@dataclass(frozen=True)
class Rule:
    """What a setting means and which values it takes."""

    doc: str
    unit: str = ""
    ge: float | None = None  # value >= ge
    gt: float | None = None  # value > gt
    le: float | None = None  # value <= le
    lt: float | None = None  # value < lt
    choices: tuple[str, ...] = ()

    @property
    def low(self) -> float | None:
        return self.ge if self.ge is not None else self.gt

    @property
    def high(self) -> float | None:
        return self.le if self.le is not None else self.lt

    def describe(self) -> str:
        """The rule in words, e.g. ``must lie in (0, 1]``."""
        if self.choices:
            return f"one of {' | '.join(self.choices)}"
        lo = _bound("[", self.ge, "(", self.gt)
        hi = _bound("]", self.le, ")", self.lt, after=True)
        if lo and hi:
            return f"must lie in {lo}, {hi}"
        if lo:
            return f"must be {'>=' if self.ge is not None else '>'} {lo[1:]}"
        if hi:
            return f"must be {'<=' if self.le is not None else '<'} {hi[:-1]}"
        return ""


def _bound(
    closed: str, inclusive: float | None, open_: str, exclusive: float | None, after: bool = False
) -> str:
    """``[0`` / ``(0`` (a low end) or ``1]`` / ``1)`` (a high end, ``after``); '' for none."""
    for bracket, value in ((closed, inclusive), (open_, exclusive)):
        if value is not None:
            return f"{value:g}{bracket}" if after else f"{bracket}{value:g}"
    return ""


def setting(default: Any, doc: str, unit: str = "", **rule: Any) -> Any:
    """A settings field: its default, its meaning, its unit and its rule (``ge``, ``gt``,
    ``le``, ``lt`` for numbers, ``choices`` for names)."""
    return field(default=default, metadata={"rule": Rule(doc, unit, **rule)})


def rule_of(group: Any, name: str) -> Rule:
    for f in fields(group):
        if f.name == name:
            rule: Rule = f.metadata["rule"]
            return rule
    raise KeyError(name)


def check_group(group: Any, prefix: str) -> None:
    """Check every field of ``group`` against its rule; errors name ``prefix.field``."""
    for f in fields(group):
        rule: Rule = f.metadata["rule"]
        name, value, default = f"{prefix}.{f.name}", getattr(group, f.name), f.default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise InvalidValueError(name, "must be true or false", value)
        elif isinstance(default, str):
            if rule.choices and value not in rule.choices:
                raise UnknownNameError(name, value, rule.choices)
        elif isinstance(default, tuple):
            _check_numbers(name, tuple(value), rule)
        elif isinstance(default, Integral):
            if not isinstance(value, Integral) or isinstance(value, bool):  # not 2.5, NaN, True
                rule_text = rule.describe().replace("must be ", "").replace("must lie ", "")
                raise InvalidValueError(name, f"must be an int {rule_text}".rstrip(), value)
            _check_number(name, float(value), rule)
        else:
            if not isinstance(value, Real) or isinstance(value, bool) or math.isnan(value):
                raise InvalidValueError(name, "must be a number", value)
            _check_number(name, float(value), rule)


def _check_numbers(name: str, values: tuple[Any, ...], rule: Rule) -> None:
    if not values:
        raise InvalidValueError(name, "must hold at least one value", values)
    for v in values:
        if not isinstance(v, Real) or isinstance(v, bool) or math.isnan(v):
            raise InvalidValueError(name, "must hold numbers", values)
        _check_number(name, float(v), rule, shown=values)


def _check_number(name: str, v: float, rule: Rule, shown: Any = None) -> None:
    ok = (
        (rule.ge is None or v >= rule.ge)
        and (rule.gt is None or v > rule.gt)
        and (rule.le is None or v <= rule.le)
        and (rule.lt is None or v < rule.lt)
    )
    if not ok:
        raise InvalidValueError(name, rule.describe(), v if shown is None else shown)
