"""Commands the arm can follow: each joint's command changes by at most what its acceleration
limit reaches in one tick.

A row provider and a command filter (settings group ``actuator``; off by default and in the
``paper`` preset). The paper's Opt assumes ``q̇ = u``: any command within ū takes effect at once,
so its fail-safe flips every joint at full speed in one tick (a 1 rad/s step at ū = 0.5). A
real joint follows a velocity command at most as fast as its acceleration limit ``a_j``
(``facts.accel_limits`` of the robot's description) allows: a command it cannot reach is a plan
it does not follow.

The rows keep Opt's step ``y`` (held ``t_plan``) within
``t_plan·(u_prev_j ± share·a_j·tick)``, where ``u_prev`` is this planner's last command; the
fail-safe and an unconstrained step are projected onto them like every row provider's rows, so
the fail-safe becomes the best reachable command toward its direction. The filter clips the
final command to the same band (after the other filters, which may have shortened it) and
remembers it. The V rows against every peer's worst case stay; a step the band excludes makes
Opt infeasible, and then the fail-safe runs. It is built only for arms whose description gives
acceleration limits.

An arm that cannot stop at once must not close on a peer faster than it can brake before the
margin. With ``approach_rate`` γ the stage adds one row per peer, linear in the step:
``∇_{q_own}V·y ≥ −γ·t_plan·max(V − margin, 0)``: V may fall at most γ times its gap per second,
so the arm slows down as the gap closes (γ·(braking time) below one keeps the approach from
overshooting). A step of zero keeps the rows.
"""

from __future__ import annotations

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.problem import LinearRows
from nehmo_core.planning.opt.tick import PeerValues, Tick

__all__ = ["AccelLimits"]


class AccelLimits:
    """The ``actuator`` row provider and command filter of one planner."""

    name = "actuator"

    def __init__(self, host: Host) -> None:
        s = host.settings
        limits = host.robot.facts.accel_limits
        if limits is None:
            rule = f"needs facts.accel_limits in the description of robot {host.robot.name!r}"
            raise InvalidValueError("actuator.enabled", rule, True)
        self.host = host
        self.dof = host.robot.dof
        self.rate = s.actuator.approach_rate
        self.t_plan = s.opt.t_plan
        # [rad/s] the change of command one tick reaches, per joint
        self.reach = s.actuator.share * s.opt.tick * np.asarray(limits, dtype=float)
        self.shortened = 0
        self.reset()

    def reset(self) -> None:
        """At rest: the last command is zero."""
        self.last = np.zeros(self.dof)
        self.shortened = 0

    def close(self) -> None:
        """It holds nothing."""

    def rows(self, q: np.ndarray) -> LinearRows:
        """``y_j ≥ t_plan·(last_j − reach_j)`` and ``−y_j ≥ −t_plan·(last_j + reach_j)``."""
        eye = np.eye(self.dof)
        low, high = self.last - self.reach, self.last + self.reach
        return LinearRows(np.vstack([eye, -eye]), np.concatenate([low, -high]) * self.t_plan)

    def peer_rows(self, tick: Tick, now: PeerValues) -> LinearRows | None:
        """``∇_{q_own}V_i·y ≥ −γ·t_plan·max(V_i − margin_i, 0)`` for each peer ``i``."""
        if not now.ids:
            return None
        grads = np.array([g[: self.dof] for g in now.grads])
        margins = np.array(
            [self.host.group_margin(m, b) for m, b in zip(now.model_index, now.bounds, strict=True)]
        )
        gaps = np.maximum(now.values - margins, 0.0)
        return LinearRows(grads, -self.rate * self.t_plan * gaps)

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u`` clipped to the commands reachable from the last one; remembered as the last."""
        out = np.clip(u, self.last - self.reach, self.last + self.reach)
        self.shortened += not np.array_equal(out, u)
        self.last = np.array(out, dtype=float)
        return out
