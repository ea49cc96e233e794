"""A cell of two Pandas (7 joints each) through the ROS 2 node suite: the bridge simulates the
Panda from its URDF, each planner loads it by name with the pair models ``nehmo pair build``
made, and the recorder logs it."""

from __future__ import annotations

from pathlib import Path

from _ros_testutil import DOMAIN_ID

from nehmo_core.eval.episode_log import read_episode_log
from nehmo_core.sim.scenario_files import draw_scenario_set, save_scenario_set
from nehmo_ros.suite import run_episode as run_ros_episode
from nehmo_ros.suite_settings import SuiteSettings


def test_the_node_suite_runs_a_dual_panda_episode(tmp_path: Path, colcon_install: Path) -> None:
    scenarios = save_scenario_set(draw_scenario_set("dual_panda", 7, 1), tmp_path / "s.json")
    settings = SuiteSettings(
        planner="nehmo",
        model="shipped",
        time_limit=6.0,
        domain_id=DOMAIN_ID,
        startup_timeout=300.0,  # each planner compiles the 15-D models on first use
        install_space=str(colcon_install),
    )
    run = run_ros_episode(scenarios, 0, tmp_path, settings)
    assert run.error == "", run.error
    assert run.result is not None and run.result.outcome != "collision"
    assert all(length > 0.1 for length in run.result.path_lengths.values())  # both arms moved
    log = read_episode_log(run.log)
    assert [a.robot.name for a in log.cell.arms] == ["panda", "panda"]
    assert all(a.robot.dof == 7 for a in log.cell.arms)
    planner_log = (run.log.parent / "logs" / run.log.name / "planner_panda_0.log").read_text()
    assert "panda_panda_any" in planner_log
