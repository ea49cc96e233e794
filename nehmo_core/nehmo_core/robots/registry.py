"""The one registry of robot and arm-pair facts: whatever NeHMO knows about a robot, or a pair
of robots, by name. Code outside :mod:`nehmo_core.robots` reads robot facts from the model
(``robot.facts``, attached by :func:`~nehmo_core.robots.loader.load_robot`) and pair facts from
here; it names no robot itself (``tests/test_robot_names.py`` checks that).

* a robot is its description file (:mod:`nehmo_core.robots.descriptions`): where its URDF comes
  from, its tip link and its :class:`~nehmo_core.robots.model.RobotFacts` (learned-distance
  keypoints, CHOMP's sphere radius, the evaluation protocol's joint sampling ranges);
  :func:`robot_facts` reads them.
* :data:`ARM_PAIRS`: the named arm pairs, i.e. the learned distances and HJI games, each with
  its robots (controlled robot first), its frame (arms of a shipped cell, arm 2 at any base
  distance, or another pair seen from its second arm) and which of its models ship.
* :data:`HA_BENCHMARK_ROBOT`: the robot of Ha et al.'s benchmark tasks.
"""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.robots.descriptions import DATA_DIR, description_paths, load_description
from nehmo_core.robots.model import RobotFacts

__all__ = [
    "ARM_PAIRS",
    "CONDITIONED_PAIRS",
    "FIXED_PAIRS",
    "HA_BENCHMARK_ROBOT",
    "PAIR_NAMES",
    "ROBOT_NAMES",
    "SWAPPED_PAIRS",
    "ArmPair",
    "distance_pairs",
    "pairs_by_robots",
    "robot_facts",
    "synthetic_pairs",
    "value_variants",
]

UR5 = "ur5"
KINOVA = "kinova_gen3_6dof"
PLANAR = "planar_2link"


ROBOT_NAMES: tuple[str, ...] = tuple(sorted(p.parent.name for p in DATA_DIR.glob("*/robot.yaml")))
"""The shipped robots (``robots/data/<name>/robot.yaml``; more: ``NEHMO_ROBOTS``)."""

HA_BENCHMARK_ROBOT = UR5
"""The robot of Ha et al.'s multi-arm benchmark (their task files hold its joint vectors)."""


def robot_facts(name: str) -> RobotFacts:
    """The facts of robot ``name``'s description (none for a robot that has no description)."""
    path = description_paths().get(name)
    return RobotFacts() if path is None else load_description(path).facts


SHIPPED = "shipped"
OPTIONAL = "optional"


@dataclass(frozen=True)
class ArmPair:
    """A named arm pair: a learned distance, an HJI game, or both.

    Its frame is one of: ``cell = (cell, arm 1, arm 2)``, two arms of a shipped cell;
    ``conditioned``, arm 1 at the origin and arm 2 at ``(r, 0, 0)`` facing it for any base
    distance ``r`` (a model input); ``swapped``, the named pair seen from its arm 2 (this pair's
    arm 1), reusing its learned distance. ``distance`` says whether its own learned distance
    ships (``shipped``), has a code path but no weights yet (``optional``) or does not exist
    (None); ``values`` / ``optional_values`` are the value-function variants that ship / that
    count as shipped once trained and copied to ``models/``.
    """

    name: str
    robots: tuple[str, str]
    cell: tuple[str, str, str] | None = None
    conditioned: bool = False
    swapped: str | None = None
    distance: str | None = None
    values: tuple[str, ...] = ()
    optional_values: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        frames = (self.cell is not None) + self.conditioned + (self.swapped is not None)
        if frames != 1:
            raise ValueError(f"arm pair {self.name}: needs one of cell, conditioned, swapped")
        if self.swapped is not None and self.distance is not None:
            raise ValueError(f"arm pair {self.name}: reuses {self.swapped}'s distance")


ARM_PAIRS: tuple[ArmPair, ...] = (
    # Order matters: per (robot 1, robot 2), planners try the fixed base distances first, in
    # this order, then the conditioned pair (see pairs_by_robots).
    ArmPair(
        "ur5_ur5",
        (UR5, UR5),
        cell=("dual_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym", "bc", "deepreach"),
    ),
    ArmPair(  # 0.849 m: the diagonal neighbours of the five-UR5 cell
        "ur5_ur5_diag",
        (UR5, UR5),
        cell=("diagonal_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair(  # 1.2 m: the outer arms of the three- and five-UR5 cells facing each other
        "ur5_ur5_opposite",
        (UR5, UR5),
        cell=("opposite_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair(
        "ur5_kinova",
        (UR5, KINOVA),
        cell=("ur5_kinova", "ur5_0", "kinova_0"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair("kinova_ur5", (KINOVA, UR5), swapped="ur5_kinova", values=("bc+sym",)),
    ArmPair("ur5_ur5_any", (UR5, UR5), conditioned=True, distance=SHIPPED, values=("bc+sym",)),
    ArmPair(
        "ur5_kinova_any",
        (UR5, KINOVA),
        conditioned=True,
        distance=OPTIONAL,
        optional_values=("bc+sym",),
    ),
    ArmPair("kinova_ur5_any", (KINOVA, UR5), swapped="ur5_kinova_any", optional_values=("bc+sym",)),
)
PAIR_NAMES: tuple[str, ...] = tuple(p.name for p in ARM_PAIRS)

FIXED_PAIRS: dict[str, tuple[str, str, str]] = {p.name: p.cell for p in ARM_PAIRS if p.cell}
"""Pair name → (cell, arm 1, arm 2) of the pairs in a shipped cell."""
CONDITIONED_PAIRS: dict[str, tuple[str, str]] = {
    p.name: p.robots for p in ARM_PAIRS if p.conditioned
}
"""Pair name → (robot 1, robot 2) of the pairs conditioned on the base distance."""
SWAPPED_PAIRS: dict[str, str] = {p.name: p.swapped for p in ARM_PAIRS if p.swapped}
"""Pair name → the pair whose learned distance it reuses with the arms' roles exchanged."""


def distance_pairs(status: str) -> tuple[str, ...]:
    """Pairs whose own learned distance is ``shipped`` or ``optional`` (registry order)."""
    return tuple(p.name for p in ARM_PAIRS if p.distance == status)


def value_variants(status: str) -> dict[str, tuple[str, ...]]:
    """Pair → value-function variants that are ``shipped`` or ``optional`` (registry order)."""
    return {
        p.name: variants
        for p in ARM_PAIRS
        if (variants := p.values if status == SHIPPED else p.optional_values)
    }


def pairs_by_robots() -> dict[tuple[str, str], tuple[str, ...]]:
    """(controlled robot, other robot) → its pairs in registry order (the order planners try
    them in: the fixed base distances, then any distance)."""
    out: dict[tuple[str, str], tuple[str, ...]] = {}
    for p in ARM_PAIRS:
        out[p.robots] = (*out.get(p.robots, ()), p.name)
    return out


def synthetic_pairs() -> dict[tuple[str, str], str]:
    """(controlled robot, other robot) → its first pair in a shipped cell: the learned-distance
    cell that a synthetic stand-in value model is built on."""
    out: dict[tuple[str, str], str] = {}
    for p in ARM_PAIRS:
        if p.cell is not None:
            out.setdefault(p.robots, p.name)
    return out
