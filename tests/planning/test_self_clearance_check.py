"""The self-clearance stage's exact check of each step's end, and its rows from where the
command starts.

In ``gen_7arm_s78_024`` (seven UR5s, tasks seed 78) ``ur5_0``, folded (elbow 2.76 rad), crept
through the rows' safety distance 0.5–1 mm per tick with every command on its rows, and its
wrist touched its upper arm at 9.88 s: the rows are linear, and the distance of that pair is not
(in wrist 2 it can have a ridge, so that a step up one side of it ends down the other). The
replay is deterministic and still touches with ``self_clearance.check`` 0. So does a Panda of
``mixed_four`` (seed 75, scenario 78), its hand on its own base at 2.6 s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.pipeline import read_tick
from nehmo_core.planning.opt.problem import project_step
from nehmo_core.planning.opt.tick import NO_PEERS
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.sim.scenario_files import load_scenario_set

DATA = Path(__file__).parents[1] / "data" / "self_contact"
TASK = DATA / "gen_7arm_s78_024.json"
# ur5_0 of that task at 9.60 s of the run that touched: wrist_3_link 2.3 mm from upper_arm_link
FOLDED = np.array([-1.5496736, -1.74180604, 2.75511026, -1.14050799, -1.5372209, 0.00078901])


def test_the_folded_arm_of_a_seven_arm_task_keeps_off_itself() -> None:
    task = load_task(TASK)
    settings = PlannerSettings().override({"opt.deadline": 3600.0})
    kinds = {a: "nehmo" for a in task.cell.arm_ids}
    planners = build_planners(task.cell, kinds, task.scenario, 0.04, ModelRegistry(), settings)
    result = run_episode(task.cell, task.scenario, planners, EpisodeSettings(time_limit=20.0))
    assert not result.collisions


def test_a_panda_of_the_mixed_cell_keeps_its_hand_off_its_base() -> None:
    scenario = load_scenario_set(DATA / "mixed_four_seed75_0078.json").scenarios[0]
    cell = load_cell("mixed_four")
    settings = PlannerSettings().override({"opt.deadline": 3600.0})
    kinds = {a: "nehmo" for a in cell.arm_ids}
    planners = build_planners(cell, kinds, scenario, 0.04, ModelRegistry(), settings)
    result = run_episode(cell, scenario, planners, EpisodeSettings(time_limit=5.0))
    assert not result.collisions


def _one_ur5() -> NehmoPlanner:
    cell = Cell("one_ur5", (ArmSpec("ur5_0", load_robot("ur5"), Pose()),))
    return NehmoPlanner(cell, "ur5_0", [], PlannerSettings())


def test_no_checked_step_ends_below_its_floor_where_rows_alone_let_some() -> None:
    """Random commands at the folded pose: every command the stage lets through ends each
    pair closer than ``check`` no lower than ``min(d, safety)`` after one tick; projected onto
    the rows alone, some do not."""
    planner = _one_ur5()
    stage = planner.stage("self_clearance")
    s = planner.settings
    tick = read_tick(planner, FOLDED, {}, np.zeros(6), {}, None)
    rows = stage.rows(FOLDED)
    near = {
        p: d for p, d in zip(rows.pairs, rows.distances, strict=True) if d < s.self_clearance.check
    }
    assert near, "the folded pose has a pair within the check distance"
    floors = {p: min(d, s.self_clearance.safety) for p, d in near.items()}

    def lowest(u: np.ndarray) -> float:
        ends = stage.distances(FOLDED + s.opt.tick * u)
        return min(ends.get(p, np.inf) - floors[p] for p in near)

    rng = np.random.default_rng(11)
    below_on_rows, changed = 0, 0
    for _ in range(60):
        u = rng.uniform(-s.opt.u_max, s.opt.u_max, 6)
        on_rows = project_step(s.opt.t_plan * u, rows, s.opt.t_plan * s.opt.u_max) / s.opt.t_plan
        below_on_rows += lowest(on_rows) < -1e-5
        out = stage.filter(tick, NO_PEERS, on_rows)
        changed += not np.array_equal(out, on_rows)
        assert lowest(out) >= -2e-6
    assert below_on_rows > 0
    assert changed >= below_on_rows
    planner.close()


def test_rows_are_built_where_the_command_in_flight_takes_the_arm() -> None:
    planner = _one_ur5()
    stage = planner.stage("self_clearance")
    in_flight = np.array([0.0, 0.0, 0.5, 0.0, 0.5, 0.0])
    planner.commanded(in_flight)
    ahead = FOLDED + planner.settings.opt.tick * in_flight
    np.testing.assert_array_equal(planner.ahead(FOLDED), ahead)
    np.testing.assert_allclose(planner.rows(FOLDED).A, stage.rows(ahead).A)
    off = PlannerSettings().override({"self_clearance.ahead": False})
    assert NehmoPlanner(planner.cell, "ur5_0", [], off).ahead(FOLDED) is FOLDED
    planner.close()


def test_the_check_setting_is_checked_and_off_with_the_stage() -> None:
    with pytest.raises(InvalidValueError, match=r"self_clearance\.check"):
        PlannerSettings().override({"self_clearance.check": -0.01})
    paper = NehmoPlanner(_one_ur5().cell, "ur5_0", [], PlannerSettings.preset("paper"))
    assert all(f.name != "self_clearance" for f in paper._filters)
