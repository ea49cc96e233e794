"""Solver faults on purpose: the ``arm_planner`` parameter ``fault_injection`` (default off).

It lives in ``nehmo_ros`` although it imports no ROS package because it is a node parameter:
only the node (and the fault experiments that drive the node's control loop) wraps planners
this way. For testing the fail-safes of a running node, never for operation: a node with a fault
injected says so in a WARN line at start and in every status (``fault_injection``). Syntax
``KIND[:SECONDS][@CALLS]``; the fault starts at plan call number ``CALLS`` (default 0, the
first call after the warm-up):

=================== ===========================================================================
``raise``           every ``plan()`` raises (a planner crash: the controller's error path)
``solver_raise``    the optimizer inside an Opt planner raises (the planner's own fail-safe path)
``hang[:S]``        ``plan()`` blocks ``S`` s (default: for good), then plans
``slow:S``          every ``plan()`` first sleeps ``S`` s (repeated missed deadlines)
=================== ===========================================================================
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import Planner, PlanResult

__all__ = ["FAULT_KINDS", "FaultInjectingPlanner", "FaultSpec", "InjectedFault", "parse_fault"]

FAULT_KINDS = ("raise", "solver_raise", "hang", "slow")
_SYNTAX = re.compile(r"^(?P<kind>[a-z_]+)(?::(?P<seconds>[0-9.eE+-]+))?(?:@(?P<after>\d+))?$")
_RULE = f"must be '' (off) or KIND[:SECONDS][@CALLS] with KIND in {list(FAULT_KINDS)}"


class InjectedFault(RuntimeError):
    """The exception a ``raise`` or ``solver_raise`` fault throws."""


@dataclass(frozen=True)
class FaultSpec:
    """A parsed ``fault_injection`` value."""

    kind: str
    seconds: float = math.inf  # hang duration / slow-down [s]
    after: int = 0  # plan calls before the fault starts

    def __str__(self) -> str:
        text = self.kind
        if math.isfinite(self.seconds):
            text += f":{self.seconds:g}"
        return text + (f"@{self.after}" if self.after else "")


def parse_fault(text: str) -> FaultSpec | None:
    """The fault of parameter ``fault_injection`` (None when empty: no fault)."""
    value = text.strip()
    if not value:
        return None
    match = _SYNTAX.match(value)
    if match is None or match["kind"] not in FAULT_KINDS:
        raise InvalidValueError("fault_injection", _RULE, text)
    kind = match["kind"]
    seconds = float(match["seconds"]) if match["seconds"] else math.inf
    if kind == "slow" and not (math.isfinite(seconds) and seconds > 0):
        raise InvalidValueError("fault_injection", "slow needs a finite delay > 0: slow:S", text)
    if not seconds > 0:
        raise InvalidValueError("fault_injection", "SECONDS must be > 0", text)
    return FaultSpec(kind, seconds, int(match["after"] or 0))


class _RaisingSolver:
    """Stands in for an Opt planner's optimizer once the fault is on."""

    def __init__(self, solver: Any, active: threading.Event) -> None:
        self._solver = solver
        self._active = active

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self._active.is_set():
            raise InjectedFault("injected solver fault (fault_injection=solver_raise)")
        return self._solver(*args, **kwargs)


class FaultInjectingPlanner:
    """Wraps a planner and injects ``spec`` into its ``plan`` calls; the rest is delegated."""

    def __init__(self, planner: Planner, spec: FaultSpec) -> None:
        self.inner = planner
        self.spec = spec
        self.arm_id = planner.arm_id
        self.calls = 0
        self._active = threading.Event()
        self._release = threading.Event()  # ends a hang early (tests, shutdown)
        if spec.kind == "solver_raise":
            if not isinstance(planner, NehmoPlanner):
                raise InvalidValueError(
                    "fault_injection", "solver_raise needs an Opt planner (nehmo, ...)", str(spec)
                )
            planner.solver = _RaisingSolver(planner.solver, self._active)

    # -- the rest of the Planner interface, the inner planner's --------------------------------
    @property
    def announces(self) -> bool:
        return self.inner.announces

    @property
    def announcement(self) -> float:
        return self.inner.announcement

    @property
    def peers_unmodelled(self) -> tuple[str, ...]:
        return self.inner.peers_unmodelled

    @property
    def epsilon_source(self) -> str:
        return self.inner.epsilon_source

    def fail_safe(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray | None:
        return self.inner.fail_safe(q_self, peers, peer_bounds)

    def commanded(self, u: ArrayLike) -> None:
        """The command in flight, passed to the inner planner."""
        self.inner.commanded(u)

    def release(self) -> None:
        """End a running or future hang."""
        self._release.set()

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """The inner planner's plan, after the fault."""
        call, self.calls = self.calls, self.calls + 1
        if call >= self.spec.after:
            self._active.set()
            kind = self.spec.kind
            if kind == "raise":
                raise InjectedFault("injected planner fault (fault_injection=raise)")
            if kind == "hang":
                self._release.wait(None if math.isinf(self.spec.seconds) else self.spec.seconds)
            elif kind == "slow":
                time.sleep(self.spec.seconds)
        return self.inner.plan(q_self, peers, q_goal, peer_bounds)

    def reset(self) -> None:
        self.inner.reset()
