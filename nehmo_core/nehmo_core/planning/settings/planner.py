"""All settings of the NeHMO planner, in groups by concern, and the named presets.

A setting is named ``group.field`` (``escape.stall_ticks``, ``hold.bound``) everywhere: in
:meth:`PlannerSettings.override`, ``--planner-setting`` on the command line, the node
parameters and ``arm_planner.yaml``. The flat names of earlier releases are refused with an
error that names the new one.
"""

from __future__ import annotations

import types
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.settings.groups import (
    FailSafeSettings,
    MarginSettings,
    OptSettings,
    SolverSettings,
)
from nehmo_core.planning.settings.limits import JointLimitSettings, SelfClearanceSettings
from nehmo_core.planning.settings.spec import Rule
from nehmo_core.planning.settings.stage_groups import (
    ActuatorSettings,
    ContactSettings,
    EscapeSettings,
    ExactGuardSettings,
    HoldSettings,
    SilentWatchSettings,
)

__all__ = ["PAPER_OPT", "PRESETS", "REMOVED", "RENAMED", "PlannerSettings", "parse_assignments"]

PAPER_OPT: Mapping[str, Any] = types.MappingProxyType(
    {
        "margins.certified": False,
        "hold.bound": 1.0,
        "exact_guard.gap": 0.0,
        "contact.clearance": 0.0,
        "actuator.enabled": False,
        "silent_watch.lookahead": 0.0,
        "self_clearance.enabled": False,
        "escape.enabled": False,
        "joint_limits.enabled": False,
        "fail_safe.deadband": 0.0,
    }
)
"""What the paper's Opt leaves out of NeHMO's defaults (the ``paper`` preset, ``nehmo_paper``):
every stage beyond the paper off and the paper's fixed margin."""

PRESETS: Mapping[str, Mapping[str, Any]] = types.MappingProxyType(
    {
        "default": {},
        "paper": PAPER_OPT,
        "ipopt": {"solver.name": "ipopt"},
        "wrapped_goal": {"opt.wrap_goal": True},
        # for arms that follow commands under acceleration limits (docs/evaluation.md)
        "real_actuators": {
            "actuator.enabled": True,
            "hold.self_check": True,
            "margins.actuators": "realistic",
        },
    }
)

RENAMED: Mapping[str, str] = types.MappingProxyType(
    {
        **{k: f"opt.{k}" for k in ("epsilon", "t_plan", "t_safe", "u_max", "d_max", "wrap_goal")},
        **{k: f"opt.{k}" for k in ("reach_margin", "deadline", "tick")},
        "certified_epsilon": "margins.certified",
        "settled_epsilon": "hold.settled_epsilon",
        "solver": "solver.name",
        "backend": "solver.backend",
        **{k: f"solver.{k}" for k in ("sqp_max_iter", "sqp_tol", "sqp_screen", "sqp_warm_hessian")},
        **{k: f"solver.{k}" for k in ("sqp_native", "ipopt_tol", "ipopt_max_iter")},
        "fail_safe_deadband": "fail_safe.deadband",
        "hold_bound": "hold.bound",
        "hold_tolerance": "hold.tolerance",
        "hold_release": "hold.release",
        "bound_release_ticks": "hold.release_ticks",
        "exact_guard": "exact_guard.gap",
        "silent_lookahead": "silent_watch.lookahead",
        "silent_clearance": "silent_watch.clearance",
        "self_clearance": "self_clearance.enabled",
        **{f"self_{k}": f"self_clearance.{k}" for k in ("influence", "safety", "gain")},
        "escape": "escape.enabled",
        **{k: f"escape.{k}" for k in ("stall_ticks", "escape_ticks", "yield_ticks")},
        **{k: f"escape.{k}" for k in ("stall_progress", "stall_margin")},
        "escape_seed": "escape.seed",
    }
)
"""The flat names of earlier releases and the dotted names that replaced them."""

REMOVED: Mapping[str, str] = types.MappingProxyType(
    {
        name: "the maximin fail-safe was removed: switched off alone it changed no row of the "
        "ablation beyond noise (docs/ablation.md); the fail-safe is the paper's"
        for name in (
            "fail_safe",
            "fail_safe_band",
            "fail_safe_slack",
            "fail_safe_harm",
            "fail_safe.kind",
            "fail_safe.band",
            "fail_safe.slack",
            "fail_safe.harm",
        )
    }
)
"""Settings that no longer exist, and why."""


