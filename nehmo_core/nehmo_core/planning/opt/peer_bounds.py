"""Announced speed bounds, the receiving side: a peer that promises to move slowly is planned
against its promise for as long as its observed motion keeps it.

Time rescaling gives the bound without a new value function. With ``q̇¹ = u``, ``q̇² = d``,
``|u|∞ ≤ ū`` and ``|d|∞ ≤ d̄``, a peer that keeps ``|d|∞ ≤ k·d̄`` (``0 ≤ k ≤ 1``) can be answered
by the arm with ``|u|∞ ≤ k·ū``, which is the full-speed game slowed down by ``k``; a larger
control set can only help the arm, so

    V_{ū, k·d̄}(τ, x)  ≥  V_{k·ū, k·d̄}(τ, x)  =  V(k·τ, x),

and ``V(k·t_safe, x) ≥ ε`` keeps the paper's guarantee against that peer with the value function
already trained (``V(0, x) = l(x)``: a peer that holds still is as far as it is). Problem Opt
takes each peer's bound (1 unless announced and kept); the announcing side is a stage
(:mod:`nehmo_core.planning.stages.speed_bounds`).

:class:`PeerBounds` keeps each peer's announcement and checks the peer's observed motion against
it; the tick a peer moves faster than it announced (with a small tolerance), the peer is planned
against ``d̄`` again, until it withdraws its announcement and makes a new one. A peer that
announces nothing is planned against ``d̄``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError

__all__ = ["FULL_SPEED", "PeerBounds", "check_bound"]

FULL_SPEED = 1.0  # the announcement of an arm that promises nothing


def check_bound(value: float, parameter: str = "speed bound") -> float:
    """``value`` as a speed-bound fraction, or :class:`InvalidValueError` unless in [0, 1]."""
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise InvalidValueError(parameter, "must lie in [0, 1] (a fraction of d̄)", value)
    return value


@dataclass
class _Peer:
    announced: deque[float]  # the most recent announcements, newest last
    q: np.ndarray | None = None
    t: float = 0.0
    broken: bool = False  # moved faster than announced; distrusted until it re-announces
    breaches: int = 0
    heard: bool = False  # has announced at all: it takes part in the announcements


class PeerBounds:
    """Each peer's announced bound, trusted while the peer's observed motion keeps it.

    ``d_max`` [rad/s] is the peers' full speed; a displacement over ``dt`` is within an
    announcement ``k`` when no joint moved more than ``k·d_max·dt·(1 + rel_tol) + abs_tol``.
    The check allows the largest of the last ``window`` announcements (a peer's motion follows
    its announcements with a command's latency).
    """

    def __init__(
        self, d_max: float, window: int = 3, rel_tol: float = 0.1, abs_tol: float = 2e-3
    ) -> None:
        if not d_max > 0:
            raise InvalidValueError("d_max", "must be > 0 [rad/s]", d_max)
        if window < 1:
            raise InvalidValueError("window", "must be >= 1 announcement", window)
        self.d_max = float(d_max)
        self.window = int(window)
        self.rel_tol = float(rel_tol)
        self.abs_tol = float(abs_tol)
        self._peers: dict[str, _Peer] = {}

    def reset(self) -> None:
        self._peers.clear()

    def _peer(self, peer: str) -> _Peer:
        if peer not in self._peers:
            self._peers[peer] = _Peer(deque([FULL_SPEED], maxlen=self.window))
        return self._peers[peer]

    def announce(self, peer: str, bound: float) -> None:
        """Record ``peer``'s newest announcement (a fraction of ``d_max``)."""
        p = self._peer(peer)
        bound = check_bound(bound)
        p.heard = True
        if p.broken and bound >= FULL_SPEED:
            p.broken = False  # withdrawn: its next announcement is trusted again
        p.announced.append(bound)

    def observe(self, peer: str, t: float, q: ArrayLike) -> None:
        """Record ``peer``'s joint positions ``q`` at time ``t`` [s] and check the motion since
        the previous observation against its announcements."""
        p = self._peer(peer)
        q = np.asarray(q, dtype=np.float64)
        if p.q is not None and t > p.t:
            allowed = max(p.announced) * self.d_max * (t - p.t) * (1.0 + self.rel_tol)
            if float(np.abs(q - p.q).max()) > allowed + self.abs_tol:
                if not p.broken:
                    p.breaches += 1
                p.broken = True
        p.q, p.t = q.copy(), float(t)

    def bound(self, peer: str) -> float:
        """The fraction of ``d_max`` to plan ``peer`` against: its newest announcement while it
        keeps its word, 1 otherwise."""
        p = self._peers.get(peer)
        if p is None or p.broken:
            return FULL_SPEED
        return p.announced[-1]

    def bounds(self, peers: Iterable[str] | None = None) -> dict[str, float]:
        """:meth:`bound` of every peer that has announced (of those among ``peers`` if given).
        A peer never heard from is left out: it takes no part in the announcements (a planner
        plans it at full speed and treats it as silent)."""
        ids = self._peers if peers is None else peers
        return {p: self.bound(p) for p in ids if p in self._peers and self._peers[p].heard}

    def breaches(self, peer: str) -> int:
        """How often ``peer`` was caught moving faster than it announced."""
        p = self._peers.get(peer)
        return 0 if p is None else p.breaches
