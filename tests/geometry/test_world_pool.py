"""Shared PyBullet worlds belong to their users: closed with the last lease, by close() or GC."""

from __future__ import annotations

import gc

import numpy as np
import pybullet as pb
import pytest

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.world_pool import WorldPool
from nehmo_core.planning.factory import make_planner
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.stages import exact_guard, self_clearance
from nehmo_core.robots.loader import load_cell


class _Owner:
    pass


def test_a_world_is_shared_and_closed_with_its_last_lease() -> None:
    pool, cell = WorldPool(), load_cell("dual_ur5")
    a, b = _Owner(), _Owner()
    first = pool.lease("k", lambda: CellWorld(cell), a)
    second = pool.lease("k", lambda: CellWorld(cell), b)
    assert first.world is second.world and len(pool) == 1
    client = first.world.client
    first.release()
    first.release()  # twice is harmless
    assert first.released and pb.isConnected(physicsClientId=client)
    del b  # the second owner is collected without a release: its lease goes with it
    gc.collect()
    assert len(pool) == 0 and not pb.isConnected(physicsClientId=client)


def test_a_planner_gives_its_stages_worlds_back(monkeypatch: pytest.MonkeyPatch) -> None:
    pool = WorldPool()  # no other test's planners share these worlds
    monkeypatch.setattr(exact_guard, "WORLDS", pool)
    monkeypatch.setattr(self_clearance, "WORLDS", pool)
    cell = load_cell("dual_ur5")
    before = len(pool)
    models = ModelRegistry().models_for("nehmo", cell)
    planners = [make_planner("nehmo", cell, a, models) for a in cell.arm_ids]
    q = {a: np.zeros(6) for a in cell.arm_ids}
    planners[0].plan(q[cell.arm_ids[0]], {cell.arm_ids[1]: q[cell.arm_ids[1]]}, np.zeros(6))
    assert len(pool) == before + 2  # the cell's world (exact guard) and the UR5's own
    planners[0].close()
    assert len(pool) == before + 2  # still used by the other planner
    del planners
    gc.collect()
    assert len(pool) == before
