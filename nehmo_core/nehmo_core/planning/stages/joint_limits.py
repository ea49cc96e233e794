"""Commands within the joint limits: a row provider and command filter stage (settings group
``joint_limits``; off in the ``paper`` preset).

Opt and the paper's fail-safe ``ū·sign(∂V/∂q¹)`` know the joints' speed bound, not their position
limits. A joint at its limit does not move however it is commanded (the simulator and a real
drive hold it there), so a command that drives it further is not what the arm does, and every
stage that predicts the step from the command (the self-clearance check, the contact guard)
predicts a pose the arm never takes. This stage clips each joint's command so that the pose
where the step ends (from where the command in flight leaves the arm, :meth:`Host.ahead`) stays
within the limits: a joint may stop at its limit, never pass it, and it is never pushed into
motion. It runs before every other command filter, so they check the step the arm will take.

Opt also gets the limits as rows (``y_j ≥ min(lower_j − q_j, 0)``, ``y_j ≤ max(upper_j − q_j,
0)`` for a joint within one full step of a limit; ``y = 0`` keeps them): a step clipped after the
solve is one Opt did not choose, and its other joints can then close a self-clearance row it
kept only with the clipped joint's help (a Panda stopped beside its peer for good, dual_panda
seed 82). Joints that wrap (no limits) are left alone. The V rows against every peer's worst
case stay.
"""

from __future__ import annotations

import numpy as np

from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.problem import LinearRows
from nehmo_core.planning.opt.tick import PeerValues, Tick

__all__ = ["JointLimits"]


class JointLimits:
    """The stage; ``shortened`` counts the commands it clipped."""

    name = "joint_limits"

    def __init__(self, host: Host) -> None:
        self.host = host
        robot = host.robot
        bounded = ~np.asarray(robot.continuous, dtype=bool)
        self._lower = np.where(bounded, robot.lower, -np.inf)
        self._upper = np.where(bounded, robot.upper, np.inf)
        self._eye = np.eye(robot.dof)
        self._none = LinearRows(np.zeros((0, robot.dof)), np.zeros(0))  # no joint near a limit
        self.shortened = 0

    def reset(self) -> None:
        self.shortened = 0

    def close(self) -> None:
        pass

    def rows(self, q: np.ndarray) -> LinearRows:
        """``A·y ≥ b`` for the joints that a full step from ``q`` could take past a limit."""
        s = self.host.settings.opt
        reach = s.t_plan * s.u_max
        lower, upper = self._lower - q, self._upper - q  # room to each limit (−inf, inf: none)
        near_lower = np.flatnonzero(lower > -reach)
        near_upper = np.flatnonzero(upper < reach)
        if len(near_lower) + len(near_upper) == 0:  # most ticks, and every tick of a UR5
            return self._none
        return LinearRows(
            np.vstack([self._eye[near_lower], -self._eye[near_upper]]),
            np.concatenate(
                [np.minimum(lower[near_lower], 0.0), -np.maximum(upper[near_upper], 0.0)]
            ),
        )

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` with each joint's speed cut to what keeps the step's end within its limits."""
        q = self.host.ahead(tick.q)
        dt = self.host.settings.opt.tick
        low = np.minimum((self._lower - q) / dt, 0.0)  # never below 0: no joint is pushed
        high = np.maximum((self._upper - q) / dt, 0.0)
        clipped = np.clip(u, low, high)
        if not np.array_equal(clipped, u):
            self.shortened += 1
        return clipped
