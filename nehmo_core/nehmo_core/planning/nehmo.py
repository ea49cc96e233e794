"""The NeHMO planner of one arm: Algorithm 1 of the paper with problem Opt.

Every tick: map each peer in reach into a trained pair model's frame; evaluate ``V`` and ``∇V``
of all pairs at ``τ = t_plan`` from the current state (one batched call per model); predict each
peer under its worst case ``dⁱ = −d̄·sign(∂V/∂qⁱ)``; solve Opt; and if the solve fails, is
infeasible or misses the deadline, apply the fail-safe ``u = ū·sign(∂V/∂q¹)`` of the most
critical pair (the smallest ``V``), i.e. the HJI optimal control of that pair. With
``self_clearance`` on (the default; not in the paper), Opt also carries the arm's self-collision
damper rows and the fail-safe is projected onto them (:mod:`.self_clearance`). Peers out of
reach are skipped; peers in reach that no model fits are reported as unmodelled (they are not
constrained, so a caller must treat them as a configuration error or accept the risk).

Not in the paper, on by default: the stall escape (``escape``, :mod:`.stall_escape`) leaves a
local minimum on the safe set, or yields the goal, through Opt solutions with the same
constraints (safety unchanged); the exact guard (``exact_guard``, :mod:`.exact_guard`) shortens
a step that would bring the arm's real geometry too close to a peer holding at its goal.
"""

from __future__ import annotations

import math
import time
import zlib
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.models.margins import CertifiedMargins
from nehmo_core.planning.models.pair_frame import constrained_pairs
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.interface import (
    PlanResult,
    Telemetry,
    check_peers,
    goal_error,
    one_joint_vector,
)
from nehmo_core.planning.opt.problem import Constraints, OptProblem, worst_case_disturbance
from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.planning.solvers.base import OptSolver, SqpSolver, make_solver
from nehmo_core.planning.solvers.native import loop
from nehmo_core.planning.stages.exact_guard import GUARD_NEAR, closer_than, guard_step, prepare
from nehmo_core.planning.stages.fail_safe import MaximinFailSafe, maximin_command
from nehmo_core.planning.stages.self_clearance import SelfClearance, SelfClearanceRows, project_step
from nehmo_core.planning.stages.silent_peers import SilentPathWatch
from nehmo_core.planning.stages.speed_bounds import FULL_SPEED, check_bound
from nehmo_core.planning.stages.stall_escape import StallEscape
from nehmo_core.robots.model import Cell

__all__ = ["NehmoPlanner"]


