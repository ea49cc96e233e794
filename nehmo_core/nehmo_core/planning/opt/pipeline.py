"""The extension points of the NeHMO planner: the kinds of stage that run around problem Opt.

:meth:`~nehmo_core.planning.nehmo.NehmoPlanner.plan` is the paper's Algorithm 1 (evaluate every
pair, predict each peer's worst case, solve Opt, fall back to the HJI fail-safe) with a loop over
the stages its settings switch on. Each kind may change one thing and must keep the rest; none
may drop or weaken the V rows against a peer's worst case:

* :class:`Announcer`: the speed bound this arm announces, and the share of ū its commands keep;
* :class:`RowProvider`: linear rows ``A·y ≥ b`` on the step besides the V rows (the fail-safe and
  an unconstrained step are projected onto them too);
* :class:`PeerRowProvider`: linear rows that depend on this tick's peer values (added once the
  peers are evaluated, so an unconstrained step and the fail-safe computed ahead do not see them);
* :class:`Objective`: a target that replaces the goal in Opt's cost for a tick (the constraints
  stay as they are);
* :class:`CommandFilter`: shortens the command after the solve or the fail-safe;
* :class:`Fallback`: the command when Opt fails, is infeasible or late (the paper's is
  :class:`~nehmo_core.planning.opt.fail_safe.HjiFailSafe`).

A stage keeps its own state (``reset()`` clears it) and reads the planner through
:class:`Host`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.models.pair_frame import PairMapping
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.interface import check_peers, goal_error, one_joint_vector
from nehmo_core.planning.opt.problem import LinearRows
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell, RobotModel

__all__ = [
    "Announcer",
    "CommandFilter",
    "Fallback",
    "Host",
    "Objective",
    "PeerRowProvider",
    "RowProvider",
    "Stage",
    "margin_gaps",
    "peer_vectors",
    "read_tick",
]


class Host(Protocol):
    """What a stage may read of its planner."""

    @property
    def cell(self) -> Cell: ...

    @property
    def arm_id(self) -> str: ...

    @property
    def robot(self) -> RobotModel: ...

    @property
    def settings(self) -> PlannerSettings: ...

    @property
    def models(self) -> Sequence[PairValueModel]: ...

    @property
    def pairs(self) -> Mapping[str, PairMapping]: ...

    def evaluate(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        ids: list[str],
        bounds: Mapping[str, float],
    ) -> PeerValues:
        """``V`` and ``∇V`` at ``τ = b·t_plan`` of the pairs with peers ``ids`` now."""
        ...

    def group_margin(self, model_index: int, bound: float) -> float:
        """The margin [m] rows of model ``model_index`` keep against peers at ``bound``."""
        ...

    def ahead(self, q: np.ndarray) -> np.ndarray:
        """Where observed ``q`` goes under the command in flight, where the next one starts."""
        ...


class Stage(Protocol):
    """Every stage has a name (its settings group), state it can forget, and resources it
    releases when its planner is closed (a shared PyBullet world; most hold none)."""

    name: str

    def reset(self) -> None: ...

    def close(self) -> None: ...


class Announcer(Stage, Protocol):
    def announce(self, tick: Tick) -> None:
        """Set ``tick.announced`` and ``tick.cap`` for this command."""
        ...

    @property
    def announcement(self) -> float:
        """The bound announced with the latest command (a fraction of ū)."""
        ...

    @property
    def speed_cap(self) -> float:
        """The share of ū this arm's commands keep now."""
        ...


class RowProvider(Stage, Protocol):
    def rows(self, q: np.ndarray) -> LinearRows:
        """The rows ``A·y ≥ b`` on the step from joint vector ``q``."""
        ...


class PeerRowProvider(Stage, Protocol):
    def peer_rows(self, tick: Tick, now: PeerValues) -> LinearRows | None:
        """Rows ``A·y ≥ b`` on the step from this tick's peer values (``y = 0`` keeps them)."""
        ...


class Objective(Stage, Protocol):
    #: the Telemetry flag that says this stage steered the step
    flag: str

    def begin(self, tick: Tick) -> None:
        """Called first in every ``plan()`` (also for an arm with no peer in reach)."""
        ...

    def target(self, tick: Tick, now: PeerValues) -> np.ndarray | None:
        """A stand-in for ``e₀`` in Opt's cost this tick, or None. Called every tick with
        peers in reach, whichever stage steers."""
        ...

    def after(self, tick: Tick, min_constraint: float) -> None:
        """Called after the command (``min_constraint``: the smallest V row at the solution
        minus its margin [m], NaN after a fail-safe)."""
        ...


class CommandFilter(Stage, Protocol):
    #: commands this filter changed since the last reset
    shortened: int

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """The command [rad/s] to send instead of ``u``."""
        ...


class Fallback(Stage, Protocol):
    def command(self, now: PeerValues, u_max: float) -> np.ndarray:
        """The fail-safe command [rad/s] within ``u_max``."""
        ...


def margin_gaps(host: Host, now: PeerValues) -> np.ndarray:
    """``V_i − margin_i`` [m] of each peer in ``now``: its V at this tick less the margin its
    rows keep against a peer at the bound it announced (negative: the row is broken now)."""
    margins = [host.group_margin(m, b) for m, b in zip(now.model_index, now.bounds, strict=True)]
    return now.values - np.array(margins)


def read_tick(
    arm: Host,
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
        error0=goal_error(q, goal, arm.robot, arm.settings.opt.wrap_goal),
        peers=others,
        bounds=bounds,
        participants=frozenset(p for p in peer_bounds or {} if p in arm.pairs),
    )


def peer_vectors(cell: Cell, arm_id: str, peers: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """:func:`~nehmo_core.planning.opt.interface.check_peers`, one joint vector per peer."""
    checked = check_peers(cell, arm_id, peers)
    return {p: one_joint_vector(q, f"peers[{p!r}]") for p, q in checked.items()}
