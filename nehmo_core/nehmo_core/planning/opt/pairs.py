"""The constrained peers of one arm, and problem Opt built from them each tick.

:class:`PeerPairs` maps each peer in reach into a pair model's frame
(:func:`~nehmo_core.planning.models.pair_frame.constrained_pairs`), keeps the certified margins
(:class:`~nehmo_core.planning.models.margins.CertifiedMargins`: ε raised to the largest certified
δ), evaluates ``V`` and ``∇V`` of every pair at once (one batched call per model and speed
bound) and assembles Opt: each peer moved by its worst case ``dⁱ = −d̄·sign(∂V/∂qⁱ)``, its V rows
at time-to-go ``b·t_safe`` for a peer that keeps an announced bound ``b``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from nehmo_core.planning.models.margins import CertifiedMargins
from nehmo_core.planning.models.pair_frame import constrained_pairs
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED, check_bound
from nehmo_core.planning.opt.problem import Constraints, LinearRows, OptProblem
from nehmo_core.planning.opt.problem import worst_case_disturbance as worst_case
from nehmo_core.planning.opt.tick import PeerValues
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = ["PeerPairs"]


class PeerPairs:
    """Arm ``arm_id``'s constrained peers under ``models``; ``settings`` comes back with ε
    raised by the certified margins (:attr:`settings`)."""

    def __init__(
        self,
        cell: Cell,
        arm_id: str,
        models: Sequence[PairValueModel],
        settings: PlannerSettings,
    ) -> None:
        self.robot = cell.arm(arm_id).robot
        self.models = list(models)
        self.pairs, self.skipped, self.unmodelled = constrained_pairs(
            cell, arm_id, [m.geometry for m in self.models], settings.opt.reach_margin
        )
        self.margins = CertifiedMargins(
            self.models,
            [m.model_index for m in self.pairs.values()],
            settings.opt.epsilon,
            settings.hold.settled_epsilon,
            settings.opt.t_safe,
            settings.margins.certified,
            settings.margins.actuators,
        )
        self.settings = settings.override({"opt.epsilon": self.margins.epsilon})
        self._last: tuple[object, PeerValues] | None = None  # see current()

    def forget(self) -> None:
        """Drop the kept evaluation (a new episode)."""
        self._last = None

    def group_margin(self, model_index: int, bound: float) -> float:
        """The margin [m] of model ``model_index``'s rows against peers planned at ``bound`` of
        full speed (:meth:`~nehmo_core.planning.models.margins.CertifiedMargins.group`)."""
        return self.margins.group(model_index, bound)

    def bounds(self, peer_bounds: Mapping[str, float] | None) -> dict[str, float]:
        """Each constrained peer's bound (1 unless given)."""
        given = peer_bounds or {}
        return {
            p: check_bound(given[p], f"peer_bounds[{p!r}]") if p in given else FULL_SPEED
            for p in self.pairs
        }

    def current(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        bounds: Mapping[str, float] | None = None,
        only_known: bool = False,
    ) -> PeerValues:
        """The constrained peers' pair states, ``V`` and ``∇V`` at ``τ = b·t_plan`` now (``b``
        the peer's speed bound). The last answer is kept: a node asks for the fail-safe ahead of
        each solve from the same state, and the solve then reuses its evaluation."""
        ids = [p for p in self.pairs if p in peers] if only_known else list(self.pairs)
        if bounds is None:
            bounds = self.bounds(None)
        key = (q.tobytes(), tuple((p, peers[p].tobytes(), bounds[p]) for p in ids))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        now = self.evaluate(q, peers, ids, bounds)
        self._last = (key, now)
        return now

    def evaluate(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        ids: list[str],
        bounds: Mapping[str, float],
    ) -> PeerValues:
        """``V`` and ``∇V`` at ``τ = b·t_plan`` of the pairs with peers ``ids`` (uncached)."""
        index = [self.pairs[p].model_index for p in ids]
        states = [self.pairs[p].state(q, peers[p]) for p in ids]
        values = np.empty(len(ids))
        grads: list[np.ndarray] = [np.empty(0)] * len(ids)
        now = PeerValues(ids, index, states, values, grads, np.array([bounds[p] for p in ids]))
        for m, b, members in now.groups:
            v, g = self.models[m].evaluate(
                b * self.settings.opt.t_plan, np.array([states[i] for i in members])
            )
            for k, i in enumerate(members):
                values[i], grads[i] = v[k], g[k]
        return now

    def problem(
        self,
        target: np.ndarray,
        now: PeerValues,
        rows: LinearRows | None = None,
        cap: float = FULL_SPEED,
    ) -> OptProblem:
        """Problem Opt toward ``target`` (a stand-in for ``e₀``): the V rows of every
        constrained peer at its predicted worst case, ``rows`` after them."""
        s, n1 = self.settings, self.robot.dof
        groups, horizons, margins = [], [], []
        for m, b, members in now.groups:
            predicted = np.array([now.states[i] for i in members])
            n12 = n1 + self.models[m].n2  # a conditioned model's r (after q²) never moves
            peer_grads = np.array([now.grads[i][n1:n12] for i in members])
            predicted[:, n1:n12] += s.opt.t_plan * worst_case(peer_grads, b * s.opt.d_max)
            groups.append((m, predicted))
            horizons.append(b * s.opt.t_safe)
            margins.append(self.group_margin(m, b))
        constraints = Constraints(
            self.models, groups, s.opt.t_safe, s.opt.epsilon, rows, tuple(horizons), tuple(margins)
        )
        return OptProblem(target, s.opt.t_plan * s.opt.u_max * cap, s.opt.t_plan, constraints)
