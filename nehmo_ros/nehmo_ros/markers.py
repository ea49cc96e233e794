"""What a planner intends, for RViz and Foxglove: ``/<id>/planner/markers``
(visualization_msgs/MarkerArray, frame ``world``, the cell's frame) at about 5 Hz, and the
smallest ``V`` [m] on ``/<id>/planner/min_value`` (std_msgs/Float64, inf without a constrained
peer) with it, to plot.

Three markers per message (namespace ``nehmo/<id>``):

- ``critical`` (id 0, LINE_LIST): the closest pair of link origins between the arm and its
  critical peer (the peer of the smallest ``V``), coloured by ``V`` against the margin ``ε``
  (the planner setting `opt.epsilon`, the floor of the certified margin):
  green ``V ≥ 2ε``, amber ``ε ≤ V < 2ε``, red ``V < ε``; deleted (action DELETE) while no peer is
  constrained. Link origins stand in for the closest points of the geometry, which the planner
  never computes (it plans on the learned ``V``).
- ``goal`` (id 1, SPHERE): where the goal puts the arm's tip link.
- ``mode`` (id 2, TEXT_VIEW_FACING) above the base: the mode (``planning``, ``fail_safe``, ...)
  and ``V``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA, Float64
from visualization_msgs.msg import Marker, MarkerArray

from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.logs.topics import markers_topic, min_value_topic
from nehmo_core.robots.model import Cell
from nehmo_ros.move_action import decision_mode

__all__ = ["FRAME", "MARKER_RATE", "PlannerMarkers", "markers_topic", "value_colour"]

FRAME = "world"
MARKER_RATE = 5.0  # [Hz]
GREEN, AMBER, RED = (0.1, 0.8, 0.2), (1.0, 0.65, 0.0), (0.9, 0.1, 0.1)


def value_colour(value: float, epsilon: float) -> tuple[float, float, float]:
    """Green at ``V ≥ 2ε``, amber at ``ε ≤ V < 2ε``, red below ``ε``."""
    if value >= 2 * epsilon:
        return GREEN
    return AMBER if value >= epsilon else RED


class PlannerMarkers:
    """Builds one arm's MarkerArray from the latest states, goal and decision."""

    def __init__(self, cell: Cell, arm_id: str, epsilon: float) -> None:
        self.cell, self.arm_id, self.epsilon = cell, arm_id, epsilon
        self.kin = {a.arm_id: ArmKinematics(a.robot) for a in cell.arms}
        self.base = {a.arm_id: a.base.matrix() for a in cell.arms}
        self.ns = f"nehmo/{arm_id}"

    def points(self, arm_id: str, q: np.ndarray) -> np.ndarray:
        """World positions (L, 3) of the arm's link origins."""
        with torch.no_grad():
            local = self.kin[arm_id].link_positions(torch.as_tensor(q, dtype=torch.float64)[None])
        p = local[0].numpy()
        T = self.base[arm_id]
        return p @ T[:3, :3].T + T[:3, 3]

    def build(
        self,
        stamp: Any,
        states: Mapping[str, np.ndarray],
        goal: np.ndarray | None,
        mode: str,
        critical: str | None,
        value: float,
    ) -> MarkerArray:
        out = MarkerArray()
        own = states.get(self.arm_id)
        line = self._marker(stamp, 0, Marker.LINE_LIST)
        if own is not None and critical and critical in states and math.isfinite(value):
            a, b = self.points(self.arm_id, own), self.points(critical, states[critical])
            gaps = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
            i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
            line.points = [_point(a[i]), _point(b[j])]
            line.scale.x = 0.01
            line.color = _colour(value_colour(value, self.epsilon))
        else:
            line.action = Marker.DELETE
        out.markers.append(line)
        target = self._marker(stamp, 1, Marker.SPHERE)
        if goal is not None:
            tip = self.points(self.arm_id, goal)[-1]
            target.pose.position = _point(tip)
            target.scale.x = target.scale.y = target.scale.z = 0.06
            target.color = _colour(GREEN, 0.6)
        else:
            target.action = Marker.DELETE
        out.markers.append(target)
        text = self._marker(stamp, 2, Marker.TEXT_VIEW_FACING)
        base = self.base[self.arm_id][:3, 3]
        text.pose.position = _point(base + np.array([0.0, 0.0, 1.1]))
        text.scale.z = 0.08
        shown = f"{value:.3f} m" if math.isfinite(value) else "no peer"
        text.text = f"{self.arm_id}: {mode}, V {shown}"
        text.color = _colour((1.0, 1.0, 1.0))
        out.markers.append(text)
        return out

    def _marker(self, stamp: Any, marker_id: int, kind: int) -> Marker:
        m = Marker(ns=self.ns, id=marker_id, type=kind, action=Marker.ADD)
        m.header.frame_id = FRAME
        m.header.stamp = stamp
        m.pose.orientation.w = 1.0
        m.lifetime = Duration(sec=1)  # gone when the planner stops
        return m


def _point(p: np.ndarray) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _colour(rgb: tuple[float, float, float], alpha: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=rgb[0], g=rgb[1], b=rgb[2], a=alpha)


class MarkerPublisher:
    """Publishes ``node``'s markers every ``round(rate / MARKER_RATE)`` ticks."""

    def __init__(self, node: Any, controller: Any, arm_id: str, epsilon: float, rate: float):
        self.node, self.controller = node, controller
        self.markers = PlannerMarkers(controller.cell, arm_id, epsilon)
        self.every = max(1, round(rate / MARKER_RATE))
        self.due = 0
        self.pub = node.create_publisher(MarkerArray, markers_topic(arm_id), 5)
        self.value_pub = node.create_publisher(Float64, min_value_topic(arm_id), 5)

    def on_tick(self, decision: Any) -> None:
        self.due -= 1
        if self.due > 0:
            return
        self.due = self.every
        mode = decision_mode(decision, self.controller.paused)
        states = {}
        for arm_id in self.controller.cell.arm_ids:
            got = self.controller.states.get(arm_id)
            if got is not None:
                states[arm_id] = np.asarray(got[0], dtype=float)
        telemetry = decision.telemetry
        critical = None if telemetry is None else telemetry.critical_peer
        value = math.inf if telemetry is None else float(telemetry.min_value)
        stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(
            self.markers.build(stamp, states, self.controller.goal, mode, critical, value)
        )
        self.value_pub.publish(Float64(data=value))
