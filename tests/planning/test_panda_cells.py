"""The Panda (7 joints, every joint limited) through the planner with the pair models that
``nehmo pair build`` made: dual-Panda and UR5-Panda episodes in closed loop stay apart."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell, registry
from nehmo_core.sim.scenarios import generate_scenario_set

SEED = 7  # scenarios of this test only (evaluation seeds: docs/adding-a-robot.md)


def _cells() -> list[str]:
    have = set(registry.PAIR_NAMES)
    cells = []
    if "panda_panda_any" in have:
        cells.append("dual_panda")
    if {"ur5_panda_any", "panda_ur5_any"} <= have:
        cells.append("ur5_panda")
    return cells


def test_the_panda_pairs_ship() -> None:
    assert "panda_panda_any" in registry.PAIR_NAMES
    assert registry.arm_pair("panda_panda_any").domain == "limits"
    low, high = registry.pair_base_range("panda_panda_any")
    assert low <= 0.3 and high >= 1.95  # two Pandas touch up to 2 x 0.96 m apart


@pytest.mark.parametrize("cell_name", _cells())
def test_episodes_in_closed_loop_stay_apart_and_mostly_arrive(cell_name: str) -> None:
    cell = load_cell(cell_name)
    assert max(a.robot.dof for a in cell.arms) == 7
    scenarios = generate_scenario_set(cell, seed=SEED, count=3).scenarios
    unhurried = PlannerSettings().override({"opt.deadline": 3600.0})
    registry_ = ModelRegistry()
    reached = 0
    for scenario in scenarios:
        planners = build_planners(
            cell, {a: "nehmo" for a in cell.arm_ids}, scenario, 0.04, registry_, unhurried
        )
        result = run_episode(cell, scenario, planners, EpisodeSettings(time_limit=20.0))
        assert not [c for c in result.collisions if c.arm_a != c.arm_b]
        assert all(np.isfinite(e) for e in result.final_errors.values())
        reached += result.outcome == "success"
    assert reached >= 2
