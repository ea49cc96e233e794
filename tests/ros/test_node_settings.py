"""Node parameters named like planner settings reach the planner, and a bad one is rejected with
its name: the arm_planner node built in process from parameters as ``ros2 run`` builds it."""

from __future__ import annotations

import pytest
from _ros_testutil import in_process

from nehmo_core.errors import InvalidValueError
from nehmo_ros.arm_planner import ArmPlannerNode

BASE = ["cell:=dual_ur5", "arm_id:=ur5_0", "planner:=nehmo"]


def test_planner_settings_given_as_node_parameters_reach_the_planner() -> None:
    given = ["hold_release:=0.25", "hold_bound:=0.3", "escape:=false", "fail_safe:=single"]
    with in_process("arm_planner", [*BASE, *given]) as nodes:
        node = ArmPlannerNode()
        nodes.add(node)
        s = node.controller.planner.settings
        assert (s.hold_release, s.hold_bound, s.escape, s.fail_safe) == (0.25, 0.3, False, "single")
        assert isinstance(s.hold_release, float) and isinstance(s.escape, bool)


def test_the_silent_path_watch_takes_its_parameters_and_the_nodes_period() -> None:
    given = ["silent_lookahead:=1.5", "silent_clearance:=0.1", "rate:=20.0"]
    with in_process("arm_planner", [*BASE, *given]) as nodes:
        node = ArmPlannerNode()
        nodes.add(node)
        s = node.controller.planner.settings
        assert (s.silent_lookahead, s.silent_clearance) == (1.5, 0.1)
        assert s.tick == pytest.approx(0.05)  # velocities over one period of the rate


def test_a_release_inside_the_hold_tolerance_is_rejected_by_name() -> None:
    with (
        in_process("arm_planner", [*BASE, "hold_release:=0.01"]),
        pytest.raises(InvalidValueError, match=r"hold_release.*hold_tolerance"),
    ):
        ArmPlannerNode()
