"""``orchestrate run --task FILE``: a generated task becomes a cell YAML and a one-scenario set
that every node loads."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.eval.task_generator import TaskSpec, write_tasks
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_ros.orchestrate import task_files


def test_a_task_file_becomes_a_cell_and_a_scenario(tmp_path: Path) -> None:
    tasks = write_tasks(TaskSpec(arms=3), seed=5, count=1, out=tmp_path / "t")
    task = load_task(tasks[0])
    scenario_file = task_files(str(tasks[0]), tmp_path)
    scenarios = load_scenario_set(scenario_file)
    cell = load_cell(scenarios.cell)
    assert cell.arm_ids == task.cell.arm_ids
    for a, b in zip(cell.arms, task.cell.arms, strict=True):
        np.testing.assert_allclose(a.base.matrix(), b.base.matrix(), atol=1e-12)
        assert a.robot.name == b.robot.name
    (scenario,) = scenarios.scenarios
    for arm_id in cell.arm_ids:
        np.testing.assert_allclose(scenario.start[arm_id], task.scenario.start[arm_id])
        np.testing.assert_allclose(scenario.goal[arm_id], task.scenario.goal[arm_id])
