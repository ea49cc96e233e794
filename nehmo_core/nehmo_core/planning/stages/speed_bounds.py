"""Announced speed bounds, the announcing side: an arm settled at its goal promises to move
slowly, so its peers may plan against ``V(k·t_safe)`` instead of ``V(t_safe)`` with it.

An announcer stage (settings group ``hold``; ``hold.bound = 1``, the ``paper`` preset, announces
nothing). It
changes the share of ū this arm's commands keep and what it announces; the V rows against every
peer's worst case stay (why a kept bound is safe: :mod:`nehmo_core.planning.opt.peer_bounds`).

A NeHMO arm within ``hold_tolerance`` of its goal (``hold.pressed_tolerance`` while a peer's V row
reads within ``hold.pressed_band`` of its margin) announces ``k = hold_bound`` with every command
and keeps its own commands within ``k·ū`` from then on, including its fail-safe. A withdrawal (a
new goal, drifting beyond ``hold_release``, or a threat) is announced ``bound_release_ticks``
commands before the arm moves faster, so peers hear it before it matters. The threat: a NeHMO
peer (one that announces, even only full speed) plans against the settled arm's bound and so
keeps ``V(k·t_safe)`` at or above its settled margin with it; it is a threat only when it brings
``V(k·t_plan)`` below half that margin (beyond what its linearized steps can explain). A peer
that announces nothing is a threat as soon as it brings ``V(k·t_plan)`` below ε (a reckless arm).
Either is a threat within ``exact_guard`` of the real geometry
(:func:`nehmo_core.planning.stages.exact_guard.closer_than`). Either way the settled arm
withdraws to flee at full speed. The price that remains: the two commands before the arm may
speed up.

An arm keeps only the bound its joints follow: one whose acceleration is limited may still move
faster than ``k·ū`` for a few ticks after it announces (it was braking into its goal), and its
peers then distrust it until it withdraws
(:class:`~nehmo_core.planning.opt.peer_bounds.PeerBounds`).
With ``hold.self_check`` the arm applies its peers' check to its own observed motion; the tick it
would fail, it announces full speed (a withdrawal, its commands stay within ``k·ū``) and announces
its bound anew from the next tick, so its peers trust it again once it moves slowly.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from nehmo_core.planning.opt.peer_bounds import FULL_SPEED, PeerBounds
from nehmo_core.planning.opt.pipeline import Host, margin_gaps
from nehmo_core.planning.opt.tick import Tick
from nehmo_core.planning.stages.exact_guard import cell_world, closer_than

__all__ = ["HoldAnnouncer"]


class HoldAnnouncer:
    """The hold at the goal: this arm's announcements and the speed cap they imply."""

    name = "hold"

    def __init__(self, host: Host) -> None:
        self.host = host
        self.settings = host.settings
        # the threat test's real geometry (the exact guard's world of the cell)
        guarded = host.settings.exact_guard.gap > 0 and host.pairs
        self._lease = cell_world(host.cell, self) if guarded else None
        self.reset()

    def close(self) -> None:
        """Give the cell's world back (it closes with its last user)."""
        if self._lease is not None:
            self._lease.release()

    def reset(self) -> None:
        # this arm's recent announcements (newest last); its commands keep the smallest
        self._announced = deque([FULL_SPEED], maxlen=self.settings.hold.release_ticks + 1)
        self.holding = False  # settled at the goal, announcing hold_bound
        # this arm's own announcements checked against its own observed motion, as its peers do
        self._own = PeerBounds(self.settings.opt.d_max)
        self._clock = 0.0  # [s] plan() calls times the tick period
        self.withdrawals = 0  # announcements withdrawn because this arm broke them

    @property
    def announcement(self) -> float:
        return self._announced[-1]

    @property
    def speed_cap(self) -> float:
        """The smallest of the announcements of the last ``bound_release_ticks`` commands and
        this one (a withdrawal is heard first)."""
        return min(self._announced)

    def announce(self, tick: Tick) -> None:
        """hold_bound from within hold_tolerance of the goal until beyond hold_release, or
        until a peer breaks the slow game (:meth:`threatened`), else full speed."""
        s = self.settings
        e = float(np.linalg.norm(tick.error0))
        arrived = e <= s.hold.tolerance or (
            not self.holding and e <= s.hold.pressed_tolerance and self.pressed(tick)
        )
        live = self.holding or arrived  # else the threat test cannot matter
        if e > s.hold.release or (live and self.threatened(tick)):
            self.holding = False
        elif arrived:
            self.holding = True
        tick.announced = s.hold.bound if self.holding else FULL_SPEED
        if s.hold.self_check:
            tick.announced = self._checked(tick.q, tick.announced)
        self._announced.append(tick.announced)
        tick.cap = self.speed_cap

    def _checked(self, q: np.ndarray, bound: float) -> float:
        """``bound``, or full speed (a withdrawal) if this arm's motion since the last tick broke
        what it announced, judged as its peers judge it."""
        me = self.host.arm_id
        self._clock += self.settings.opt.tick
        self._own.observe(me, self._clock, q)
        broken = self._announced[-1] < FULL_SPEED and self._own.bound(me) >= FULL_SPEED
        if bound < FULL_SPEED and broken:  # withdrawn now, announced anew next tick
            self.withdrawals += 1
            bound = FULL_SPEED
        self._own.announce(me, bound)
        return bound

    def pressed(self, tick: Tick) -> bool:
        """Whether some peer's V row (at the bound it announced) reads within
        ``hold.pressed_band`` of its margin: the arm may be held short of its goal by it."""
        host = self.host
        ids = [p for p in host.pairs if p in tick.bounds]
        if not ids:
            return False
        now = host.evaluate(tick.q, tick.peers, ids, tick.bounds)
        return bool(np.any(margin_gaps(host, now) < self.settings.hold.pressed_band))

    def threatened(self, tick: Tick) -> bool:
        """Whether a peer at full speed has broken the slow game with this arm near its goal:
        a participant (it plans against this arm's bound ``k`` and keeps ``V(k·t_safe)`` at its
        settled margin) brings ``V(k·t_plan)`` below half that margin, a peer that announces
        nothing below ε, or either comes within ``exact_guard`` of the real geometry."""
        s, host = self.settings, self.host
        ids = [p for p in host.pairs if tick.bounds[p] >= FULL_SPEED]
        if not ids:
            return False
        slow = host.evaluate(tick.q, tick.peers, ids, dict.fromkeys(ids, s.hold.bound))
        half = [0.5 * host.group_margin(host.pairs[p].model_index, s.hold.bound) for p in ids]
        floor = [
            h if p in tick.participants else s.opt.epsilon for p, h in zip(ids, half, strict=True)
        ]
        if np.any(slow.values < np.array(floor)):
            return True
        near = {
            p: tick.peers[p]
            for p, v in zip(ids, slow.values, strict=True)
            if v < s.exact_guard.near
        }
        if self._lease is None:
            return False
        return closer_than(self._lease.world, host.arm_id, tick.q, near, s.exact_guard.gap)
