"""The contact guard: two Pandas that start 13 mm apart part with the guard; near contact the
guard never returns a step that closes the real gap; far apart it changes nothing.

With the first Panda build the learned fail-safe stepped these arms into each other when the
guard was off; the rebuilt pair (certified δ 9.6 cm) keeps them apart without it, so this
replay no longer shows the guard's need, and the random-command test is what can fail."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.pipeline import read_tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import Scenario

CELL = load_cell("dual_panda")
A, B = CELL.arm_ids
# Scenario 32 of the dual-Panda set with seed 62: a collision-free start 13 mm apart.
START = {
    A: [-2.69226291, 1.43083099, -0.89915762, -2.83388080, -0.07885560, 2.23294133, -1.39975814],
    B: [2.56366951, -0.74055545, -2.02355332, -1.73744617, -1.34278910, 2.40874661, -0.73350303],
}
GOAL = {
    A: [-1.83201227, -1.42826504, 1.11568121, -0.40073612, -1.38866593, 1.92346379, 1.41486326],
    B: [2.58526551, -1.19995578, 0.55931503, -1.02003908, 1.68264902, 1.08258821, -2.86063520],
}
SCENARIO = Scenario(
    {k: np.array(v) for k, v in START.items()}, {k: np.array(v) for k, v in GOAL.items()}
)
UNHURRIED = {"opt.deadline": 3600.0}


@pytest.fixture(scope="module")
def registry() -> ModelRegistry:
    return ModelRegistry()


def _inter_arm(clearance: float, registry: ModelRegistry) -> list:
    settings = PlannerSettings().override({**UNHURRIED, "contact.clearance": clearance})
    kinds = {a: "nehmo" for a in CELL.arm_ids}
    planners = build_planners(CELL, kinds, SCENARIO, 0.04, registry, settings)
    result = run_episode(CELL, SCENARIO, planners, EpisodeSettings(time_limit=2.0))
    return [c for c in result.collisions if c.arm_a != c.arm_b]


def test_the_start_is_collision_free_and_within_the_margin() -> None:
    with CellWorld(CELL) as world:
        world.set_configuration(SCENARIO.start)
        assert 0.0 < world.distance(A, B) < PlannerSettings().contact.clearance


def test_the_guard_parts_arms_that_start_in_contact(registry: ModelRegistry) -> None:
    assert _inter_arm(PlannerSettings().contact.clearance, registry) == []


def _planner(registry: ModelRegistry, **overrides: float) -> NehmoPlanner:
    settings = PlannerSettings().override({**UNHURRIED, **overrides})
    return NehmoPlanner(CELL, A, registry.models_for("nehmo", CELL), settings)


def _guarded(
    planner: NehmoPlanner, q: np.ndarray, peer: np.ndarray, u: np.ndarray, bound: float = 1.0
) -> np.ndarray:
    """The contact guard's command instead of ``u`` with the arm at ``q``, its peer at ``peer``
    (announcing ``bound``, a share of full speed)."""
    guard = next(f for f in planner._filters if f.name == "contact")
    tick = read_tick(planner, q, {B: peer}, SCENARIO.goal[A], {B: bound}, {B: bound})
    tick.rows = planner.rows(q)
    return guard.filter(tick, planner.current(tick.q, tick.peers, tick.bounds), u)


def test_near_contact_no_command_closes_the_real_gap(registry: ModelRegistry) -> None:
    """Random commands from that start: the guarded command's step (the peer still) ends no
    closer than the arms are now, and some commands are changed."""
    planner = _planner(registry)
    rng = np.random.default_rng(3)
    q, peer = SCENARIO.start[A], SCENARIO.start[B]
    changed = 0
    with CellWorld(CELL) as world:
        world.set_configuration({A: q, B: peer})
        now = world.distance(A, B)
        for _ in range(12):
            u = rng.uniform(-0.5, 0.5, CELL.arm(A).robot.dof)
            out = _guarded(planner, q, peer, u)
            changed += not np.array_equal(out, u)
            assert np.abs(out).max() <= planner.settings.opt.u_max + 1e-12
            world.set_joint_positions(A, q + planner.settings.opt.t_plan * out)
            assert world.distance(A, B) >= now - 1e-9
    assert changed > 0


def test_far_apart_it_changes_nothing(registry: ModelRegistry) -> None:
    u = np.full(CELL.arm(A).robot.dof, 0.3)
    out = _guarded(_planner(registry), SCENARIO.goal[A], SCENARIO.goal[B], u)
    assert np.array_equal(out, u)


def test_settings_are_checked_and_off_in_the_paper_preset() -> None:
    assert PlannerSettings.preset("paper").contact.clearance == 0.0
    with pytest.raises(InvalidValueError, match=r"contact\.clearance"):
        PlannerSettings().override({"contact.clearance": -0.01})


def test_a_holding_peer_keeps_the_holding_clearance(registry: ModelRegistry) -> None:
    """From the start 13 mm apart, random commands: against a peer that holds (bound 0.2) a
    step may close the gap down to ``holding_clearance`` (1 cm) but never below it, where
    against a full-speed peer no step closes it at all."""
    planner = _planner(registry, **{"contact.holding_clearance": 0.01})
    rng = np.random.default_rng(5)
    q, peer = SCENARIO.start[A], SCENARIO.start[B]
    t = planner.settings.opt.t_plan
    closer = 0
    with CellWorld(CELL) as world:
        world.set_configuration({A: q, B: peer})
        now = world.distance(A, B)
        assert 0.01 < now < planner.settings.contact.clearance
        for _ in range(16):
            u = rng.uniform(-0.5, 0.5, CELL.arm(A).robot.dof)
            for bound in (0.2, 1.0):
                out = _guarded(planner, q, peer, u, bound)
                world.set_joint_positions(A, q + t * out)
                end = world.distance(A, B)
                if bound < 1.0:
                    assert end >= 0.01 - 1e-9
                    closer += end < now - 1e-4
                else:
                    assert end >= now - 1e-9
    assert closer > 0  # some steps toward the holding peer are let through


def test_the_holding_clearance_is_at_most_the_clearance(registry: ModelRegistry) -> None:
    """A holding clearance above the clearance acts as the clearance: the guard against a
    holding peer then matches the guard against a full-speed one."""
    planner = _planner(registry, **{"contact.holding_clearance": 0.5})
    u = np.full(CELL.arm(A).robot.dof, 0.4)
    q, peer = SCENARIO.start[A], SCENARIO.start[B]
    held, free = _guarded(planner, q, peer, u, 0.2), _guarded(planner, q, peer, u, 1.0)
    assert np.array_equal(held, free)
