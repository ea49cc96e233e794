"""The exact-geometry guard of a NeHMO arm beside peers that hold still at their goals.

A command filter stage (settings group ``exact_guard``; ``gap`` 0, the ``paper`` preset, turns
it off). It only shortens a command (to ½, ¼ or nothing); the V rows against every peer's worst
case stay.

Against a peer that announced a speed bound (it holds at its goal, :mod:`.speed_bounds`) the
value rows keep only the settled margin, and the learned distance under them can err by a few
centimetres near contact. The guard closes that gap with the arms' real geometry: before a
command is sent, the arm's pose after the step (and halfway) is checked against every holding
peer's current pose with PyBullet. A step that would bring the arms closer than
``exact_guard.gap`` [m] is shortened (to ½, ¼ of it, or nothing) until it does not, unless the
arms are already closer and the step does not bring them closer still. The peer's own motion
within its bound is left to the value rows; a peer that breaks its bound is fled from by the
threat test, which checks the real geometry too (:func:`closer_than`).

One PyBullet world per cell is shared by the planners of a process that use it
(:mod:`nehmo_core.geometry.world_pool`); it closes with the last of them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.world_pool import WORLDS, Lease
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = [
    "ExactGuard",
    "WorldFilter",
    "cell_world",
    "closer_than",
    "closest",
    "distances",
    "guard_step",
]


def cell_world(cell: Cell, owner: object) -> Lease:
    """The shared PyBullet world of ``cell``, held for ``owner``."""
    return WORLDS.lease(("cell", cell), lambda: CellWorld(cell), owner)


def closest(
    world: CellWorld, arm_id: str, x: np.ndarray, peers: Iterable[str], cutoff: float
) -> float:
    """Arm ``arm_id`` posed at ``x``: its smallest distance [m] to ``peers`` (already posed)."""
    world.set_joint_positions(arm_id, x)
    return min(world.distance(arm_id, p, cutoff) for p in peers)


def distances(
    world: CellWorld, arm_id: str, x: np.ndarray, peers: Iterable[str], cutoff: float
) -> np.ndarray:
    """Arm ``arm_id`` posed at ``x``: its distance [m] to each of ``peers`` (already posed)."""
    world.set_joint_positions(arm_id, x)
    return np.array([world.distance(arm_id, p, cutoff) for p in peers])


def guard_step(
    world: CellWorld,
    arm_id: str,
    q: np.ndarray,
    u: np.ndarray,
    held: Mapping[str, np.ndarray],
    settings: PlannerSettings,
) -> float:
    """The share of the command ``u`` [rad/s] (one of ``exact_guard.scales`` or 0), held for
    ``opt.t_plan``, that keeps arm ``arm_id`` at least ``exact_guard.gap`` [m] from every peer
    of ``held`` (``{peer: q}``, posed as given) at the step's end and midpoint, or no closer than
    now where it already is closer."""
    floor, step = settings.exact_guard.gap, u * settings.opt.t_plan
    if not held or floor <= 0.0:
        return 1.0
    cutoff = 2.0 * floor + 0.05
    world.set_configuration(held)
    now = closest(world, arm_id, q, held, cutoff)
    for scale in settings.exact_guard.scales:
        ends = [closest(world, arm_id, q + f * scale * step, held, cutoff) for f in (1.0, 0.5)]
        if min(ends) >= min(floor, now):
            return scale
    return 0.0


def closer_than(
    world: CellWorld, arm_id: str, q: np.ndarray, peers: Mapping[str, np.ndarray], floor: float
) -> bool:
    """Whether arm ``arm_id`` at ``q`` is closer than ``floor`` [m] to a peer of ``peers``
    (``{peer: q}``), with the real geometry. A holding arm withdraws from a peer that brought
    it there: the learned V under the settled margin can read 1–3 cm at contact, so a peer
    pressing at that margin while the holding arm's bounded fail-safe cannot get away (it sits
    between two) would otherwise never count as a threat."""
    if not peers or floor <= 0.0:
        return False
    world.set_configuration(peers)
    return closest(world, arm_id, q, peers, 2.0 * floor) < floor


class WorldFilter:
    """A command filter that checks the real geometry in the cell's shared PyBullet world."""

    def __init__(self, host: Host, world: bool = True) -> None:
        self.host = host
        self.shortened = 0
        # built now, not in the first tick; no constrained peer, nothing to guard against
        self._lease = cell_world(host.cell, self) if world and host.pairs else None

    def close(self) -> None:
        """Give the cell's world back (it closes with its last user)."""
        if self._lease is not None:
            self._lease.release()

    def reset(self) -> None:
        self.shortened = 0


class ExactGuard(WorldFilter):
    """The ``exact_guard`` command filter of one planner."""

    name = "exact_guard"

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` shortened by :func:`guard_step` against the peers near now that keep an
        announced bound (they take part in the announcements)."""
        host = self.host
        if self._lease is None:
            return u
        near_v = host.settings.exact_guard.near
        near = [p for p, v in zip(now.ids, now.values, strict=True) if v < near_v]
        held = {p: tick.peers[p] for p in near if tick.holds(p)}
        share = guard_step(self._lease.world, host.arm_id, tick.q, u, held, host.settings)
        self.shortened += share < 1.0
        return u * share
