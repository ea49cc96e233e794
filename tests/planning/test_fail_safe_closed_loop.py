"""The paper's fail-safe in five-UR5 scenarios where an earlier multi-peer fail-safe collided.

Fresh-seed five-UR5 scenarios (tables of seeds 34, 35 and 41) in which an arm between two peers
drove into one of them on the maximin fail-safe this planner once had (plain, then
lexicographic). That stage was removed after the ablation (``docs/ablation.md``); with the
paper's ``ū·sign(∂V/∂q¹)`` and the other stages of today's defaults no arm touches another.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set

SANDWICHED = Path(__file__).parents[1] / "data" / "sandwiched"


@pytest.mark.parametrize(
    "name", ["five_ur5_seed34_0076", "five_ur5_seed35_0061", "five_ur5_seed41_0045"]
)
def test_five_arms_where_an_earlier_fail_safe_collided_stay_apart(name: str) -> None:
    scenario = load_scenario_set(SANDWICHED / f"{name}.json").scenarios[0]
    cell = load_cell("five_ur5")
    unhurried = PlannerSettings().override({"opt.deadline": 3600.0})
    planners = build_planners(
        cell, {a: "nehmo" for a in cell.arm_ids}, scenario, 0.04, ModelRegistry(), unhurried
    )
    result = run_episode(cell, scenario, planners, EpisodeSettings(time_limit=10.0))
    assert not [c for c in result.collisions if c.arm_a != c.arm_b]
