"""The stall escape of a NeHMO arm: leave a local minimum on the safe set, or yield the goal.

Opt only ever takes the step closest to the goal, so an arm whose goal lies behind a peer's
level set stops where the goal direction meets the constraint. :class:`StallEscape` counts calls
without progress against an active V row and, after ``stall_ticks`` of them, swaps the goal
error for a target step along a random direction projected onto the tangent space of the
critical pair's level set (or, at the goal, up V's gradient). It is a part of
:class:`~nehmo_core.planning.nehmo.NehmoPlanner`, whose state it keeps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.robots.model import RobotModel

__all__ = ["StallEscape"]


class _TickPeers(Protocol):
    """What the escape reads of one tick's constrained peers."""

    @property
    def values(self) -> np.ndarray:
        """(k,) V per peer [m]."""

    @property
    def grads(self) -> Sequence[np.ndarray]:
        """(n_i,) ∇ₓV per peer."""


class StallEscape:
    """The stall and escape state of a planner, and the rules that change it."""

    settings: PlannerSettings
    robot: RobotModel
    _rng: np.random.Generator

    def _clear_stall(self) -> None:
        """Forget the stall and escape state (on reset() and whenever the goal changes; the
        warm start, Hessian estimate and random stream are kept)."""
        self._goal: np.ndarray | None = None  # the goal the stall state was gathered toward
        self._stall = 0  # consecutive calls without progress against an active V row
        self._escapes = 0  # escapes since the goal error last reached a new low
        self._escape_left = 0  # calls left in the current escape
        self._escape_dir = np.zeros(self.robot.dof)
        self._yielding = False  # the current escape gives way at the goal
        self._last_error = math.inf
        self._best_error = math.inf

    def _escape_error(self, now: _TickPeers) -> np.ndarray:
        """The stand-in for ``e₀`` while escaping: minus a full-speed target step, along the
        escape direction projected onto the tangent space of the critical pair's level set of V
        (a stalled arm), or straight up V's gradient (an arm yielding its goal)."""
        g = now.grads[int(np.argmin(now.values))][: self.robot.dof]
        if self._yielding:
            d = g
        else:
            d = self._escape_dir
            gg = float(g @ g)
            if gg > 1e-12:
                d = d - (d @ g) / gg * g
        peak = float(np.abs(d).max())
        if peak < 1e-9:
            return np.zeros(self.robot.dof)
        return -(self.settings.t_plan * self.settings.u_max / peak) * d

    def _track_stall(self, error0: np.ndarray, pressed: bool) -> None:
        """Count calls without progress while a V row is active; start an escape (away from
        the goal) or a yield (at the goal) after ``stall_ticks`` of them."""
        s = self.settings
        e = float(np.linalg.norm(error0))
        step = s.t_plan * s.u_max
        progressed = self._last_error - e > s.stall_progress * step
        self._last_error = e
        if self._best_error - e > s.stall_progress * step:
            # closer than ever before: a stall from here on is a new trap, not the same one
            self._best_error = e
            self._escapes = 0
        if self._escape_left > 0:
            self._escape_left -= 1
            return
        if not pressed or (progressed and e >= step):
            self._stall = 0
            return
        self._stall += 1
        if self._stall < s.stall_ticks:
            return
        self._stall = 0
        self._yielding = e < step
        if self._yielding:
            self._escape_left = s.yield_ticks
        else:
            self._escapes += 1
            self._escape_left = s.escape_ticks * min(2 ** (self._escapes - 1), 4)
            self._escape_dir = self._rng.standard_normal(self.robot.dof)
