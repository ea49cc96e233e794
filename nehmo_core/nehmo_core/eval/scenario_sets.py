"""Scenario sets of the evaluation setups, generated once per seed and kept as JSON files.

Scenario ``i`` of the set with seed ``s`` is drawn by the paper's protocol from
:func:`nehmo_core.sim.scenarios.scenario_rng` (seed 0: the authors' draws). The UR5-Kinova
challenging set keeps, like the authors, the first candidates in which the naive planner on every
arm ends in a collision *between the arms* (a naive self-collision does not qualify), run by the
same episode runner and rules as the evaluation, so its Naive / Naive row collides in every
episode by construction. The cells beyond the paper's keep their goals
:data:`~nehmo_core.eval.setups.GOAL_SEPARATION` apart (``Setup.goal_separation``): a candidate
whose goals are closer is skipped, so scenario ``i`` stays candidate ``i`` until the first skip.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from nehmo_core.errors import UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.setups import SCENARIO_FILTERS, Setup
from nehmo_core.geometry.pybullet_world import DEFAULT_CUTOFF, CellWorld
from nehmo_core.planning.baselines.naive import NaivePlanner
from nehmo_core.robots.loader import is_cell_file
from nehmo_core.robots.model import Cell
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenario_files import load_scenario_set, save_scenario_set
from nehmo_core.sim.scenarios import SAMPLING_REVISION, Scenario, ScenarioSet, generate_scenario_set

__all__ = [
    "goal_separation",
    "goals_apart",
    "naive_collides",
    "scenario_set_for",
    "scenario_set_path",
]


def naive_collides(
    cell: Cell, settings: EpisodeSettings, sim: CellSimulator
) -> Callable[[Scenario], bool]:
    """A filter: true when the naive planner on every arm ends in an inter-arm collision.

    The authors' challenging set holds the naive planner's inter-arm collision trials; an episode
    that ends in a self-collision alone is not one.
    """
    planners = {a: NaivePlanner(cell, a) for a in cell.arm_ids}

    def accept(scenario: Scenario) -> bool:
        result = run_episode(cell, scenario, planners, settings, simulator=sim)
        return result.outcome == "collision" and any(c.arm_a != c.arm_b for c in result.collisions)

    return accept


def goal_separation(
    world: CellWorld, goal: Mapping[str, np.ndarray], cutoff: float = DEFAULT_CUTOFF
) -> float:
    """The smallest exact distance [m] between two arms with every arm at its ``goal``
    (``world`` the cell's; ``cutoff`` when every pair is farther apart than it)."""
    world.set_configuration(goal)
    ids = list(goal)
    return min(world.distance(a, b, cutoff) for i, a in enumerate(ids) for b in ids[i + 1 :])


def goals_apart(world: CellWorld, separation: float) -> Callable[[Scenario], bool]:
    """A filter: true when :func:`goal_separation` is at least ``separation`` [m]."""

    def accept(scenario: Scenario) -> bool:
        return goal_separation(world, scenario.goal, separation + 0.01) >= separation

    return accept


def scenario_set_path(directory: str | Path, setup: Setup, seed: int) -> Path:
    return Path(directory) / f"{setup.name}_seed{seed}.json"


def scenario_set_for(
    setup: Setup,
    seed: int,
    count: int,
    directory: str | Path | None = None,
    max_candidates: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ScenarioSet:
    """The first ``count`` scenarios of ``setup``'s set with ``seed``.

    With ``directory``, a saved set with at least ``count`` scenarios drawn by the current
    sampling revision is reused (a shorter or older one is regenerated) and a new set is saved
    there.
    """
    path = scenario_set_path(directory, setup, seed) if directory is not None else None
    if path is not None and path.exists():
        saved = load_scenario_set(path)
        if (
            saved.meta.get("setup") == setup.name
            and saved.meta.get("sampling") == SAMPLING_REVISION
            and saved.meta.get("goal_separation", 0.0) == setup.goal_separation
            and len(saved) >= count
        ):
            return saved.head(count)
    cell = setup.load_cell()
    settings = EpisodeSettings.for_setup(setup)
    meta = {
        "setup": setup.name,
        "filter": setup.scenario_filter,
        "sampling": SAMPLING_REVISION,
        "goal_separation": setup.goal_separation,
    }
    with ExitStack() as stack:
        tests = []
        if setup.goal_separation > 0:
            world = stack.enter_context(CellWorld(cell))
            tests.append(goals_apart(world, setup.goal_separation))
        if setup.scenario_filter == "naive_collides":
            sim = CellSimulator(cell, settings.substeps, settings.self_collision)
            tests.append(naive_collides(cell, settings, stack.enter_context(sim)))
        elif setup.scenario_filter is not None:
            raise UnknownNameError("scenario filter", setup.scenario_filter, SCENARIO_FILTERS)

        def accept(scenario: Scenario) -> bool:
            return all(test(scenario) for test in tests)  # the cheap test first

        made = generate_scenario_set(
            cell, seed, count, accept if tests else None, max_candidates, meta, progress
        )
    if is_cell_file(setup.cell):  # a user's cell: its file, which loads anywhere
        made = dataclasses.replace(made, cell=str(Path(setup.cell).resolve()))
    if path is not None:
        save_scenario_set(made, path)
    return made
