"""The stall escape of a NeHMO arm: leave a local minimum on the safe set, or yield the goal.

An objective stage (settings group ``escape``; off in the ``paper`` preset). It changes
only Opt's target; the V rows against every peer's worst case stay.

Opt only ever takes the step closest to the goal, so an arm whose goal lies behind a peer's
level set stops where the goal direction meets the constraint. :class:`StallEscape` counts calls
without progress against an active V row and, after ``stall_ticks`` of them, swaps the goal
error for a target step along a random direction projected onto the tangent space of the
critical pair's level set (or, at the goal, up V's gradient) for ``escape_ticks`` calls (doubled
with every escape from the same trap, up to ``max_stretch`` times as long).
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.tick import PeerValues, Tick

__all__ = ["StallEscape"]


class StallEscape:
    """The stall and escape state of one arm, and the rules that change it."""

    name = "escape"
    flag = "escaping"

    def __init__(self, host: Host) -> None:
        self.arm_id = host.arm_id
        self.settings = host.settings
        self.dof = host.robot.dof
        self.reset()

    def reset(self) -> None:
        """A new episode: the random stream starts again, the stall state is forgotten."""
        seed = zlib.crc32(self.arm_id.encode()) ^ self.settings.escape.seed
        self.rng = np.random.default_rng(seed)
        self.clear()

    def close(self) -> None:
        """It holds nothing."""

    def clear(self) -> None:
        """Forget the stall and escape state (on reset() and whenever the goal changes; the
        random stream is kept)."""
        self.goal: np.ndarray | None = None  # the goal the stall state was gathered toward
        self.stall = 0  # consecutive calls without progress against an active V row
        self.escapes = 0  # escapes since the goal error last reached a new low
        self.escape_left = 0  # calls left in the current escape
        self.direction = np.zeros(self.dof)
        self.yielding = False  # the current escape gives way at the goal
        self.last_error = math.inf
        self.best_error = math.inf

    def begin(self, tick: Tick) -> None:
        """A new goal (a controller need not call reset() between goals): a stall or an
        escape toward the old one says nothing about the new one."""
        if self.goal is None or not np.array_equal(tick.goal, self.goal):
            self.clear()
            self.goal = tick.goal.copy()

    def target(self, tick: Tick, now: PeerValues) -> np.ndarray | None:
        """While escaping: minus a full-speed target step, along the escape direction
        projected onto the tangent space of the critical pair's level set of V (a stalled arm),
        or straight up V's gradient (an arm yielding its goal)."""
        if self.escape_left <= 0:
            return None
        g = now.grads[now.critical][: self.dof]
        if self.yielding:
            d = g
        else:
            d = self.direction
            gg = float(g @ g)
            if gg > 1e-12:
                d = d - (d @ g) / gg * g
        peak = float(np.abs(d).max())
        if peak < 1e-9:
            return np.zeros(self.dof)
        return -(self.settings.opt.t_plan * self.settings.opt.u_max / peak) * d

    def after(self, tick: Tick, min_constraint: float) -> None:
        """Count the call, unless another stage steered it (stepping aside is no stall)."""
        if tick.steered_by in (None, self.name):
            self.track(tick.error0, min_constraint < self.settings.escape.stall_margin)

    def track(self, error0: np.ndarray, pressed: bool) -> None:
        """Count calls without progress while a V row is active; start an escape (away from
        the goal) or a yield (at the goal) after ``stall_ticks`` of them."""
        s = self.settings
        e = float(np.linalg.norm(error0))
        step = s.opt.t_plan * s.opt.u_max
        progressed = self.last_error - e > s.escape.stall_progress * step
        self.last_error = e
        if self.best_error - e > s.escape.stall_progress * step:
            # closer than ever before: a stall from here on is a new trap, not the same one
            self.best_error = e
            self.escapes = 0
        if self.escape_left > 0:
            self.escape_left -= 1
            return
        if not pressed or (progressed and e >= step):
            self.stall = 0
            return
        self.stall += 1
        if self.stall < s.escape.stall_ticks:
            return
        self.stall = 0
        self.yielding = e < step
        if self.yielding:
            self.escape_left = s.escape.yield_ticks
        else:
            self.escapes += 1
            self.escape_left = s.escape.escape_ticks * min(
                2 ** (self.escapes - 1), s.escape.max_stretch
            )
            self.direction = self.rng.standard_normal(self.dof)
