"""How ``arm_planner`` takes joint states: raw subscriptions keep only the newest message of each
arm; at each tick that one is decoded, checked and stored (:meth:`ArmController.update_state`),
timed by when it arrived. A driver may publish at 500 Hz; the planner needs one state per arm
and tick, so the messages in between are counted and never decoded."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from nehmo_ros.planner_report import WARN_EVERY

__all__ = ["StateIntake"]


class StateIntake:
    """The joint-state half of :class:`~nehmo_ros.arm_planner.ArmPlannerNode` (a mixin)."""

    controller: Any
    received: dict[str, int]
    _latest: dict[str, tuple[bytes, float]]
    get_logger: Any  # the node's

    def _state_callback(self, arm_id: str) -> Callable[[bytes], None]:
        def keep(data: bytes) -> None:
            self.received[arm_id] += 1
            self._latest[arm_id] = (data, time.monotonic())

        return keep

    def _read_states(self) -> None:
        """Decode, check and store the newest joint state of each arm since the last tick (a
        driver may publish at 500 Hz; the planner needs one state per arm and tick)."""
        latest, self._latest = self._latest, {}
        for arm_id, (data, received) in latest.items():
            self._on_state(arm_id, data, received)

    def _on_state(self, arm_id: str, data: bytes, now: float) -> None:
        try:
            msg = deserialize_message(data, JointState)
            stamp = msg.header.stamp
            stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
            note = self.controller.update_state(arm_id, msg.name, msg.position, now, stamp_ns)
        except Exception as err:  # a malformed message never takes the node down
            note = f"rejected: {type(err).__name__}: {err}"
        if note is None:
            return
        untrusted = f"; {arm_id} untrusted for {self.controller.settings.peer_timeout:g} s"
        if note.startswith("rejected"):
            self.get_logger().warning(
                f"joint state of {arm_id} {note} ({self.controller.states.rejected[arm_id]} "
                f"rejected){untrusted}",
                throttle_duration_sec=WARN_EVERY,
            )
        else:
            self.get_logger().warning(
                f"joint state of {arm_id} {note} ({self.controller.states.jumps[arm_id]} jumps)"
                f"{untrusted}",
                throttle_duration_sec=WARN_EVERY,
            )
