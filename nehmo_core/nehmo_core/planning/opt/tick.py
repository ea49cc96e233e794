"""What one ``plan()`` call knows: the arm's state and goal, the peers' values, and what the
stages decided so far (:class:`Tick`), shared by problem Opt and the stages of a planner."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.problem import LinearRows

__all__ = ["NO_PEERS", "PeerValues", "Tick"]


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


NO_PEERS = PeerValues([], [], [], np.zeros(0), [], np.zeros(0))
"""The peer values of a tick with no constrained peer."""


@dataclass
class Tick:
    """The inputs of one ``plan()`` call, checked, and what the stages set on the way.

    ``bounds``: each constrained peer's speed bound (a fraction of d̄; 1 unless announced);
    ``participants``: the peers that take part in the announcements. The stages set ``cap``
    (the share of ū the command keeps), ``announced`` (this command's announcement),
    ``rows`` (linear rows on the step besides the V rows), ``steered_by`` (the objective
    stage whose target replaced the goal this tick) and ``fail_safe`` (the planner ran the
    fail-safe).
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
    steered_by: str | None = None
    fail_safe: bool = False  # Opt gave no step this tick: the fail-safe command ran

    def holds(self, peer: str) -> bool:
        """Whether ``peer`` holds: it takes part in the announcements and announced a bound
        below full speed."""
        return peer in self.participants and self.bounds.get(peer, FULL_SPEED) < FULL_SPEED
