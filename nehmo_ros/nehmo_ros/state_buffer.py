"""The latest joint states of every arm, checked: rejected messages and jumps, per arm.

A state that is NaN/inf, of the wrong length or with unknown joint names is rejected and leaves
the previous valid state in place; a valid state that moved further than the arm can move since
the previous one is kept but counted as a *jump*. Either makes that arm *untrusted* for a while
(:class:`~nehmo_ros.control.ArmController` decides what that means). Times are monotonic
seconds given by the caller.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots.model import Cell, RobotModel

__all__ = ["StateBuffer", "order_joints"]


@dataclass
class _Latest:
    q: np.ndarray
    received: float  # [s] monotonic
    stamp_ns: int  # header stamp [ns] (0: none)


class StateBuffer:
    """Latest valid joint state [rad] of every arm of a cell, with its receive time.

    ``speed`` [rad/s] per arm and ``jump_margin`` [rad] set the jump test (module docstring);
    without them only malformed states are caught.
    """

    def __init__(
        self,
        cell: Cell,
        speed: Mapping[str, float] | None = None,
        jump_margin: float = math.inf,
    ) -> None:
        self.cell = cell
        self.speed = dict(speed or {})
        self.jump_margin = jump_margin
        self._lock = threading.Lock()
        self._latest: dict[str, _Latest] = {}
        self._untrusted_at: dict[str, float] = {}
        self.rejected: dict[str, int] = {a: 0 for a in cell.arm_ids}
        self.jumps: dict[str, int] = {a: 0 for a in cell.arm_ids}
        self.last_rejection: dict[str, str] = {}

    def update(
        self,
        arm_id: str,
        names: Sequence[str],
        position: Sequence[float],
        now: float,
        stamp_ns: int = 0,
    ) -> str | None:
        """Store a joint state. Returns None for a plain valid state, else what was wrong:
        ``"rejected: ..."`` (not stored) or ``"jumped ..."`` (stored, arm untrusted)."""
        robot = self.cell.arm(arm_id).robot
        try:
            q = order_joints(robot, names, position, f"/{arm_id}/joint_states")
        except (InvalidValueError, ValueError, TypeError) as err:
            with self._lock:
                self.rejected[arm_id] += 1
                self.last_rejection[arm_id] = str(err)
                self._untrusted_at[arm_id] = now
            return f"rejected: {err}"
        note = None
        with self._lock:
            previous = self._latest.get(arm_id)
            if previous is not None and math.isfinite(self.jump_margin):
                note = self._jump(arm_id, previous, q, now, stamp_ns)
                if note is not None:
                    self.jumps[arm_id] += 1
                    self._untrusted_at[arm_id] = now
            self._latest[arm_id] = _Latest(q, now, stamp_ns)
        return note

    def _jump(
        self, arm_id: str, previous: _Latest, q: np.ndarray, now: float, stamp_ns: int
    ) -> str | None:
        """Why ``q`` is a jump from ``previous``, or None when it is reachable."""
        robot = self.cell.arm(arm_id).robot
        dt = max(now - previous.received, 0.0)
        if stamp_ns > 0 and previous.stamp_ns > 0:
            dt = max(dt, (stamp_ns - previous.stamp_ns) / 1e9)
        speed = self.speed.get(arm_id, math.inf)
        allowed = self.jump_margin + 2.0 * speed * dt
        step = np.abs(robot.wrap(q - previous.q))
        if not float(step.max()) > allowed:
            return None
        joint = robot.joint_names[int(np.argmax(step))]
        return (
            f"jumped {float(step.max()):.3f} rad on {joint} in {dt * 1e3:.0f} ms (allowed "
            f"{allowed:.3f} rad at {speed:g} rad/s)"
        )

    def untrusted(self, now: float, window: float) -> tuple[str, ...]:
        """Arms whose data was rejected or jumped within the last ``window`` seconds."""
        with self._lock:
            return tuple(a for a, t in self._untrusted_at.items() if now - t <= window)

    def get(self, arm_id: str) -> tuple[np.ndarray, float] | None:
        """``(q, receive time)`` of ``arm_id``'s latest valid state, or None."""
        with self._lock:
            latest = self._latest.get(arm_id)
        return None if latest is None else (latest.q, latest.received)


def order_joints(
    robot: RobotModel, names: Sequence[str], position: Sequence[float], parameter: str
) -> np.ndarray:
    """Positions in the robot's joint order (:meth:`RobotModel.joint_state`, the rule the
    episode-log reader applies too)."""
    return robot.joint_state(names, position, parameter)
