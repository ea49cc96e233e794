"""`command_watchdog` node: zero velocity when a planner's commands stop (real setups).

    install/nehmo_ros/lib/nehmo_ros/command_watchdog --ros-args -p arm_id:=ur5_0

A ros2_control forward command controller keeps applying the last command it received, with
no timeout: if the planner process dies, the arm keeps its last velocity. Put this node between
the planner and the controller:

- the planner publishes to ``/<id>/planner/commands`` (start it with
  ``--ros-args -r /<id>/velocity_controller/commands:=/<id>/planner/commands``);
- the watchdog forwards every valid command at once to ``/<id>/velocity_controller/commands``
  (std_msgs/Float64MultiArray, the controller's topic);
- a command is valid for ``validity`` seconds (default 0.06: the one 40 ms period the planner
  checked it for, plus jitter): when the next one is late it publishes zeros (and keeps
  publishing them every ``1/rate`` s) until commands come again, so a planner slowed by a
  loaded machine never leaves the arm running on a command nobody checked; a command that is
  not finite or has the wrong length is replaced by zeros at once;
- when no command came for more than ``timeout`` seconds the planner is taken for lost (a trip:
  a WARN line, and an INFO line when commands resume).

The simulated bridge has the same watchdog built in (``command_timeout``); this node is the
piece for a real arm. Parameters (validated at start, read-only): ``arm_id`` (required),
``validity`` [s] (default 0.06), ``timeout`` [s] (default 0.2: five missed 25 Hz ticks),
``rate`` [Hz] of the check and of the
zeros (default 100), ``joints`` (the command length; 0: the length of the first command),
``input_topic`` and ``output_topic`` (defaults above). ``use_sim_time`` works as for any node:
the timeout then runs on ``/clock``. It logs a WARN line when it takes over and an INFO line
when commands resume, and reports its counters when stopped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from nehmo_core.logs.topics import command_topic
from nehmo_ros.node_support import Param, declare_parameters, require_text, run_main

__all__ = ["PARAMS", "CommandWatchdogNode", "main"]

PARAMS: dict[str, Param] = {
    "arm_id": Param("", "the arm whose commands are watched (required)"),
    "validity": Param(0.06, "[s] a command's life: zeros when the next is later", 0.001, 60.0),
    "timeout": Param(0.2, "[s] no command for longer than this: a trip", 0.001, 60.0),
    "rate": Param(100.0, "[Hz] how often the age is checked and zeros are repeated", 1.0, 1000.0),
    "joints": Param(0, "command length (0: the length of the first command)", 0, 64),
    "input_topic": Param("", "the planner's commands (default /<arm_id>/planner/commands)"),
    "output_topic": Param(
        "", "the controller's topic (default /<arm_id>/velocity_controller/commands)"
    ),
}
HISTORY = 10


def planner_topic(arm_id: str) -> str:
    """Where a planner behind the watchdog publishes (remapped from the controller's topic)."""
    return f"/{arm_id}/planner/commands"


class CommandWatchdogNode(Node):
    """Forward valid commands; zeros after ``timeout`` without one, or for a bad one."""

    def __init__(self) -> None:
        super().__init__("command_watchdog")
        p = declare_parameters(self, PARAMS)
        self.arm_id = require_text("arm_id", p["arm_id"], "the arm to watch, e.g. ur5_0")
        self.timeout_ns = round(float(p["timeout"]) * 1e9)
        self.validity_ns = round(float(p["validity"]) * 1e9)
        self.joints = int(p["joints"])
        source = p["input_topic"] or planner_topic(self.arm_id)
        target = p["output_topic"] or command_topic(self.arm_id)
        self.last_ns: int | None = None  # clock time of the last valid command
        self.tripped = False
        self.expired = False  # zeros since the latest command outlived its validity
        self.counts = {"forwarded": 0, "rejected": 0, "zeros": 0, "trips": 0, "expired": 0}
        self.pub = self.create_publisher(Float64MultiArray, target, HISTORY)
        self.create_subscription(Float64MultiArray, source, self._on_command, HISTORY)
        self.timer = self.create_timer(1.0 / float(p["rate"]), self._on_check)
        self.get_logger().info(
            f"watching {source} -> {target}: zeros {p['validity']:g} s after a command "
            f"without the next, a trip after {p['timeout']:g} s"
        )

    def _now(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    def _zeros(self) -> None:
        if self.joints > 0:
            self.pub.publish(Float64MultiArray(data=[0.0] * self.joints))
            self.counts["zeros"] += 1

    def _on_command(self, msg: Float64MultiArray) -> None:
        data = list(msg.data)
        if self.joints == 0 and data:
            self.joints = len(data)
        if len(data) != self.joints or not all(math.isfinite(v) for v in data):
            self.counts["rejected"] += 1
            self.get_logger().warning(
                f"rejected a command of {len(data)} values for {self.arm_id} (expected "
                f"{self.joints} finite values): zeros instead",
                throttle_duration_sec=2.0,
            )
            self._zeros()
            return
        self.last_ns = self._now()
        self.expired = False
        if self.tripped:
            self.tripped = False
            self.get_logger().info(f"watchdog: commands for {self.arm_id} resumed")
        self.pub.publish(msg)
        self.counts["forwarded"] += 1

    def _on_check(self) -> None:
        if self.last_ns is None:
            return  # nothing commanded yet: the controller holds what it has
        age = self._now() - self.last_ns
        if age <= self.validity_ns:
            return
        if not self.expired:
            self.expired = True
            self.counts["expired"] += 1
            self.get_logger().warning(
                f"the command for {self.arm_id} is {age / 1e9:.3f} s old (> validity "
                f"{self.validity_ns / 1e9:g} s: the planner runs late): zeros until the next "
                f"({self.counts['expired']} times so far)",
                throttle_duration_sec=2.0,
            )
        if age > self.timeout_ns and not self.tripped:
            self.tripped = True
            self.counts["trips"] += 1
            self.get_logger().warning(
                f"watchdog: no command for {self.arm_id} in {age / 1e9:.3f} s "
                f"(> timeout {self.timeout_ns / 1e9:g} s): publishing zeros"
            )
        self._zeros()

    def on_stop(self) -> None:
        """Zeros once more (the arm stops with the watchdog), then the counters."""
        self._zeros()
        self.get_logger().info(f"stopped: {self.counts}")


def main(argv: Sequence[str] | None = None) -> int:
    return run_main("command_watchdog", CommandWatchdogNode, argv, usage=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
