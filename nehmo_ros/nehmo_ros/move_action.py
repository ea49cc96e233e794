"""Goals of a planner node: the ``/<id>/move_arm`` action (``nehmo_interfaces/action/MoveArm``)
and the ``/<id>/goal`` topic, one code path (:meth:`GoalKeeper.apply`).

A goal on either path replaces the one before: an action goal still running ends ``ABORTED``
("preempted"). Feedback is sent every planner tick: the largest joint error, the smallest ``V``
and its peer, and the mode (``planning``, ``fail_safe``, ``escaping``, ``evading``, ``holding``,
``waiting``). A goal ends ``REACHED`` when the joint error's norm (L2, continuous joints
wrapped: the evaluation's success rule) is within its tolerance,
``TIMED_OUT`` after its time limit, ``CANCELED`` on cancel: the arm then holds with zero commands
until the next goal (on either path) or ``/planner/resume``.

The action needs the ``nehmo_interfaces`` package (built in ``ros_ws``); without it the node
says so once and serves the topic alone.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.task import Future

from nehmo_core.sim.scenarios import goal_error
from nehmo_ros.control import ArmController
from nehmo_ros.solve_worker import Decision

__all__ = ["DEFAULT_TOLERANCE", "GoalKeeper", "action_name", "decision_mode"]

DEFAULT_TOLERANCE = 0.1
"""[rad] A goal's tolerance when it gives none (the evaluation's success rule)."""


def action_name(arm_id: str) -> str:
    return f"/{arm_id}/move_arm"


def decision_mode(decision: Decision, paused: bool) -> str:
    """What the arm is doing at this tick, in one word."""
    if not decision.ready:
        return "waiting"
    if paused or decision.hold:
        return "holding"
    if decision.fail_safe:
        return "fail_safe"
    telemetry = decision.telemetry
    if telemetry is not None and telemetry.escaping:
        return "escaping"
    if telemetry is not None and telemetry.evading:
        return "evading"
    return "planning"


@dataclass
class _Active:
    handle: Any
    goal: np.ndarray
    tolerance: float
    time_limit: float
    start: float
    waiter: Future | None = None
    ended_by: str = ""  # "preempted" / "replaced": another goal took over
    error: float = math.inf
    feedback: tuple[float, str, str] = (math.inf, "", "waiting")


class GoalKeeper:
    """The goal paths of ``node`` for ``controller``'s arm."""

    def __init__(self, node: Node, controller: ArmController, arm_id: str) -> None:
        self.node, self.controller, self.arm_id = node, controller, arm_id
        self.robot = controller.robot
        self.active: _Active | None = None
        self._held = False  # holding after a cancel, until the next goal
        try:
            from nehmo_interfaces.action import MoveArm
        except ImportError:
            self.action_type = None
            node.get_logger().info(
                f"action {action_name(arm_id)} off: nehmo_interfaces is not importable (build "
                "ros_ws and source its install/setup.bash); goals come on the topic"
            )
            return
        from rclpy.action import ActionServer, CancelResponse, GoalResponse

        self.action_type = MoveArm
        self._accept, self._reject = GoalResponse.ACCEPT, GoalResponse.REJECT
        self._cancel_ok = CancelResponse.ACCEPT
        self.server = ActionServer(
            node,
            MoveArm,
            action_name(arm_id),
            execute_callback=self._execute,
            goal_callback=self._on_goal_request,
            handle_accepted_callback=self._on_accepted,
            cancel_callback=lambda _handle: self._cancel_ok,
        )

    # -- both paths ---------------------------------------------------------------------------
    def apply(self, names: Sequence[str], position: Sequence[float], by: str) -> np.ndarray:
        """Validate and set a goal; ends a running action goal (``by`` says what replaced it)
        and a hold after a cancel."""
        goal = self.controller.set_goal(names, position)
        if self.active is not None and by == "topic":
            self._end_early(self.active, "replaced by a goal on the topic")
        if self._held:
            self._held = False
            self.controller.resume()
        return goal

    def on_topic(self, msg: Any) -> None:
        """A goal on ``/<id>/goal`` (sensor_msgs/JointState); a bad one keeps the previous goal."""
        try:
            goal = self.apply(msg.name, msg.position, "topic")
        except Exception as err:  # InvalidValueError, or a malformed message
            self.node.get_logger().error(
                f"rejected goal: {err}; keeping the previous goal", throttle_duration_sec=2.0
            )
            return
        self.node.get_logger().info(
            f"goal {[round(float(x), 3) for x in goal]}", throttle_duration_sec=5.0
        )

    def on_tick(self, decision: Decision) -> None:
        """Called by the node every tick: wakes the running action goal with this tick's state."""
        active = self.active
        if active is None:
            return
        got = self.controller.states.get(self.arm_id)
        if got is not None:
            active.error = float(np.linalg.norm(goal_error(got[0], active.goal, self.robot)))
        telemetry = decision.telemetry
        min_value = math.inf if telemetry is None else float(telemetry.min_value)
        peer = "" if telemetry is None else telemetry.critical_peer or ""
        active.feedback = (min_value, peer, decision_mode(decision, self.controller.paused))
        self._wake(active)

    def destroy(self) -> None:
        """End a running goal (aborted) and take the action server down."""
        if self.active is not None:
            self._end_early(self.active, "the planner was cleaned up")
        if self.action_type is not None:
            self.server.destroy()

    # -- the action -----------------------------------------------------------------------------
    def _on_goal_request(self, request: Any) -> Any:
        try:
            q = self._check(request)
        except Exception as err:  # InvalidValueError names the field and the rule
            self.node.get_logger().error(f"rejected move_arm goal: {err}")
            return self._reject
        self.node.get_logger().info(f"accepted move_arm goal {[round(float(x), 3) for x in q]}")
        return self._accept

    def _check(self, request: Any) -> np.ndarray:
        from nehmo_core.errors import InvalidValueError
        from nehmo_ros.state_buffer import order_joints

        where = f"{action_name(self.arm_id)} goal"
        for field in ("tolerance", "time_limit"):
            value = float(getattr(request, field))
            if not (math.isfinite(value) and value >= 0):
                raise InvalidValueError(f"{where}.{field}", "must be finite and >= 0", value)
        q = order_joints(self.robot, list(request.name), list(request.position), where)
        return self.robot.check_within_limits(q, where)

    def _on_accepted(self, handle: Any) -> None:
        if self.active is not None:
            self._end_early(self.active, "preempted by a new goal")
        handle.execute()

    def _end_early(self, active: _Active, why: str) -> None:
        active.ended_by = why
        if self.active is active:
            self.active = None
        self._wake(active)

    def _wake(self, active: _Active) -> None:
        waiter, active.waiter = active.waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result(True)

    async def _execute(self, handle: Any) -> Any:
        request = handle.request
        goal = self.apply(list(request.name), list(request.position), "action")
        active = _Active(
            handle,
            goal,
            float(request.tolerance) or DEFAULT_TOLERANCE,
            float(request.time_limit),
            time.monotonic(),
        )
        self.active = active
        result = self.action_type.Result  # type: ignore[union-attr]
        feedback = self.action_type.Feedback()  # type: ignore[union-attr]
        while True:
            active.waiter = Future()
            await active.waiter
            elapsed = time.monotonic() - active.start
            if active.ended_by:
                handle.abort()
                return self._result(result, result.ABORTED, active.ended_by, active, elapsed)
            if handle.is_cancel_requested:
                self._finish(active)
                self.controller.pause()
                self._held = True
                handle.canceled()
                self.node.get_logger().info("move_arm goal canceled: holding")
                return self._result(result, result.CANCELED, "canceled: holding", active, elapsed)
            min_value, peer, mode = active.feedback
            feedback.goal_error, feedback.min_value = active.error, min_value
            feedback.critical_peer, feedback.mode, feedback.elapsed = peer, mode, elapsed
            handle.publish_feedback(feedback)
            if active.error <= active.tolerance:
                self._finish(active)
                handle.succeed()
                return self._result(result, result.REACHED, "reached", active, elapsed)
            if active.time_limit and elapsed > active.time_limit:
                self._finish(active)
                handle.abort()
                why = f"not reached within {active.time_limit:g} s"
                return self._result(result, result.TIMED_OUT, why, active, elapsed)

    def _finish(self, active: _Active) -> None:
        if self.active is active:
            self.active = None

    @staticmethod
    def _result(cls: Any, code: int, message: str, active: _Active, elapsed: float) -> Any:
        return cls(code=code, message=message, goal_error=active.error, elapsed=elapsed)
