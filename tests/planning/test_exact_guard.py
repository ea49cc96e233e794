"""The exact guard: beside a peer holding at its goal, the arm's real geometry keeps its floor
even where the learned rows would let it closer, and the guard leaves other steps alone."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.stages.exact_guard import closer_than, guard_step
from nehmo_core.robots import load_cell

DT = 0.04
CELL = load_cell("dual_ur5")
OWN, PEER = CELL.arm_ids
FLOOR = 0.03


@pytest.fixture(scope="module")
def world() -> CellWorld:
    w = CellWorld(CELL)
    yield w
    w.close()


def _folded(world: CellWorld) -> bool:
    return any(c.arm_a == c.arm_b for c in world.collisions())


def _goal_inside_peer(world: CellWorld) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A held peer pose, and a goal of the arm in contact with it, with a free start."""
    rng = np.random.default_rng(7)
    robot = CELL.arm(OWN).robot
    for _ in range(4000):
        peer = rng.uniform(-1.5, 1.5, 6)
        goal = rng.uniform(-1.5, 1.5, 6)
        world.set_configuration({OWN: goal, PEER: peer})
        if not -0.03 < world.distance(OWN, PEER) < 0.0 or _folded(world):
            continue
        start = goal.copy()
        start[0] += 1.4  # swing the shoulder away
        world.set_joint_positions(OWN, start)
        if world.distance(OWN, PEER) > 0.15 and not _folded(world):
            assert robot.dof == 6
            return peer, goal, start
    raise AssertionError("no such scenario in the draws")


def _closest(world: CellWorld, settings: PlannerSettings, models: list) -> tuple[float, int]:
    """Drive the arm toward a goal inside a peer that holds (bound 0.2) still; the closest exact
    distance it reaches and how many steps the guard shortened."""
    peer, goal, start = _goal_inside_peer(world)
    planner = NehmoPlanner(CELL, OWN, models, settings)
    q, closest = start.copy(), np.inf
    for _ in range(250):
        result = planner.plan(q, {PEER: peer}, goal, peer_bounds={PEER: 0.2})
        q = q + result.velocity * DT
        world.set_configuration({OWN: q, PEER: peer})
        closest = min(closest, world.distance(OWN, PEER))
    return closest, planner.guarded


@pytest.fixture(scope="module")
def models() -> list:
    return ModelRegistry().models_for("nehmo", CELL)


def test_the_guard_keeps_the_floor_where_the_learned_rows_would_not(
    world: CellWorld, models: list
) -> None:
    # a settled floor of 1 mm lets the learned rows run the arm into the held peer's geometry
    # (the contact guard, which would also stop it, is off: this is the exact guard's test)
    loose = PlannerSettings().override(
        {
            "hold.settled_epsilon": 1e-3,
            "exact_guard.gap": 0.0,
            "escape.enabled": False,
            "contact.clearance": 0.0,
        }
    )
    unguarded, _ = _closest(world, loose, models)
    assert unguarded < FLOOR - 0.01
    guarded, shortened = _closest(world, loose.override({"exact_guard.gap": FLOOR}), models)
    assert shortened > 0
    assert guarded >= FLOOR - 0.005  # discrete checks of a straight step


def test_the_guard_leaves_steps_alone_without_a_held_peer_or_when_off(world: CellWorld) -> None:
    settings = PlannerSettings().override({"exact_guard.gap": FLOOR})
    q, u = np.zeros(6), np.full(6, 0.5)
    assert guard_step(world, OWN, q, u, {}, settings) == 1.0
    assert (
        guard_step(world, OWN, q, u, {PEER: np.zeros(6)}, settings.override({"exact_guard.gap": 0}))
        == 1
    )
    with pytest.raises(InvalidValueError, match=r"exact_guard\.gap.*\[0, 1\]"):
        PlannerSettings().override({"exact_guard.gap": -0.01})


def test_a_step_that_opens_the_gap_passes_even_below_the_floor(world: CellWorld) -> None:
    peer, goal, start = _goal_inside_peer(world)
    settings = PlannerSettings().override({"exact_guard.gap": FLOOR})
    toward, away = (goal - start), (start - goal)
    step = 0.5 / np.abs(toward).max()  # full speed on the largest joint
    assert guard_step(world, OWN, goal, away * step, {PEER: peer}, settings) == 1.0
    assert guard_step(world, OWN, goal, toward * step, {PEER: peer}, settings) < 1.0


def test_a_holding_arm_withdraws_from_a_full_speed_peer_within_the_floor(
    world: CellWorld, models: list
) -> None:
    """The learned V under the settled margin can read high enough at 1–2 cm that a pressing
    peer never counts as a threat; the real geometry makes it one."""
    rng = np.random.default_rng(7)
    kept_without = 0
    poses = 0
    for _ in range(4000):
        peer, q = rng.uniform(-1.5, 1.5, 6), rng.uniform(-1.5, 1.5, 6)
        world.set_configuration({OWN: q, PEER: peer})
        if not 0.005 < world.distance(OWN, PEER) < FLOOR or _folded(world):
            continue
        assert closer_than(world, OWN, q, {PEER: peer}, FLOOR)
        assert not closer_than(world, OWN, q, {PEER: peer}, 0.004)
        bounds = []
        for guard in (0.0, FLOOR):
            settings = PlannerSettings().override(
                {"hold.settled_epsilon": 1e-3, "exact_guard.gap": guard, "opt.deadline": 3600.0}
            )
            planner = NehmoPlanner(CELL, OWN, models, settings)
            # at its goal, beside a peer that announces full speed
            bounds.append(planner.plan(q, {PEER: peer}, q, {PEER: 1.0}).telemetry.speed_bound)
        assert bounds[1] == 1.0  # withdrawn
        kept_without += bounds[0] < 1.0
        poses += 1
        if poses == 4:
            break
    assert poses == 4 and kept_without >= 1
