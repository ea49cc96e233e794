"""PyBullet worlds shared by the planners of a process, each closed with its last user.

A PyBullet client costs about 30 MB and a few tens of milliseconds to build, so the planners of
one process that need the same world (the exact guard's world of a cell, the self-clearance
world of a robot) share it. A :class:`Lease` is what a user holds: the world, a dictionary for
facts derived from it (kept as long as the world), and :meth:`Lease.release`. A lease is
released when its owner is closed or garbage-collected, whichever comes first, and the world is
closed when its last lease is released: nothing outlives the planners that use it.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

from nehmo_core.geometry.pybullet_world import CellWorld

__all__ = ["WORLDS", "Lease", "WorldPool"]


@dataclass
class _Entry:
    world: CellWorld
    users: int = 0
    facts: dict[str, Any] = field(default_factory=dict)


class Lease:
    """One user's hold on a shared world."""

    def __init__(self, pool: WorldPool, key: Hashable, entry: _Entry, owner: object) -> None:
        self.world = entry.world
        self.facts = entry.facts
        self._done = weakref.finalize(owner, pool._release, key)

    def release(self) -> None:
        """Give the world back (once; later calls do nothing)."""
        self._done()

    @property
    def released(self) -> bool:
        return not self._done.alive


class WorldPool:
    """Worlds by key (a cell, a robot), counted by their users."""

    def __init__(self) -> None:
        self._entries: dict[Hashable, _Entry] = {}

    def lease(self, key: Hashable, make: Callable[[], CellWorld], owner: object) -> Lease:
        """The world of ``key`` (built by ``make`` if no one holds it), held for ``owner``."""
        entry = self._entries.get(key)
        if entry is None:
            entry = self._entries[key] = _Entry(make())
        entry.users += 1
        return Lease(self, key, entry, owner)

    def _release(self, key: Hashable) -> None:
        entry = self._entries[key]
        entry.users -= 1
        if entry.users == 0:
            del self._entries[key]
            entry.world.close()

    def clients(self) -> set[int]:
        """PyBullet clients of the worlds held now."""
        return {e.world.client for e in self._entries.values()}

    def __len__(self) -> int:
        return len(self._entries)


WORLDS = WorldPool()
"""The process's pool (its worlds belong to the leases that hold them)."""
