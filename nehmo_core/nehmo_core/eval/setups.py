"""The evaluation setups of the paper (§ IV) and their planner rows.

A :class:`Setup` names a cell, its time limit, its success rule, the arms whose planning time
is reported (the centre arm of the three- and five-UR5 cells, like the paper) and an optional
scenario filter (the UR5-Kinova challenging set keeps scenarios where the naive planners
collide with each other). In the three- and five-UR5 cells the outer arms are 0.85 m or 1.2 m
apart; the shipped bc+sym pair models ``ur5_ur5_diag`` and ``ur5_ur5_opposite`` cover those
gaps, so ``nehmo`` and ``nehmo_paper`` constrain every pair. The other Opt rows (bc, DeepReach)
have a model for 0.6 m only: like the authors' planners, they constrain the pairs with the
centre arm, and the unconstrained peers are reported (telemetry, summaries). Collisions are
checked among all pairs regardless.

A *row* is one planner per arm, written ``nehmo`` (every arm) or ``nehmo/reckless`` (one kind
per arm, in the cell's arm order).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.factory import CENTRALIZED, DECENTRALIZED
from nehmo_core.planning.models.registry import OPT_KINDS
from nehmo_core.robots import Cell, load_cell
from nehmo_core.robots.loader import is_cell_file

__all__ = [
    "OPT_KINDS",
    "PLANNER_KINDS",
    "SETUPS",
    "SUCCESS_NORMS",
    "Setup",
    "get_setup",
    "parse_row",
    "row_slug",
]

PLANNER_KINDS = DECENTRALIZED + CENTRALIZED
SUCCESS_NORMS = ("l2", "max")
SCENARIO_FILTERS = ("naive_collides",)


@dataclass(frozen=True)
class Setup:
    """One evaluation setup: cell, time limit [s], success rule, timed arms, scenario filter."""

    name: str
    cell: str
    time_limit: float  # [s] of simulated time
    success_norm: str = "l2"  # wrapped joint-space error per arm: "l2" norm or "max" abs
    success_tolerance: float = 0.1  # [rad]
    timed_arms: tuple[str, ...] | None = None  # None: every arm
    scenario_filter: str | None = None
    unmodelled_peers_ok: bool = False  # 3/5-arm cells: models only ship at 0.6 m for bc, DeepReach
    description: str = ""
    # [m] the smallest exact distance between two arms with every arm at its goal (0: any
    # collision-free goal, the paper's protocol; its cells keep it)
    goal_separation: float = 0.0

    def __post_init__(self) -> None:
        if not self.time_limit > 0:
            raise InvalidValueError("time_limit", "must be > 0 [s]", self.time_limit)
        if self.success_norm not in SUCCESS_NORMS:
            raise UnknownNameError("success norm", self.success_norm, SUCCESS_NORMS)
        if not self.success_tolerance > 0:
            raise InvalidValueError("success_tolerance", "must be > 0", self.success_tolerance)
        if not self.goal_separation >= 0:
            raise InvalidValueError("goal_separation", "must be >= 0 [m]", self.goal_separation)
        if self.scenario_filter is not None and self.scenario_filter not in SCENARIO_FILTERS:
            raise UnknownNameError("scenario filter", self.scenario_filter, SCENARIO_FILTERS)

    def load_cell(self) -> Cell:
        return load_cell(self.cell)


GOAL_SEPARATION = 0.02
"""[m] How far apart the goals of the cells beyond the paper's (and of a user's cell file) are at
least: the smallest exact distance between two arms with every arm at its goal, as the crowd task
generator keeps them (``nehmo tasks generate``'s ``clearance``). Closer goals ask two arms to
rest within the 1 cm that planners keep from a settled peer and its real geometry."""

SETUPS: dict[str, Setup] = {
    s.name: s
    for s in (
        Setup("dual_ur5", "dual_ur5", 20.0, description="two UR5s 0.6 m apart (Table II)"),
        Setup(
            "triple_ur5",
            "triple_ur5",
            30.0,
            timed_arms=("ur5_0",),
            unmodelled_peers_ok=True,
            description="centre UR5 with neighbours at ±0.6 m in x (Table III)",
        ),
        Setup(
            "five_ur5",
            "five_ur5",
            30.0,
            success_norm="max",
            success_tolerance=0.03,
            timed_arms=("ur5_0",),
            unmodelled_peers_ok=True,
            description="centre UR5 with neighbours at ±0.6 m in x and y (Table III)",
        ),
        Setup(
            "ur5_kinova_challenging",
            "ur5_kinova",
            20.0,
            scenario_filter="naive_collides",
            description="UR5 + Kinova Gen3, scenarios where naive arms collide (Table IV)",
        ),
        Setup("ur5_kinova", "ur5_kinova", 20.0, description="UR5 + Kinova Gen3, random scenarios"),
        Setup(
            "dual_panda",
            "dual_panda",
            20.0,
            description="two Pandas 0.6 m apart, facing",
            goal_separation=GOAL_SEPARATION,
        ),
        Setup(
            "ur5_panda",
            "ur5_panda",
            20.0,
            description="UR5 + Panda 0.6 m apart, facing",
            goal_separation=GOAL_SEPARATION,
        ),
        Setup(
            "dual_kinova",
            "dual_kinova",
            20.0,
            description="two Kinova Gen3 (6-DoF) 0.6 m apart, facing",
            goal_separation=GOAL_SEPARATION,
        ),
        Setup(
            "mixed_three",
            "mixed_three",
            30.0,
            description="a UR5, a Kinova Gen3 and a Panda at irregular poses (0.79-0.83 m apart)",
            goal_separation=GOAL_SEPARATION,
        ),
        Setup(
            "triangle_ur5_kinova",
            "triangle_ur5_kinova",
            20.0,
            description="two UR5s and a Kinova in a triangle (1.8, 1.17, 1.24 m apart)",
            goal_separation=GOAL_SEPARATION,
        ),
        Setup(
            "mixed_four",
            "mixed_four",
            30.0,
            description="two UR5s and two Pandas at irregular poses (0.70-1.21 m apart)",
            goal_separation=GOAL_SEPARATION,
        ),
    )
}


USER_CELL_TIME_LIMIT = 20.0  # [s] a user's cell file: the paper's two-arm episode length


def get_setup(name: str) -> Setup:
    """The setup called ``name``, or for a cell file (``*.yaml``) a setup of that cell with the
    paper's two-arm rules (20 s, every arm within 0.1 rad L2 of its goal at once, named after the
    file's ``name``) and goals :data:`GOAL_SEPARATION` apart; raises listing the valid names."""
    if name in SETUPS:
        return SETUPS[name]
    if is_cell_file(name):
        cell = load_cell(name)
        return Setup(
            cell.name,
            name,
            USER_CELL_TIME_LIMIT,
            description=f"the cell of {name}",
            goal_separation=GOAL_SEPARATION,
        )
    raise UnknownNameError("setup", name, [*SETUPS, "<a cell file>.yaml"])


def parse_row(row: str, cell: Cell) -> dict[str, str]:
    """Planner kind per arm id of ``cell`` for a row ``kind`` or ``kind1/kind2/...``.

    Centralized planners (``chomp``, ``ompl``) plan every arm at once, so they cannot be mixed.
    """
    parts = [p.strip() for p in row.split("/")]
    for p in parts:
        if p not in PLANNER_KINDS:
            raise UnknownNameError("planner", p, PLANNER_KINDS)
    if len(parts) == 1:
        parts = parts * len(cell.arms)
    if len(parts) != len(cell.arms):
        raise InvalidValueError(
            "planners",
            f"must give one kind for every arm or one per arm {list(cell.arm_ids)} joined by '/'",
            row,
        )
    central = {p for p in parts if p in CENTRALIZED}
    if central and len(set(parts)) > 1:
        raise InvalidValueError(
            "planners", f"centralized {sorted(central)} plans every arm; it cannot be mixed", row
        )
    return dict(zip(cell.arm_ids, parts, strict=True))


def row_slug(row: str) -> str:
    """A file-name-safe form of a row label (``nehmo/reckless`` → ``nehmo+reckless``)."""
    return row.replace("/", "+")


def is_centralized(kinds: Mapping[str, str]) -> bool:
    return any(k in CENTRALIZED for k in kinds.values())
