"""Stepping out of the way of a peer that announces nothing (not in the paper).

An objective stage (settings group ``silent_watch``; ``silent_watch.lookahead = 0``, the ``paper``
preset, turns it off). It changes only Opt's target; the
V rows against every peer's worst case stay.

A peer that takes no part in the speed announcements (a reckless or foreign arm) is planned at
full speed, as the paper does: the V rows hold against its worst case ``t_safe`` ahead. They
say nothing about where it is going. An arm that keeps heading for its goal until those rows
bind can then be deep inside the path of a peer that drives straight through it, and by the
time the fail-safe starts it cannot get out: on development seeds, in most collisions with the
reckless Kinova no constant full-speed command from the first fail-safe tick would have escaped
the Kinova's remaining path.

:class:`SilentPathWatch` extrapolates each silent peer's observed joint velocity (the change of
its position between two ``plan()`` calls ``tick`` apart, continuous joints wrapped, clipped to
the peers' speed bound ``d̄``: a call that follows a skipped tick cannot make a peer look faster
than it may move) up to ``lookahead`` seconds and
evaluates ``V(t_plan)`` with the peer at ``points`` of that path. When the lowest is below
``clearance`` and lower than now by more than ``approach`` (the peer is coming closer), the
step's target becomes a full-speed step up ``∂V/∂q_own`` at that point instead of the goal.
Only the objective changes: the V rows against the peer's worst case stay as they are, so the
guarantee of the paper's Opt is kept, and a peer that stops (or moves away) stops steering it.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

import numpy as np

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import SilentWatchSettings
from nehmo_core.robots.model import RobotModel

__all__ = ["SilentPathWatch", "SilentPeers"]


class SilentPathWatch:
    """The observed velocities of silent peers and the escape step from their paths."""

    def __init__(
        self,
        lookahead: float,
        clearance: float,
        tick: float,
        d_max: float,
        robots: Mapping[str, RobotModel] | None = None,
        approach: float = SilentWatchSettings.approach,
        points: Sequence[float] = SilentWatchSettings.points,
    ) -> None:
        self.lookahead = lookahead
        self.clearance = clearance
        self.approach = approach
        self.points = np.asarray(points, dtype=float)
        self.tick = tick
        self.d_max = d_max
        self.robots = dict(robots or {})  # peer id → its robot (continuous joints wrapped)
        self._last: dict[str, np.ndarray] = {}

    def reset(self) -> None:
        self._last = {}

    def velocities(
        self, peers: Mapping[str, np.ndarray], participants: Collection[str]
    ) -> dict[str, np.ndarray]:
        """Each silent peer's joint velocity [rad/s] since the previous call, within ±d̄ (peers
        seen for the first time, and peers that take part in the announcements, have none;
        none at all, and nothing kept, with the watch off)."""
        if self.lookahead <= 0.0:
            return {}
        last, self._last = self._last, {p: q.copy() for p, q in peers.items()}
        out = {}
        for p, q in peers.items():
            if p in last and p not in participants:
                step = q - last[p]
                if p in self.robots:
                    step = self.robots[p].wrap(step)
                out[p] = np.clip(step / self.tick, -self.d_max, self.d_max)
        return out

    def target(
        self,
        models: Sequence[PairValueModel],
        ids: Sequence[str],
        model_index: Sequence[int],
        states: Sequence[np.ndarray],
        values: np.ndarray,
        velocities: Mapping[str, np.ndarray],
        n1: int,
        t_plan: float,
        step: float,
    ) -> np.ndarray | None:
        """Minus a ``step`` [rad] (largest joint) up ``∂V/∂q_own`` at the lowest point of the
        silent peers' predicted paths, when one comes within ``clearance``; else None.

        ``ids``, ``model_index``, ``states`` and ``values`` describe the constrained peers now
        (pair states and ``V(t_plan)``); ``n1`` is this arm's joint count."""
        if self.lookahead <= 0.0:
            return None
        worst: tuple[float, np.ndarray] | None = None
        for i, p in enumerate(ids):
            v = velocities.get(p)
            if v is None:
                continue
            model = models[model_index[i]]
            path = np.repeat(states[i][None, :], len(self.points), axis=0)
            path[:, n1 : n1 + model.n2] += np.outer(self.points * self.lookahead, v)
            ahead, grads = model.evaluate(t_plan, path)
            j = int(np.argmin(ahead))
            low = float(ahead[j])
            approaching = low < self.clearance and low < values[i] - self.approach
            if approaching and (worst is None or low < worst[0]):
                worst = (low, grads[j][:n1])
        if worst is None:
            return None
        peak = float(np.abs(worst[1]).max())
        return None if peak < 1e-9 else -(step / peak) * worst[1]


class SilentPeers:
    """The ``silent_watch`` objective of one planner: a :class:`SilentPathWatch` over its
    constrained peers."""

    name = "silent_watch"
    flag = "evading"

    def __init__(self, host: Host) -> None:
        self.host = host
        s, w = host.settings, host.settings.silent_watch
        robots = {p: host.cell.arm(p).robot for p in host.pairs}
        self.watch = SilentPathWatch(
            w.lookahead, w.clearance, s.opt.tick, s.opt.d_max, robots, w.approach, w.points
        )

    def reset(self) -> None:
        self.watch.reset()

    def close(self) -> None:
        """It holds nothing."""

    def begin(self, tick: Tick) -> None:
        """Nothing to do before the tick."""

    def target(self, tick: Tick, now: PeerValues) -> np.ndarray | None:
        s, host = self.host.settings, self.host
        velocities = self.watch.velocities(tick.peers, tick.participants)
        return self.watch.target(
            host.models, now.ids, now.model_index, now.states, now.values, velocities,
            host.robot.dof, s.opt.t_plan, s.opt.t_plan * s.opt.u_max * tick.cap,
        )  # fmt: skip

    def after(self, tick: Tick, min_constraint: float) -> None:
        """Nothing to do after the tick."""
