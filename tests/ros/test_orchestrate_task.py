"""``orchestrate run --task FILE``: a generated task becomes a cell YAML and a one-scenario set
that every node loads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.eval.task_generator import TaskSpec, write_tasks
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_ros.orchestrate import _assignment, _ros_param, build_parser, task_files
from nehmo_ros.suite_settings import SuiteSettings


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


def test_bridge_parameters_pass_through_and_unknown_ones_are_refused() -> None:
    args = build_parser().parse_args(
        ["run", "--bridge-param", "command_validity=0.2", "--bridge-param", "stop_on_success=false"]
    )
    assert [_assignment(t) for t in args.bridge_param] == [
        ("command_validity", 0.2),
        ("stop_on_success", False),
    ]
    assert _ros_param("plan_age=.inf") == "plan_age:=.inf"
    with pytest.raises(InvalidValueError, match="`--bridge-param` must be NAME=VALUE"):
        _assignment("command_validity")
    with pytest.raises(InvalidValueError, match="`bridge_params` must name sim_bridge parameters"):
        SuiteSettings(bridge_params=(("command_validty", 0.1),))
    assert SuiteSettings(bridge_params=(("command_validity", 0.1),)).bridge_params
    # a whole number for a float parameter is the float (ROS would refuse the integer)
    settings = SuiteSettings(bridge_params=(("physics_rate", 50), ("episode", 3)))
    assert settings.bridge_params == (("physics_rate", 50.0), ("episode", 3))
    assert type(settings.bridge_params[0][1]) is float


def test_a_layout_measured_to_miss_25_hz_gets_a_note() -> None:
    """Eight arms on 2 cores in eight processes, or at 100 Hz physics, get the measured
    advice; five arms, or eight composed at 50 Hz, get none."""
    from nehmo_ros.suite_settings import layout_hint

    assert layout_hint(5, SuiteSettings(), cores=2) == ""
    note = layout_hint(8, SuiteSettings(), cores=2)
    assert note.startswith("8 arms in 8 planner processes with 100 Hz physics on 2 cores")
    assert "--planner-processes 2 --physics-rate 50" in note
    assert layout_hint(8, SuiteSettings(planner_processes=2), cores=2)  # 100 Hz
    assert layout_hint(8, SuiteSettings(planner_processes=2, physics_rate=50.0), cores=2) == ""
    assert layout_hint(8, SuiteSettings(planner_processes=1, physics_rate=50.0), cores=2) == ""
    assert layout_hint(8, SuiteSettings(), cores=4) == ""