@dataclass(frozen=True)
class PlannerSettings:
    """Problem Opt, its solver and fail-safe, and one group per stage beyond the paper."""

    opt: OptSettings = field(default_factory=OptSettings)
    margins: MarginSettings = field(default_factory=MarginSettings)
    solver: SolverSettings = field(default_factory=SolverSettings)
    fail_safe: FailSafeSettings = field(default_factory=FailSafeSettings)
    hold: HoldSettings = field(default_factory=HoldSettings)
    exact_guard: ExactGuardSettings = field(default_factory=ExactGuardSettings)
    contact: ContactSettings = field(default_factory=ContactSettings)
    actuator: ActuatorSettings = field(default_factory=ActuatorSettings)
    silent_watch: SilentWatchSettings = field(default_factory=SilentWatchSettings)
    self_clearance: SelfClearanceSettings = field(default_factory=SelfClearanceSettings)
    escape: EscapeSettings = field(default_factory=EscapeSettings)
    joint_limits: JointLimitSettings = field(default_factory=JointLimitSettings)

    def __post_init__(self) -> None:
        for f in fields(self):
            group = getattr(self, f.name)
            if not isinstance(group, f.default_factory):  # type: ignore[arg-type]
                raise InvalidValueError(f.name, f"must be a {f.default_factory.__name__}", group)  # type: ignore[union-attr]

    @classmethod
    def preset(cls, name: str, overrides: Mapping[str, Any] | None = None) -> PlannerSettings:
        """Named settings (``default``, ``paper``, ``ipopt``, ``wrapped_goal``,
        ``real_actuators``) with dotted overrides on top."""
        if name not in PRESETS:
            raise UnknownNameError("planner preset", name, PRESETS)
        return cls().override({**PRESETS[name], **(overrides or {})})

    def override(self, values: Mapping[str, Any]) -> PlannerSettings:
        """These settings with ``{"group.field": value}`` changed; every value is checked by
        its group's rules."""
        changes: dict[str, dict[str, Any]] = {}
        for name, value in values.items():
            group, key = _split(name)
            changes.setdefault(group, {})[key] = value
        return replace(self, **{g: replace(getattr(self, g), **kv) for g, kv in changes.items()})

    def flat(self) -> dict[str, Any]:
        """Every setting by its dotted name."""
        return {name: getattr(getattr(self, g), k) for name, g, k, _ in self.specs()}

    @classmethod
    def specs(cls) -> Iterator[tuple[str, str, str, Rule]]:
        """(dotted name, group, field, rule) of every setting, in declaration order."""
        for g in fields(cls):
            for f in fields(g.default_factory):  # type: ignore[arg-type]
                yield f"{g.name}.{f.name}", g.name, f.name, f.metadata["rule"]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _split(name: str) -> tuple[str, str]:
    """``group.field`` → (group, field), or an error naming the valid names."""
    valid = [n for n, *_ in PlannerSettings.specs()]
    if name in RENAMED:
        raise _renamed(name)
    if name in REMOVED:
        error = UnknownNameError("planner setting", name, valid)
        error.args = (f"planner setting {name!r} no longer exists: {REMOVED[name]}",)
        raise error
    group, _, key = name.partition(".")
    if name not in valid:
        raise UnknownNameError("planner setting", name, valid)
    return group, key


def _renamed(name: str) -> UnknownNameError:
    error = UnknownNameError("planner setting", name, [RENAMED[name]])
    error.args = (
        f"planner setting {name!r} is now {RENAMED[name]!r} (settings are named group.field)",
    )
    return error


def parse_assignments(items: list[str], option: str = "--planner-setting") -> dict[str, Any]:
    """``["opt.t_plan=0.08", "escape.enabled=false"]`` → overrides typed by each setting's
    default (the values are checked when applied); errors name ``option`` and the item."""
    defaults = PlannerSettings().flat()
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = (part.strip() for part in item.partition("="))
        if not sep:
            raise InvalidValueError(option, "must be GROUP.FIELD=VALUE", item)
        _split(key)  # unknown or renamed: an error naming the valid or new name
        default = defaults[key]
        try:
            out[key] = _parse(default, text)
        except ValueError:
            what = {bool: "true or false", int: "an integer", float: "a number"}
            kind = what.get(type(default), "text")
            if isinstance(default, tuple):
                kind = "numbers separated by commas"
            raise InvalidValueError(option, f"{key} must be {kind}", text) from None
    return out


def _parse(default: Any, text: str) -> Any:
    if isinstance(default, bool):
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError(text)
        return text.lower() in ("true", "1")
    if isinstance(default, tuple):
        return tuple(float(x) for x in text.strip("()[] ").split(",") if x.strip())
    return type(default)(text)
