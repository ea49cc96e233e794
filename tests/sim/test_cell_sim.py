"""Kinematic stepping of a cell with exact collision checks at sub-steps."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots import load_cell
from nehmo_core.sim.cell_sim import CellSimulator

UPRIGHT = [0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0]


def test_integrates_velocities_and_holds_arms_without_command() -> None:
    with CellSimulator(load_cell("dual_ur5")) as sim:
        sim.reset({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
        r = sim.step({"ur5_0": [0.5, 0, 0, 0, 0, 0]}, 0.04)
        assert not r.collided and r.time == pytest.approx(0.04)
        assert sim.q["ur5_0"][0] == pytest.approx(0.02)
        np.testing.assert_array_equal(sim.q["ur5_1"], UPRIGHT)


def test_collision_inside_a_step_is_caught() -> None:
    """A fast sweep through the other arm within one step is seen at the sub-steps."""
    with CellSimulator(load_cell("dual_ur5"), substeps=20) as sim:
        sim.reset({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
        # Lower the shoulder by ~1.2 rad in one step: the arm sweeps through the peer.
        r = sim.step({"ur5_0": [0, 3.0, 0, 0, 0, 0]}, 0.4)
        assert r.collided
        with CellSimulator(load_cell("dual_ur5"), substeps=1) as coarse:
            coarse.reset({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
            coarse.step({"ur5_0": [0, 3.0, 0, 0, 0, 0]}, 0.8)  # ends past the peer
            assert not coarse.collisions()


def test_bad_input() -> None:
    with CellSimulator(load_cell("dual_ur5")) as sim:
        with pytest.raises(InvalidValueError, match="missing"):
            sim.reset({"ur5_0": UPRIGHT})
        sim.reset({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
        with pytest.raises(InvalidValueError, match="dt"):
            sim.step({}, 0.0)
        with pytest.raises(InvalidValueError, match="command"):
            sim.step({"ur5_0": [0.0] * 5}, 0.04)


def test_commands_and_states_the_arms_cannot_take_are_rejected() -> None:
    with CellSimulator(load_cell("dual_ur5")) as sim:
        sim.reset({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
        before = sim.positions()
        with pytest.raises(InvalidValueError, match=r"`commands` must name arms.*\['ur5_O'\]"):
            sim.step({"ur5_O": [0.1] * 6}, 0.04)  # a misspelt arm would otherwise hold still
        with pytest.raises(InvalidValueError, match=r"`command\[ur5_0\]` must respect the joint"):
            sim.step({"ur5_0": [100.0, 0, 0, 0, 0, 0]}, 0.04)
        with pytest.raises(InvalidValueError, match="`dt` must be > 0 and finite"):
            sim.step({}, float("inf"))
        for arm, q in sim.positions().items():  # nothing moved
            np.testing.assert_array_equal(q, before[arm])
        with pytest.raises(InvalidValueError, match=r"`q\[ur5_0\]` must respect joint limits"):
            sim.reset({"ur5_0": [10.0, 0, 0, 0, 0, 0], "ur5_1": UPRIGHT})
    for bad in (0, 2.5):
        with pytest.raises(InvalidValueError, match="substeps"):
            CellSimulator(load_cell("dual_ur5"), substeps=bad)  # type: ignore[arg-type]
