"""A cell YAML with three UR5s at irregular poses, through the ROS 2 node suite and the batch
runner: bridge, three planners and the recorder as separate rclpy processes loading the cell
from its file, every pair planned with the pose-conditioned value function."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _ros_testutil import DOMAIN_ID

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.episode_log import read_episode_log
from nehmo_core.eval.metrics import EpisodeResult, goal_distance
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import draw_scenario_set, load_scenario_set, save_scenario_set
from nehmo_core.sim.scenarios import Scenario
from nehmo_ros.suite import run_episode as run_ros_episode
from nehmo_ros.suite_settings import SuiteSettings

CELL_FILE = Path(__file__).resolve().parents[2] / "examples" / "cells" / "irregular_three_ur5.yaml"
CELL = load_cell(CELL_FILE)


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    scenarios = draw_scenario_set(str(CELL_FILE), 0, 1)
    return save_scenario_set(scenarios, tmp_path_factory.mktemp("irregular") / "scenarios.json")


def assert_the_arms_made_progress(result: EpisodeResult, scenario: Scenario) -> None:
    """No collision is not enough (arms that never move have none): every arm moved, and at
    least two of the three ended within half their start distance of their goals (in this
    crowded scenario one arm may stay blocked by the others until the time limit)."""
    assert result.outcome != "collision", result.collisions
    assert set(result.path_lengths) == set(CELL.arm_ids)
    assert all(length > 0.2 for length in result.path_lengths.values()), result.path_lengths
    start = {
        a: goal_distance(scenario.start[a], scenario.goal[a], CELL, a, "l2") for a in CELL.arm_ids
    }
    assert all(d > 0.5 for d in start.values()), start  # every goal is a real move away
    closer = [a for a in CELL.arm_ids if result.final_errors[a] < 0.5 * start[a]]
    assert len(closer) >= 2, (start, result.final_errors)


def test_the_scenario_file_names_the_cell_file(scenario_file: Path) -> None:
    assert load_scenario_set(scenario_file).cell == str(CELL_FILE)


def test_batch_runner_plans_every_pair_and_stays_collision_free(scenario_file: Path) -> None:
    scenario = load_scenario_set(scenario_file).scenarios[0]
    kinds = dict.fromkeys(CELL.arm_ids, "nehmo")
    unhurried = PlannerSettings().override(
        {"opt.deadline": 3600.0}
    )  # no solve is cut short on a loaded machine
    planners = build_planners(CELL, kinds, scenario, 0.04, ModelRegistry(), unhurried)
    for planner in planners.values():
        assert len(planner.pairs) == 2 and not planner.peers_unmodelled  # type: ignore[attr-defined]
    result = run_episode(CELL, scenario, planners, EpisodeSettings(time_limit=8.0), kinds=kinds)
    assert_the_arms_made_progress(result, scenario)
    # lock-step and unhurried: the two arms that get through reach their goals
    reached = [
        a for a, err in result.final_errors.items() if err < EpisodeSettings().success_tolerance
    ]
    assert len(reached) >= 2, result.final_errors


def test_the_node_suite_runs_the_yaml_cell(scenario_file: Path, colcon_install: Path) -> None:
    settings = SuiteSettings(
        planner="nehmo",
        model="shipped",
        time_limit=6.0,
        domain_id=DOMAIN_ID,
        startup_timeout=300.0,  # three planners compile the conditioned model on first use
        install_space=str(colcon_install),
    )
    run = run_ros_episode(scenario_file, 0, scenario_file.parent, settings)
    assert run.error == "", run.error
    assert run.result is not None
    assert_the_arms_made_progress(run.result, load_scenario_set(scenario_file).scenarios[0])
    commands = json.loads((run.log.parent / "logs" / run.log.name / "commands.json").read_text())
    assert {"planner_ur5_0", "planner_ur5_1", "planner_ur5_2"} <= set(commands)
    nodes = {k: v for k, v in commands.items() if k != "lifecycle_manager"}  # it loads no cell
    assert all(str(CELL_FILE) in " ".join(argv) for argv in nodes.values())
    log = read_episode_log(run.log)
    assert [a.base for a in log.cell.arms] == [a.base for a in CELL.arms]
    planner_log = (run.log.parent / "logs" / run.log.name / "planner_ur5_0.log").read_text()
    assert "ur5_ur5_any" in planner_log
