"""The planner interface shared by NeHMO, its variants and the baselines.

A planner belongs to one arm of a cell (the cell gives every arm's robot type and base pose).
Each control tick it is called with the own joint state, the other arms' joint states and the
own goal, all [rad] in each robot's joint order, and returns a joint-velocity command [rad/s]
with telemetry. Planners keep no state between calls other than a warm start (NeHMO also its
stall counter and escape direction; the trajectory-tracking adapters of centralized planners the
clock of the tracked trajectory); ``reset`` clears it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots.model import Cell, RobotModel

__all__ = [
    "PlanResult",
    "Planner",
    "Telemetry",
    "WithoutValues",
    "check_peers",
    "goal_error",
    "one_joint_vector",
]


@dataclass(frozen=True)
class Telemetry:
    """What a planner reports with each command (published on ``/<arm_id>/planner/status``).

    ``status``: ``naive`` (the unconstrained step is safe), ``optimal``, ``unconstrained`` (no
    peer in range), ``infeasible``, ``iteration_limit``, ``timeout``, ``failed``, or a baseline's
    own (``naive_planner``, ``reckless``, ``tracking``). ``min_value`` is the smallest
    ``V(t_plan, x)`` [m] over constrained peers at the current state (``inf`` without peers).
    ``escaping``: NeHMO is leaving a stall (see ``PlannerSettings.escape``); ``evading``: heading
    out of the predicted path of a peer that announces nothing
    (``PlannerSettings.silent_watch``).
    """

    solve_time: float  # [s], wall time of the whole plan() call
    status: str
    fail_safe: bool = False
    min_value: float = math.inf
    min_constraint: float = math.nan  # min V(t_safe, predicted) − ε at the command [m]
    iterations: int = 0
    peers_constrained: tuple[str, ...] = ()
    peers_skipped: tuple[str, ...] = ()  # out of reach
    peers_unmodelled: tuple[str, ...] = ()  # in reach but no pair model fits: NOT constrained
    critical_peer: str | None = None
    escaping: bool = False  # the step followed a stall-escape direction, not the goal
    evading: bool = False  # the step headed away from a silent peer's predicted path
    speed_bound: float = 1.0  # announced with this command: a fraction of ū it keeps (1: none)


@dataclass(frozen=True)
class PlanResult:
    """A joint-velocity command ``velocity`` (dof,) [rad/s] and its telemetry."""

    velocity: np.ndarray
    telemetry: Telemetry = field(default_factory=lambda: Telemetry(0.0, "none"))


class Planner(Protocol):
    """One arm's planner, as the batch runner and the ROS control loop use it: ``plan`` every
    tick, ``fail_safe`` ahead of a solve that may run late, ``reset`` between episodes.

    ``announces``: the planner takes part in the speed-bound announcements (it plans against the
    bounds its peers announce, given as ``peer_bounds``, and announces its own, ``announcement``
    after each ``plan``). ``fail_safe`` is None for a planner without a value function (holding
    still is then its safe act). ``peers_unmodelled``: peers in reach it does not constrain;
    ``epsilon_source``: where its safety margin comes from ('' without one).
    """

    @property
    def arm_id(self) -> str: ...

    @property
    def announces(self) -> bool: ...

    @property
    def announcement(self) -> float: ...

    @property
    def peers_unmodelled(self) -> tuple[str, ...]: ...

    @property
    def epsilon_source(self) -> str: ...

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult: ...

    def fail_safe(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray | None: ...

    def commanded(self, u: ArrayLike) -> None:
        """The command [rad/s] that runs while the next ``plan`` does, when a control loop sent
        another than the last ``plan`` result (a hold, a late fail-safe)."""
        ...

    def reset(self) -> None: ...


class WithoutValues:
    """What a planner without a value function answers to the parts of :class:`Planner` it has
    no use for: it announces nothing, has no fail-safe and no margin, leaves no peer out."""

    announces = False
    announcement = 1.0
    peers_unmodelled: tuple[str, ...] = ()
    epsilon_source = ""

    def fail_safe(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray | None:
        """None: holding still is the safe act of a planner without a value function."""
        return None

    def commanded(self, u: ArrayLike) -> None:
        """Nothing: its next command does not depend on the one in flight."""


def goal_error(q: np.ndarray, goal: np.ndarray, robot: RobotModel, wrap: bool) -> np.ndarray:
    """``q − goal`` [rad]; continuous joints wrapped to (−π, π] when ``wrap``."""
    e = q - goal
    if wrap:
        e = robot.wrap(e)
    return e


def one_joint_vector(arr: np.ndarray, parameter: str) -> np.ndarray:
    """``arr`` (from :meth:`RobotModel.check_q`, which also takes batches) if it is one joint
    vector; a planner's inputs must be, so a batch raises :class:`InvalidValueError`."""
    if arr.ndim != 1:
        raise InvalidValueError(
            parameter, f"must be one joint vector, shape ({arr.shape[-1]},), not a batch", arr.shape
        )
    return arr


def check_peers(cell: Cell, arm_id: str, peers: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """Validate the other arms' joint states (every arm of the cell but ``arm_id``)."""
    out = {}
    for peer_id, q in peers.items():
        if peer_id == arm_id:
            continue
        out[peer_id] = cell.arm(peer_id).robot.check_q(q, f"peers[{peer_id!r}]")
    return out
