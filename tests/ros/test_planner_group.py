"""Several arm planners in one process (``arm_planners``, ``orchestrate --planner-processes``).

A dual-UR5 episode (the one of ``test_e2e_suite.py``, where the naive planner collides) runs
through the node suite with both planner nodes in one process, each still its own node with its
own topics, lifecycle and solve worker: the lifecycle manager brings up both nodes by name,
every arm is planned for every tick of the episode and the outcome is the batch runner's. Bad
group parameters stop the process with one line.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from _ros_testutil import (
    DOMAIN_ID,
    E2E_CELL,
    E2E_INDEX,
    child_env,
    e2e_batch_reference,
    e2e_scenarios,
    in_process,
    spin_until,
)

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots import load_cell
from nehmo_ros.planner_group import group_members
from nehmo_ros.suite import EpisodeRun, planner_commands
from nehmo_ros.suite import run_episode as run_ros_episode
from nehmo_ros.suite_settings import SuiteSettings

CELL = load_cell(E2E_CELL)
INDEX = E2E_INDEX


def test_arms_are_dealt_in_order_to_the_planner_processes() -> None:
    kinds = {"a": "nehmo", "b": "naive", "c": "nehmo"}
    alone = planner_commands(kinds, "triple_ur5", SuiteSettings())
    assert [name for name, _ in alone] == ["planner_a", "planner_b", "planner_c"]
    assert all("__node:=arm_planner_" + n[-1] in argv for n, argv in alone)
    grouped = planner_commands(kinds, "triple_ur5", SuiteSettings(planner_processes=2))
    assert [name for name, _ in grouped] == ["planners_0", "planners_1"]
    first, second = (argv for _, argv in grouped)
    assert "nehmo_ros.planner_group" in first
    assert "arm_ids:=[a,b]" in first and "planners:=nehmo/naive" in first
    assert "arm_ids:=[c]" in second and "planners:=nehmo" in second
    assert not any(a.startswith("__node:=") for a in first)
    # more processes than arms: one per arm
    assert len(planner_commands(kinds, "triple_ur5", SuiteSettings(planner_processes=9))) == 3


def test_bad_group_parameters_are_refused_with_their_name() -> None:
    assert group_members(["x", "y"], "") == {"x": {"arm_id": "x"}, "y": {"arm_id": "y"}}
    assert group_members(["x"], "naive")["x"] == {"arm_id": "x", "planner": "naive"}
    with pytest.raises(InvalidValueError, match="`arm_ids` must name at least one arm"):
        group_members([""], "")
    with pytest.raises(InvalidValueError, match="`arm_ids` must not repeat an arm"):
        group_members(["x", "x"], "")
    with pytest.raises(InvalidValueError, match="`planners` must give one kind per arm"):
        group_members(["x", "y"], "nehmo")
    with pytest.raises(InvalidValueError, match="`planner_processes` must be >= 0"):
        SuiteSettings(planner_processes=-1)


def test_a_bad_node_parameter_names_the_arm_in_one_line() -> None:
    args = ["--ros-args", "-p", "arm_ids:=[ur5_0,ur5_1]", "-p", "cell:=dual_ur5", "-p", "rate:=0.0"]
    proc = subprocess.run(
        [sys.executable, "-m", "nehmo_ros.planner_group", *args],
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.strip() and "pybullet build time" not in x]
    expected = "arm_planners: error: arm 'ur5_0': `rate` must lie in [0.001, 1000]; got 0.0"
    assert lines == [expected], lines


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return e2e_scenarios(tmp_path_factory.mktemp("group"))


@pytest.fixture(scope="module")
def grouped(scenario_file: Path) -> EpisodeRun:
    settings = SuiteSettings(
        planner="nehmo",
        model="synthetic",
        domain_id=DOMAIN_ID,
        startup_timeout=240.0,  # generous: a loaded CI machine starts processes slowly
        planner_processes=1,
    )
    return run_ros_episode(scenario_file, INDEX, scenario_file.parent, settings)


def test_two_planner_nodes_in_one_process_run_the_episode(grouped: EpisodeRun) -> None:
    run = grouped
    assert run.error == "", run.error
    assert set(run.exit_codes) == {"recorder", "planners_0", "sim_bridge"}
    assert all(code == 0 for code in run.exit_codes.values()), run.exit_codes
    logs = run.log.parent / "logs" / run.log.name
    managed = (logs / "lifecycle_manager.log").read_text()
    said = (logs / "planners_0.log").read_text()
    for arm_id in CELL.arm_ids:
        assert f"arm_planner_{arm_id}: activated" in managed
        assert f"arm_planner_{arm_id}: stopped; counts" in said  # each node stopped on its own
    result = run.result
    assert set(result.plan_times) == set(CELL.arm_ids)
    assert all(len(t) > 50 for t in result.plan_times.values())  # every arm kept planning
    assert not result.collisions


def test_the_grouped_episode_ends_as_the_batch_runner_does(
    grouped: EpisodeRun, scenario_file: Path
) -> None:
    batch = e2e_batch_reference(scenario_file)
    assert batch.outcome == grouped.result.outcome == "success"


def test_nodes_of_one_process_send_every_command_of_a_tick_before_any_solve_or_report(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two planner nodes in one process ticked by one simulated clock: in every tick, both
    commands go out before either node starts its solve or publishes its status, on the
    executor the nodes run in (``events``)."""
    import rclpy.node
    from rosgraph_msgs.msg import Clock

    from nehmo_ros.arm_planner import ArmPlannerNode
    from nehmo_ros.node_support import make_executor

    monkeypatch.delenv("NEHMO_EXECUTOR", raising=False)
    params = ["cell:=dual_ur5", "planner:=naive", "use_sim_time:=true"]
    with in_process("arm_planners", params):
        executor = make_executor()
        nodes = [ArmPlannerNode(f"arm_planner_{a}", {"arm_id": a}) for a in CELL.arm_ids]
        clock = rclpy.node.Node("clock")
        clock_pub = clock.create_publisher(Clock, "/clock", 10)
        events: list[tuple[int, str, str]] = []  # (tick stamp [ns], what, arm)

        def logged(what: str, node: Any, call: Any) -> Any:
            def wrapped(*args: Any) -> Any:
                events.append((node.controller.last_observation.stamp_ns, what, node.arm_id))
                return call(*args)

            return wrapped

        for node in nodes:
            monkeypatch.setattr(node, "_send", logged("send", node, node._send))
            solve = logged("solve", node, node.controller.start_solve)
            monkeypatch.setattr(node.controller, "start_solve", solve)
            executor.add_node(node)
        executor.add_node(clock)
        try:
            for k in range(1, 13):  # the clock steps 20 ms, ticks are due every 40 ms
                msg = Clock()
                msg.clock.sec, msg.clock.nanosec = divmod(k * 20_000_000, 1_000_000_000)
                clock_pub.publish(msg)
                spin_until(executor, 0.3)
        finally:
            for node in [*nodes, clock]:
                executor.remove_node(node)
                node.destroy_node()
            executor.shutdown()
    ticks = sorted({t for t, _, _ in events})
    assert len(ticks) >= 4, events
    for tick in ticks:
        these = [(what, arm) for t, what, arm in events if t == tick]
        assert sorted(these) == sorted(
            [("send", a) for a in CELL.arm_ids] + [("solve", a) for a in CELL.arm_ids]
        ), these
        assert [w for w, _ in these] == ["send", "send", "solve", "solve"], these
