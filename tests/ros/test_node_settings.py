"""Node parameters named like planner settings reach the planner, and a bad one is rejected with
its name: the arm_planner node built in process from parameters as ``ros2 run`` builds it."""

from __future__ import annotations

import pytest
from _ros_testutil import in_process

from nehmo_core.errors import InvalidValueError
from nehmo_ros.arm_planner import ArmPlannerNode

BASE = ["cell:=dual_ur5", "arm_id:=ur5_0", "planner:=nehmo"]


def test_planner_settings_given_as_node_parameters_reach_the_planner() -> None:
    given = [
        "hold.release:=0.25",
        "hold.bound:=0.3",
        "escape.enabled:=false",
        "fail_safe.deadband:=0.3",
    ]
    with in_process("arm_planner", [*BASE, *given]) as nodes:
        node = ArmPlannerNode()
        nodes.add(node)
        s = node.controller.planner.settings
        assert (s.hold.release, s.hold.bound, s.escape.enabled, s.fail_safe.deadband) == (
            0.25,
            0.3,
            False,
            0.3,
        )
        assert isinstance(s.hold.release, float) and isinstance(s.escape.enabled, bool)


def test_the_silent_path_watch_takes_its_parameters_and_the_nodes_period() -> None:
    given = ["silent_watch.lookahead:=1.5", "silent_watch.clearance:=0.1", "rate:=20.0"]
    with in_process("arm_planner", [*BASE, *given]) as nodes:
        node = ArmPlannerNode()
        nodes.add(node)
        s = node.controller.planner.settings
        assert (s.silent_watch.lookahead, s.silent_watch.clearance) == (1.5, 0.1)
        assert s.opt.tick == pytest.approx(0.05)  # velocities over one period of the rate


def test_a_release_inside_the_hold_tolerance_is_rejected_by_name() -> None:
    with (
        in_process("arm_planner", [*BASE, "hold.release:=0.01"]),
        pytest.raises(InvalidValueError, match=r"hold\.release.*hold\.tolerance"),
    ):
        ArmPlannerNode()


def test_a_deadline_as_long_as_the_period_is_rejected_by_name() -> None:
    with (
        in_process("arm_planner", [*BASE, "opt.deadline:=0.04"]),
        pytest.raises(InvalidValueError, match=r"`opt\.deadline` must be < 1/rate"),
    ):
        ArmPlannerNode()


def test_array_and_integer_settings_reach_the_planner_as_their_types() -> None:
    given = ["exact_guard.scales:=[1.0, 0.5]", "escape.stall_ticks:=20"]
    with in_process("arm_planner", [*BASE, *given]) as nodes:
        node = ArmPlannerNode()
        nodes.add(node)
        s = node.controller.planner.settings
        assert s.exact_guard.scales == (1.0, 0.5) and s.escape.stall_ticks == 20
        c = node.controller.settings.opt  # the controller's speed bounds are the planner's
        assert (c.u_max, c.d_max, c.deadline) == (s.opt.u_max, s.opt.d_max, s.opt.deadline)
