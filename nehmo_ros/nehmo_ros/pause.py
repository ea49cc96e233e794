"""Pause and resume of a planner node: ``/<id>/planner/pause`` and ``/<id>/planner/resume``
(std_srvs/Trigger). Paused, the controller commands zero velocity and plans nothing; after
resume it plans from states observed after the resume (:meth:`ArmController.resume`)."""

from __future__ import annotations

from typing import Any

from rclpy.node import Node
from std_srvs.srv import Trigger

from nehmo_ros.control import ArmController

__all__ = ["PauseServices"]


class PauseServices:
    """The two services of ``node`` for ``controller``'s arm."""

    def __init__(self, node: Node, controller: ArmController, arm_id: str) -> None:
        self.node, self.controller = node, controller
        node.create_service(Trigger, f"/{arm_id}/planner/pause", self._on_pause)
        node.create_service(Trigger, f"/{arm_id}/planner/resume", self._on_resume)

    def _on_pause(self, request: Any, response: Any) -> Any:
        already = self.controller.paused
        self.controller.pause()
        response.success = True
        response.message = "already paused" if already else "paused: commanding zero velocity"
        if not already:
            self.node.get_logger().info("paused (zero velocity until /planner/resume)")
        return response

    def _on_resume(self, request: Any, response: Any) -> Any:
        if not self.controller.paused:
            response.success, response.message = False, "not paused"
            return response
        self.controller.resume()
        response.success, response.message = True, "resumed: planning from the current state"
        self.node.get_logger().info("resumed")
        return response
