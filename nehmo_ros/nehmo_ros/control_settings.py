"""The control loop's settings (:class:`ControlSettings`) and running totals (:class:`Counters`);
the loop itself is :class:`nehmo_ros.control.ArmController`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.settings import OptSettings

__all__ = ["STALE_POLICIES", "ControlSettings", "Counters"]

STALE_POLICIES = ("fail_safe", "hold")


@dataclass(frozen=True)
class ControlSettings:
    """Rate [Hz], staleness timeout [s], what a stale peer triggers, and the jump test; speed
    bounds (commands clipped to ``opt.u_max``, jumps beyond ``opt.d_max`` + ``jump_margin``) and
    the solve budget (``opt.deadline``) are the planner's ``opt`` settings."""

    rate: float = 25.0
    peer_timeout: float = 0.25  # a joint state older than this is stale
    stale_policy: str = "hold"
    jump_margin: float = 0.1  # [rad] slack of the jump test (inf: no jump test)
    plan_age: float = 1.5  # [periods] a plan of older observations is not sent (inf: off)
    opt: OptSettings = field(default_factory=OptSettings)  # the planner's: u_max, d_max

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate) and 0 < self.rate <= 1000):
            raise InvalidValueError("rate", "must lie in (0, 1000] Hz", self.rate)
        if not self.peer_timeout > 0:
            raise InvalidValueError("peer_timeout", "must be > 0 [s]", self.peer_timeout)
        if self.stale_policy not in STALE_POLICIES:
            raise UnknownNameError("stale_policy", self.stale_policy, STALE_POLICIES)
        if not self.jump_margin > 0:
            raise InvalidValueError("jump_margin", "must be > 0 [rad] (inf: off)", self.jump_margin)
        if not self.plan_age > 1:
            raise InvalidValueError("plan_age", "must be > 1 period (inf: off)", self.plan_age)

    @property
    def period(self) -> float:
        return 1.0 / self.rate


@dataclass
class Counters:
    """Running totals reported with every status message."""

    ticks: int = 0
    deadline_misses: int = 0
    fail_safes: int = 0
    holds: int = 0
    solver_errors: int = 0
    late_plans: int = 0
