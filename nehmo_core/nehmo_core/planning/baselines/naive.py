"""Simple baselines: the naive planner and the reckless mode, and trajectory tracking.

* :class:`NaivePlanner` drives straight toward the goal, ``u = clip((q_goal − q)/t_plan, ±ū)``
  per joint, ignoring every other arm (paper § IV). Like the authors' naive planner it does not
  wrap continuous joints (``wrap_goal`` stays off): a UR5 base joint turns the long way between
  start and goal, through the side facing the other arm, which is what makes the paper's
  scenarios interact.
* ``reckless``: the same law for one arm of a cell that the others must defend against (the
  paper's UR5-Kinova "NeHMO / Naive" experiment); only the telemetry status differs.
* :class:`TrajectoryTracker` gives a centralized planner's (CHOMP, OMPL) joint trajectory of all
  arms the per-arm planner interface: each call advances a shared clock by one control period
  and commands the velocity that reaches the reference one period later, clamped to ``ū``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.interface import (
    PlanResult,
    Telemetry,
    WithoutValues,
    goal_error,
    one_joint_vector,
)
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = ["NaivePlanner", "TimedTrajectory", "TrajectoryTracker", "retime"]


class NaivePlanner(WithoutValues):
    """Straight toward the goal, clamped to ``ū`` (``reckless=True`` only relabels it)."""

    def __init__(
        self,
        cell: Cell,
        arm_id: str,
        settings: PlannerSettings | None = None,
        reckless: bool = False,
    ) -> None:
        self.cell = cell
        self.arm_id = arm_id
        self.robot = cell.arm(arm_id).robot
        self.settings = settings or PlannerSettings()
        self.status = "reckless" if reckless else "naive_planner"

    def reset(self) -> None:
        """Stateless."""

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """One tick (``peer_bounds`` is ignored: this planner announces nothing)."""
        start = time.perf_counter()
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        goal = one_joint_vector(self.robot.check_q(q_goal, "q_goal"), "q_goal")
        error = goal_error(q, goal, self.robot, self.settings.opt.wrap_goal)
        u = np.clip(
            -error / self.settings.opt.t_plan, -self.settings.opt.u_max, self.settings.opt.u_max
        )
        return PlanResult(u, Telemetry(time.perf_counter() - start, self.status))


@dataclass(frozen=True)
class TimedTrajectory:
    """Joint waypoints of every arm at times ``times`` (W,) [s]: ``waypoints[arm]`` (W, dof)."""

    times: np.ndarray
    waypoints: Mapping[str, np.ndarray]

    def sample(self, arm_id: str, t: float) -> np.ndarray:
        """Linear interpolation of ``arm_id``'s reference at time ``t`` [s] (held at the ends)."""
        w = self.waypoints[arm_id]
        return np.array([np.interp(t, self.times, w[:, j]) for j in range(w.shape[1])])


def retime(waypoints: Mapping[str, np.ndarray], speed: float) -> TimedTrajectory:
    """Time a path so that no joint of any arm exceeds ``speed`` [rad/s] on any segment.

    All arms share one clock: the coordination a centralized planner found is kept.
    """
    if not speed > 0:
        raise InvalidValueError("speed", "must be > 0", speed)
    arms = list(waypoints)
    stacked = np.concatenate([waypoints[a] for a in arms], axis=1)  # (W, total dof)
    steps = np.abs(np.diff(stacked, axis=0)).max(axis=1) / speed
    times = np.concatenate([[0.0], np.cumsum(steps)])
    return TimedTrajectory(times, {a: np.asarray(waypoints[a]) for a in arms})


class TrajectoryTracker(WithoutValues):
    """Per-arm planner interface over a centralized :class:`TimedTrajectory`."""

    def __init__(
        self,
        cell: Cell,
        trajectory: TimedTrajectory,
        arm_id: str,
        period: float,
        settings: PlannerSettings | None = None,
        plan_time: float = 0.0,
    ) -> None:
        if not period > 0:
            raise InvalidValueError("period", "must be > 0 [s]", period)
        self.trajectory = trajectory
        self.arm_id = arm_id
        self.robot = cell.arm(arm_id).robot
        self.period = period
        self.settings = settings or PlannerSettings()
        self.plan_time = plan_time  # the centralized solve, reported on the first call
        self._t = 0.0
        self._last = np.zeros(self.robot.dof)

    def reset(self) -> None:
        self._t = 0.0
        self._last = np.zeros(self.robot.dof)

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """One tick (``peer_bounds`` is ignored: this planner announces nothing)."""
        start = time.perf_counter()
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        # One tick of latency: this command acts during the next tick, while the previous one
        # acts now. Aim from where the previous command takes the arm, so that every joint stays
        # on the shared clock (a lagging joint would bend the path the planner checked).
        predicted = q + self.period * self._last
        target = self.trajectory.sample(self.arm_id, self._t + self.period)
        error = goal_error(predicted, target, self.robot, wrap=True)
        u = np.clip(-error / self.period, -self.settings.opt.u_max, self.settings.opt.u_max)
        self._last = u
        elapsed = time.perf_counter() - start + (self.plan_time if self._t == 0.0 else 0.0)
        self._t += self.period
        return PlanResult(u, Telemetry(elapsed, "tracking"))
