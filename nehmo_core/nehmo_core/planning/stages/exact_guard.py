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

One PyBullet world per cell is shared by the planners of a process (the two most recent cells
are kept; the planners of an older cell get a fresh one if they plan again).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping

import numpy as np

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = ["ExactGuard", "closer_than", "guard_step", "prepare"]

_WORLDS: OrderedDict[Cell, CellWorld] = OrderedDict()  # cells compare by value
_KEEP = 2


def _world(cell: Cell) -> CellWorld:
    world = _WORLDS.get(cell)
    if world is None:
        world = _WORLDS[cell] = CellWorld(cell)
        while len(_WORLDS) > _KEEP:
            _WORLDS.popitem(last=False)[1].close()
    _WORLDS.move_to_end(cell)
    return world


def _closest(
    world: CellWorld, arm_id: str, x: np.ndarray, peers: Mapping[str, np.ndarray], cutoff: float
) -> float:
    """Arm ``arm_id`` posed at ``x``: its smallest distance [m] to ``peers`` (already posed)."""
    world.set_joint_positions(arm_id, x)
    return min(world.distance(arm_id, p, cutoff) for p in peers)


def prepare(cell: Cell) -> None:
    """Build ``cell``'s world now (a planner does it when built, not in its first tick)."""
    _world(cell)


def guard_step(
    cell: Cell,
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
    world = _world(cell)
    cutoff = 2.0 * floor + 0.05
    world.set_configuration(held)
    now = _closest(world, arm_id, q, held, cutoff)
    for scale in settings.exact_guard.scales:
        ends = [_closest(world, arm_id, q + f * scale * step, held, cutoff) for f in (1.0, 0.5)]
        if min(ends) >= min(floor, now):
            return scale
    return 0.0


def closer_than(
    cell: Cell, arm_id: str, q: np.ndarray, peers: Mapping[str, np.ndarray], floor: float
) -> bool:
    """Whether arm ``arm_id`` at ``q`` is closer than ``floor`` [m] to a peer of ``peers``
    (``{peer: q}``), with the real geometry. A holding arm withdraws from a peer that brought
    it there: the learned V under the settled margin can read 1–3 cm at contact, so a peer
    pressing at that margin while the holding arm's bounded fail-safe cannot get away (it sits
    between two) would otherwise never count as a threat."""
    if not peers or floor <= 0.0:
        return False
    world = _world(cell)
    world.set_configuration(peers)
    return _closest(world, arm_id, q, peers, 2.0 * floor) < floor


class ExactGuard:
    """The ``exact_guard`` command filter of one planner."""

    name = "exact_guard"

    def __init__(self, host: Host) -> None:
        self.host = host
        self.shortened = 0
        if host.settings.hold.bound < FULL_SPEED and host.pairs:
            prepare(host.cell)  # build the world now, not in the first tick

    def reset(self) -> None:
        self.shortened = 0

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` shortened by :func:`guard_step` against the peers near now that keep an
        announced bound (they take part in the announcements)."""
        host = self.host
        near_v = host.settings.exact_guard.near
        near = [p for p, v in zip(now.ids, now.values, strict=True) if v < near_v]
        held = {
            p: tick.peers[p] for p in near if p in tick.participants and tick.bounds[p] < FULL_SPEED
        }
        share = guard_step(host.cell, host.arm_id, tick.q, u, held, host.settings)
        self.shortened += share < 1.0
        return u * share
