"""A bug inside a planner node's tick: the node commands zero velocity, reports it once per
throttle interval, and its timer keeps ticking. In-process: the node is built from parameters
as ``ros2 run`` builds it, and its controller's ``tick`` is made to raise."""

from __future__ import annotations

import time
from typing import Any

import pytest
import rclpy.node
from _ros_testutil import in_process
from std_msgs.msg import Float64MultiArray

from nehmo_core.logs import command_topic
from nehmo_ros.arm_planner import ArmPlannerNode


def test_a_raising_tick_commands_zero_reports_once_and_the_timer_goes_on(
    monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    params = ["cell:=dual_ur5", "arm_id:=ur5_0", "planner:=naive"]
    with in_process("arm_planner", params) as nodes:
        planner = ArmPlannerNode()
        listener = rclpy.node.Node("listener")
        commands: list[list[float]] = []
        listener.create_subscription(
            Float64MultiArray,
            command_topic("ur5_0"),
            lambda msg: commands.append(list(msg.data)),
            10,
        )
        nodes.add(planner)
        nodes.add(listener)
        ticks = [0]

        def broken(*args: Any, **kwargs: Any) -> Any:
            ticks[0] += 1
            raise RuntimeError("injected bug")

        assert nodes.spin(30.0, lambda: planner.command_pub.get_subscription_count() >= 1)
        began = time.monotonic()
        monkeypatch.setattr(planner.controller, "tick", broken)
        assert nodes.spin(30.0, lambda: ticks[0] >= 5), ticks[0]
        assert nodes.spin(30.0, lambda: len(commands) >= 5), len(commands)
        assert all(c == [0.0] * 6 for c in commands)
        err = capfd.readouterr().err
        elapsed = time.monotonic() - began
        reports = err.count("tick failed (RuntimeError: injected bug); commanding zero velocity")
        # throttled: at most one report per 2 s interval, however many ticks failed
        assert 1 <= reports <= 1 + int(elapsed / 2.0), (reports, ticks[0], elapsed)
        monkeypatch.undo()  # the bug goes away: the same timer ticks the real controller again
        calls = [0]
        real = planner.controller.tick

        def counted(*args: Any, **kwargs: Any) -> Any:
            calls[0] += 1
            return real(*args, **kwargs)

        monkeypatch.setattr(planner.controller, "tick", counted)
        assert nodes.spin(30.0, lambda: calls[0] >= 3), calls[0]
        assert "tick failed" not in capfd.readouterr().err
        planner.on_stop()
