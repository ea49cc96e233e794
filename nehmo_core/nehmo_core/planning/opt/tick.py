"""What one ``plan()`` call knows: the arm's state and goal, the peers' values, and what the
stages decided so far (:class:`Tick`), shared by problem Opt and the stages of a planner."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.interface import check_peers, goal_error, one_joint_vector
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.problem import LinearRows
from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.robots.model import Cell, RobotModel

__all__ = ["PeerValues", "Tick", "peer_vectors", "read_tick"]


@dataclass(frozen=True)
class PeerValues:
    """One tick's constrained peers: current pair states, values and gradients."""

    ids: list[str]
    model_index: list[int]
    states: list[np.ndarray]  # (n_i,) current pair state per peer
    values: np.ndarray  # (k,) V(b_i·t_plan, x) [m]
    grads: list[np.ndarray]  # (n_i,) ∇ₓV per peer
    bounds: np.ndarray  # (k,) each peer's speed bound b_i, a fraction of d̄ (1: none)

    @cached_property
    def groups(self) -> list[tuple[int, float, list[int]]]:
        """``(model index, bound, members)`` of the peers that share a model and a bound."""
        keys = list(zip(self.model_index, self.bounds.tolist(), strict=True))
        return [
            (m, b, [i for i, key in enumerate(keys) if key == (m, b)]) for m, b in sorted(set(keys))
        ]

    @property
    def critical(self) -> int:
        """Index of the peer with the smallest value."""
        return int(np.argmin(self.values))


@dataclass
class Tick:
    """The inputs of one ``plan()`` call, checked, and what the stages set on the way.

    ``bounds``: each constrained peer's speed bound (a fraction of d̄; 1 unless announced);
    ``participants``: the peers that take part in the announcements. The stages set ``cap``
    (the share of ū the command keeps), ``announced`` (this command's announcement),
    ``rows`` (linear rows on the step besides the V rows) and ``steered_by`` (the objective
    stage whose target replaced the goal this tick).
    """

    q: np.ndarray
    goal: np.ndarray
    error0: np.ndarray  # q − goal [rad] (continuous joints wrapped if the settings say so)
    peers: Mapping[str, np.ndarray]
    bounds: Mapping[str, float]
    participants: frozenset[str]
    cap: float = FULL_SPEED
    announced: float = FULL_SPEED
    rows: LinearRows | None = None
    now: PeerValues | None = None
    steered_by: str | None = None


class _Arm(Protocol):
    @property
    def cell(self) -> Cell: ...

    @property
    def arm_id(self) -> str: ...

    @property
    def robot(self) -> RobotModel: ...

    @property
    def settings(self) -> PlannerSettings: ...

    @property
    def pairs(self) -> Mapping[str, object]: ...


def read_tick(
    arm: _Arm,
    q_self: ArrayLike,
    peers: Mapping[str, ArrayLike],
    q_goal: ArrayLike,
    bounds: Mapping[str, float],
    peer_bounds: Mapping[str, float] | None,
) -> Tick:
    """One ``plan()`` call's inputs, checked (a batch, a NaN, a missing constrained peer raise
    :class:`~nehmo_core.errors.InvalidValueError` naming the argument); ``bounds``: each
    constrained peer's bound, ``peer_bounds`` as given (its peers take part in the
    announcements)."""
    q = one_joint_vector(arm.robot.check_q(q_self, "q_self"), "q_self")
    goal = one_joint_vector(arm.robot.check_q(q_goal, "q_goal"), "q_goal")
    others = peer_vectors(arm.cell, arm.arm_id, peers)
    missing = [p for p in arm.pairs if p not in others]
    if missing:
        raise InvalidValueError(
            "peers", f"must include every constrained arm {missing}", list(others)
        )
    return Tick(
        q=q,
        goal=goal,
        error0=goal_error(q, goal, arm.robot, arm.settings.wrap_goal),
        peers=others,
        bounds=bounds,
        participants=frozenset(p for p in peer_bounds or {} if p in arm.pairs),
    )


def peer_vectors(cell: Cell, arm_id: str, peers: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """:func:`~nehmo_core.planning.opt.interface.check_peers`, one joint vector per peer."""
    checked = check_peers(cell, arm_id, peers)
    return {p: one_joint_vector(q, f"peers[{p!r}]") for p, q in checked.items()}