def _peer_vectors(cell: Cell, arm_id: str, peers: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """:func:`check_peers`, with one joint vector per peer (no batches)."""
    checked = check_peers(cell, arm_id, peers)
    return {p: one_joint_vector(q, f"peers[{p!r}]") for p, q in checked.items()}


@dataclass(frozen=True)
class _Peers:
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


class NehmoPlanner(StallEscape):
    """NeHMO (or Opt + any pair value model) for arm ``arm_id`` of ``cell``."""

    def __init__(
        self,
        cell: Cell,
        arm_id: str,
        models: Sequence[PairValueModel],
        settings: PlannerSettings | None = None,
        solver: OptSolver | None = None,
    ) -> None:
        self.cell = cell
        self.arm_id = arm_id
        self.arm = cell.arm(arm_id)
        self.robot = self.arm.robot
        self.settings = settings or PlannerSettings()
        self.models = list(models)
        for model in self.models:
            if not self.settings.t_safe <= model.horizon + 1e-9:
                raise InvalidValueError(
                    "t_safe",
                    f"must be <= the horizon of model {model.name!r} ({model.horizon})",
                    self.settings.t_safe,
                )
        self.solver = solver or make_solver(self.settings)
        if isinstance(self.solver, SqpSolver) and self.solver.native:
            # build (first use in this cache) and load the C loop and models now, not in a tick
            c_loop = loop()
            if c_loop is not None:
                for model in self.models:
                    c_loop.model(model)
        self.pairs, self.peers_skipped, self.peers_unmodelled = constrained_pairs(
            cell, arm_id, [m.geometry for m in self.models], self.settings.reach_margin
        )
        used = [m.model_index for m in self.pairs.values()]
        self.margins = CertifiedMargins(self.models, self.settings, used)
        self.epsilon_source = self.margins.source
        self.settings = self.settings.replace(epsilon=self.margins.epsilon)
        self.reset()
        s = self.settings
        if s.exact_guard > 0.0 and s.hold_bound < FULL_SPEED and self.pairs:
            prepare(cell)
        self.self_clearance = (
            SelfClearance(self.robot, s.self_influence, s.self_safety, s.self_gain)
            if s.self_clearance
            else None
        )

    def group_margin(self, model_index: int, bound: float) -> float:
        """The margin [m] of model ``model_index``'s rows against peers planned at ``bound`` of
        full speed (:meth:`~nehmo_core.planning.models.margins.CertifiedMargins.group`)."""
        return self.margins.group(model_index, bound)

    def _self_rows(self, q: np.ndarray) -> SelfClearanceRows | None:
        return self.self_clearance.rows(q) if self.self_clearance is not None else None

    def _within_self_clearance(self, u: np.ndarray, rows: SelfClearanceRows | None) -> np.ndarray:
        """``u`` [rad/s], or the nearest command whose step keeps the self-clearance rows."""
        if rows is None or rows.count == 0:
            return u
        t = self.settings.t_plan
        return project_step(t * u, rows, t * self.settings.u_max) / t

    def reset(self) -> None:
        self._maximin = MaximinFailSafe(self.settings.fail_safe_band)
        # this arm's recent announcements (newest last); its commands keep the smallest
        self._announced = deque([FULL_SPEED], maxlen=self.settings.bound_release_ticks + 1)
        self._holding = False  # settled at the goal, announcing hold_bound
        self._last_current: tuple[object, _Peers] | None = None  # see _current
        # the last solution, the next solve's start; None: start at the naive step (at reset, and
        # after a fail-safe step, a corner of the box that says nothing about the next solution)
        self._warm: np.ndarray | None = None
        self._hessian: np.ndarray | None = None  # the last solve's Lagrangian Hessian estimate
        seed = zlib.crc32(self.arm_id.encode()) ^ self.settings.escape_seed
        self._rng = np.random.default_rng(seed)
        self._clear_stall()
        self.guarded = 0  # commands the exact guard shortened (planning/stages/exact_guard.py)
        s = self.settings
        robots = {p: self.cell.arm(p).robot for p in self.pairs}
        self._watch = SilentPathWatch(
            s.silent_lookahead, s.silent_clearance, s.tick, s.d_max, robots
        )

    # -- announced speed bound ---------------------------------------------------------------
    def _announce(
        self,
        error0: np.ndarray,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        bounds: Mapping[str, float],
        participants: frozenset[str],
    ) -> float:
        """This command's announcement (a fraction of ū; see :mod:`.speed_bounds`): hold_bound
        from within hold_tolerance of the goal until beyond hold_release, or until a peer breaks
        the slow game (:meth:`_threatened`), else full speed."""
        s = self.settings
        if s.hold_bound < FULL_SPEED:
            e = float(np.linalg.norm(error0))
            live = self._holding or e <= s.hold_tolerance  # else the threat test cannot matter
            if e > s.hold_release or (live and self._threatened(q, peers, bounds, participants)):
                self._holding = False
            elif e <= s.hold_tolerance:
                self._holding = True
        announced = s.hold_bound if self._holding else FULL_SPEED
        self._announced.append(announced)
        return announced

    def _threatened(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        bounds: Mapping[str, float],
        participants: frozenset[str],
    ) -> bool:
        """Whether a peer at full speed has broken the slow game with this arm near its goal:
        a participant (it plans against this arm's bound ``k`` and keeps ``V(k·t_safe)`` at its
        settled margin) brings ``V(k·t_plan)`` below half that margin, a peer that announces
        nothing below ε, or either comes within ``exact_guard`` of the real geometry. Either
        is fled from at full speed, after the withdrawal (:mod:`.speed_bounds`)."""
        s = self.settings
        ids = [p for p in self.pairs if bounds[p] >= FULL_SPEED]
        if not ids:
            return False
        slow = self._evaluate_current(q, peers, ids, dict.fromkeys(ids, s.hold_bound))
        half = [0.5 * self.group_margin(self.pairs[p].model_index, s.hold_bound) for p in ids]
        floor = [h if p in participants else s.epsilon for p, h in zip(ids, half, strict=True)]
        if np.any(slow.values < np.array(floor)):
            return True
        near = {p: peers[p] for p, v in zip(ids, slow.values, strict=True) if v < GUARD_NEAR}
        return closer_than(self.cell, self.arm_id, q, near, s.exact_guard)

    @property
    def announcement(self) -> float:
        """The speed bound this arm announced with its latest command (a fraction of ū)."""
        return self._announced[-1]

    @property
    def speed_cap(self) -> float:
        """The fraction of ū this arm's commands keep: the smallest of its announcements of
        the last ``bound_release_ticks`` commands and this one (a withdrawal is heard first)."""
        return min(self._announced)

    def _peer_bounds(self, peer_bounds: Mapping[str, float] | None) -> dict[str, float]:
        """Each constrained peer's bound (1 unless given)."""
        given = peer_bounds or {}
        return {
            p: check_bound(given[p], f"peer_bounds[{p!r}]") if p in given else FULL_SPEED
            for p in self.pairs
        }

    # -- one tick -----------------------------------------------------------------------------
    def _current(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        bounds: Mapping[str, float] | None = None,
        only_known: bool = False,
    ) -> _Peers:
        """The constrained peers' pair states, ``V`` and ``∇V`` at ``τ = b·t_plan`` now (``b``
        the peer's speed bound). The last answer is kept: a node asks for the fail-safe ahead of
        each solve from the same state, and the solve then reuses its evaluation."""
        ids = [p for p in self.pairs if p in peers] if only_known else list(self.pairs)
        if bounds is None:
            bounds = self._peer_bounds(None)
        key = (q.tobytes(), tuple((p, peers[p].tobytes(), bounds[p]) for p in ids))
        if self._last_current is not None and self._last_current[0] == key:
            return self._last_current[1]
        now = self._evaluate_current(q, peers, ids, bounds)
        self._last_current = (key, now)
        return now

    def _evaluate_current(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        ids: list[str],
        bounds: Mapping[str, float],
    ) -> _Peers:
        index = [self.pairs[p].model_index for p in ids]
        states = [self.pairs[p].state(q, peers[p]) for p in ids]
        values = np.empty(len(ids))
        grads: list[np.ndarray] = [np.empty(0)] * len(ids)
        now = _Peers(ids, index, states, values, grads, np.array([bounds[p] for p in ids]))
        for m, b, rows in now.groups:
            v, g = self.models[m].evaluate(
                b * self.settings.t_plan, np.array([states[i] for i in rows])
            )
            for k, i in enumerate(rows):
                values[i], grads[i] = v[k], g[k]
        return now

    def _problem(
        self,
        error0: np.ndarray,
        now: _Peers,
        self_rows: SelfClearanceRows | None = None,
        cap: float = FULL_SPEED,
    ) -> OptProblem:
        s, n1 = self.settings, self.robot.dof
        groups, horizons, margins = [], [], []
        for m, b, members in now.groups:
            predicted = np.array([now.states[i] for i in members])
            n12 = n1 + self.models[m].n2  # a conditioned model's r (after q²) never moves
            peer_grads = np.array([now.grads[i][n1:n12] for i in members])
            predicted[:, n1:n12] += s.t_plan * worst_case_disturbance(peer_grads, b * s.d_max)
            groups.append((m, predicted))
            horizons.append(b * s.t_safe)
            margins.append(self.group_margin(m, b))
        constraints = Constraints(
            self.models, groups, s.t_safe, s.epsilon, self_rows, tuple(horizons), tuple(margins)
        )
        return OptProblem(error0, s.t_plan * s.u_max * cap, s.t_plan, constraints)

    def _fail_safe(
        self, now: _Peers, rows: SelfClearanceRows | None = None, cap: float = FULL_SPEED
    ) -> np.ndarray:
        u = self._hji_fail_safe(now, cap * self.settings.u_max)
        return self._within_self_clearance(u, rows)

    def _hji_fail_safe(self, now: _Peers, u_max: float) -> np.ndarray:
        s, n1 = self.settings, self.robot.dof
        if s.fail_safe == "maximin" and len(now.ids) > 1:
            chosen = self._maximin.critical(now.ids, now.values)
            own = np.array([now.grads[i][:n1] for i in chosen])
            peer = np.array(
                [now.grads[i][n1 : n1 + self.models[now.model_index[i]].n2] for i in chosen]
            )
            values = now.values[chosen]
            d_max = s.d_max * now.bounds[chosen]
            return maximin_command(
                own, peer, u_max, d_max, values, s.t_plan, s.fail_safe_slack, s.fail_safe_harm
            )
        critical = int(np.argmin(now.values))
        g = now.grads[critical][: self.robot.dof]
        u = u_max * np.sign(g)
        if self.settings.fail_safe_deadband > 0.0:
            # joints that barely change V need not sweep at full speed (they cost V at most
            # ū·Σ|g_j| over the dead joints, and may fold the arm into itself)
            u[np.abs(g) < self.settings.fail_safe_deadband * np.abs(g).max()] = 0.0
        return u

    def fail_safe(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        """The fail-safe command (dof,) [rad/s] at this state: ``ū·sign(∂V/∂q¹)`` of the most
        critical constrained peer, or with ``fail_safe="maximin"`` the command that keeps every
        critical pair's worst-case V rate as high as possible (with self-clearance on, the
        nearest command that keeps the arm's self-clearance rows); zero (hold) when no peer is
        constrained.

        Cheap (one value-and-gradient evaluation); a ROS node computes it ahead of each solve
        so that a solve that overruns its tick still has a safe command to fall back on (a solve
        from the same state then reuses that evaluation).
        Peers missing from ``peers`` are left out (the caller decides what a missing peer means).
        ``peer_bounds`` and the arm's own speed cap as in :meth:`plan`.
        """
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        others = _peer_vectors(self.cell, self.arm_id, peers)
        if not any(p in others for p in self.pairs):
            return np.zeros(self.robot.dof)
        now = self._current(q, others, self._peer_bounds(peer_bounds), only_known=True)
        return self._fail_safe(now, self._self_rows(q), self.speed_cap)

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """One tick: the command for ``q_self`` among ``peers`` toward ``q_goal``.

        ``peer_bounds``: the speed bound (a fraction of d̄) each peer has announced and still
        keeps (:class:`~nehmo_core.planning.stages.speed_bounds.PeerBounds`); the peers in it take
        part in the announcements (they plan against this arm's), missing peers are planned at 1 and
        treated as silent. The command's own announcement is ``telemetry.speed_bound``.
        """
        start = time.perf_counter()
        deadline = start + self.settings.deadline
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        goal = one_joint_vector(self.robot.check_q(q_goal, "q_goal"), "q_goal")
        others = _peer_vectors(self.cell, self.arm_id, peers)
        missing = [p for p in self.pairs if p not in others]
        if missing:
            raise InvalidValueError(
                "peers", f"must include every constrained arm {missing}", list(others)
            )
        if self._goal is None or not np.array_equal(goal, self._goal):
            # a new goal (a controller need not call reset() between goals): a stall or an
            # escape toward the old one says nothing about the new one
            self._clear_stall()
            self._goal = goal.copy()
        error0 = goal_error(q, goal, self.robot, self.settings.wrap_goal)
        bounds = self._peer_bounds(peer_bounds)
        participants = frozenset(p for p in peer_bounds or {} if p in self.pairs)
        announced = self._announce(error0, q, others, bounds, participants)
        cap = self.speed_cap
        info: dict[str, Any] = {
            "peers_constrained": tuple(self.pairs),
            "peers_skipped": self.peers_skipped,
            "peers_unmodelled": self.peers_unmodelled,
            "speed_bound": announced,
        }
        rows = self._self_rows(q)
        if not self.pairs:
            y_max = self.settings.t_plan * self.settings.u_max * cap
            y = np.clip(-error0, -y_max, y_max)
            u = self._within_self_clearance(y / self.settings.t_plan, rows)
            self._warm = u * self.settings.t_plan
            return PlanResult(u, Telemetry(time.perf_counter() - start, "unconstrained", **info))
        now = self._current(q, others, bounds)
        escaping = self.settings.escape and self._escape_left > 0
        away = self._watch.target(
            self.models, now.ids, now.model_index, now.states, now.values,
            self._watch.velocities(others, participants), self.robot.dof,
            self.settings.t_plan, self.settings.t_plan * self.settings.u_max * cap,
        )  # fmt: skip
        target = self._escape_error(now) if escaping else error0
        problem = self._problem(target if away is None else away, now, rows, cap)
        try:
            hessian = self._hessian if self.settings.sqp_warm_hessian else None
            y_start = problem.naive_step() if self._warm is None else self._warm
            result = self.solver(problem, y_start, deadline, hessian)
            status = result.status
        except Exception as exc:  # any solver crash must end in the fail-safe
            result, status = None, f"failed ({type(exc).__name__})"
        late = time.perf_counter() > deadline
        if late and result is not None and result.success:
            status = "timeout"
        critical = now.ids[int(np.argmin(now.values))]
        if result is not None and result.success and not late:
            u = problem.velocity(result.y)
            self._warm = result.y
            if result.hessian is not None:
                self._hessian = result.hessian
            value_rows = result.constraint[: len(now.ids)]  # V rows first, then self-clearance
            min_constraint = float(value_rows.min()) if len(value_rows) else math.nan
            fail_safe = False
        else:
            u = self._fail_safe(now, rows, cap)
            self._warm = None
            min_constraint, fail_safe = math.nan, True
        near = [p for p, v in zip(now.ids, now.values, strict=True) if v < GUARD_NEAR]
        held = {p: others[p] for p in near if p in participants and bounds[p] < FULL_SPEED}
        share = guard_step(self.cell, self.arm_id, q, u, held, self.settings)
        u, self.guarded = u * share, self.guarded + (share < 1.0)
        if self.settings.escape and away is None:  # stepping aside is no stall
            self._track_stall(error0, min_constraint < self.settings.stall_margin)
        telemetry = Telemetry(
            solve_time=time.perf_counter() - start,
            status=status,
            fail_safe=fail_safe,
            min_value=float(now.values.min()),
            min_constraint=min_constraint,
            iterations=result.iterations if result is not None else 0,
            critical_peer=critical,
            escaping=escaping and away is None and not fail_safe,  # else it followed no escape
            evading=away is not None and not fail_safe,
            **info,
        )
        return PlanResult(u, telemetry)
