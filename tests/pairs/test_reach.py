"""One reach rule: the peers a planner constrains are exactly the base distances the shipped
pair models cover, and the reach stated in each robot description is what the geometry gives."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from nehmo_core.pairs.reach import (
    MIN_BASE_DISTANCE,
    arm_reach,
    base_range,
    can_touch,
    horizontal_reach,
)
from nehmo_core.planning.models.pair_frame import constrained_pairs
from nehmo_core.robots import registry
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose

SHIPPED_ROBOTS = ("ur5", "panda", "kinova_gen3_6dof")


@pytest.mark.parametrize("name", SHIPPED_ROBOTS)
def test_stated_reach_is_the_measured_reach(name: str) -> None:
    robot = load_robot(name)
    assert robot.facts.reach_m is not None
    measured = horizontal_reach(robot)
    # never below what the geometry reaches, and not padded beyond rounding
    assert measured <= robot.facts.reach_m + 1e-3
    assert robot.facts.reach_m - measured < 0.01


def test_reach_search_finds_a_stretched_arm() -> None:
    # the UR5's collision geometry stretched out horizontally: shoulder offset, both long links
    # and the wrist, about 0.97 m from the base axis; random draws alone fall short of it
    robot = load_robot("ur5")
    searched = horizontal_reach(robot, samples=500, seed=3)
    drawn = horizontal_reach(robot, samples=500, seed=3, climb=0)
    assert 0.95 < searched < 1.0
    assert searched >= drawn


def _conditioned_ranges() -> dict[tuple[str, str], list[tuple[float, float]]]:
    """(robot 1, robot 2) → base ranges of the conditioned pairs whose models are present."""
    out: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for name, robots in registry.CONDITIONED_PAIRS.items():
        if registry.model_file(name, f"distance_{name}.json").exists():
            out.setdefault(robots, []).append(registry.pair_base_range(name))
    return out


KNOWN_GAPS: dict[tuple[str, str], float] = {}
"""Robot pairs whose conditioned models stop short of their reach: where they stop [m] (README,
Limitations; at ``MIN_BASE_DISTANCE``: no model at all); the planner reports such a peer as
unmodelled and does not plan beside it."""


def test_every_pair_that_can_touch_is_covered_by_a_model() -> None:
    ranges = _conditioned_ranges()
    for a, b in itertools.combinations_with_replacement(SHIPPED_ROBOTS, 2):
        found = [r for key in {(a, b), (b, a)} for r in ranges.get(key, [])]  # none: no model
        reach = base_range(arm_reach(load_robot(a)), arm_reach(load_robot(b)))[1]
        covered = MIN_BASE_DISTANCE
        for low, high in sorted(found):
            if low <= covered:
                covered = max(covered, high)
        said = (
            f"{a}-{b}: models cover {MIN_BASE_DISTANCE}-{covered} m; the arms touch up to {reach}"
        )
        gap = KNOWN_GAPS.get((a, b), KNOWN_GAPS.get((b, a)))
        if gap is not None:
            assert covered == pytest.approx(gap) and covered < reach, said
        else:
            assert covered >= reach - 1e-9, said


def _pair_at(gap: float, robot: str = "ur5", tilt: float = 0.0) -> Cell:
    r = load_robot(robot)
    return Cell(
        "two",
        (
            ArmSpec("a", r, Pose()),
            ArmSpec("b", r, Pose((gap / np.sqrt(2), gap / np.sqrt(2), 0.4), (tilt, 0.0, 2.0))),
        ),
    )


def test_planner_constrains_exactly_the_peers_that_can_touch() -> None:
    ur5 = load_robot("ur5")
    limit = base_range(arm_reach(ur5), arm_reach(ur5))[1]
    # a model covering only near bases: a peer in reach beyond it is reported unmodelled,
    # a peer beyond the reach is skipped, whatever the height difference
    near_only = [("ur5", "ur5", Pose(), (0.25, 1.0))]
    for gap, expect in ((limit - 0.001, "unmodelled"), (limit + 0.001, "skipped")):
        cell = _pair_at(gap)
        assert can_touch(*cell.arms) == (expect == "unmodelled")
        pairs, skipped, unmodelled = constrained_pairs(cell, "a", near_only, 0.0)
        assert (skipped, unmodelled) == ((("b",), ()) if expect == "skipped" else ((), ("b",)))
        assert not pairs
    # a base that does not stand upright is never skipped
    tilted = _pair_at(limit + 1.0, tilt=0.3)
    assert can_touch(*tilted.arms)
    # an extra margin widens the rule
    assert can_touch(*_pair_at(limit + 0.05).arms, margin=0.1)


@pytest.mark.parametrize("pair", list(itertools.combinations_with_replacement(SHIPPED_ROBOTS, 2)))
def test_the_rule_is_symmetric(pair: tuple[str, str]) -> None:
    a, b = (load_robot(n) for n in pair)
    one = ArmSpec("a", a, Pose())
    two = ArmSpec("b", b, Pose((1.99, 0.0, 0.0), (0.0, 0.0, 1.0)))
    assert can_touch(one, two) == can_touch(two, one)
