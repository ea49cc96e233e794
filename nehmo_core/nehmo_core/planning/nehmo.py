"""The NeHMO planner of one arm: Algorithm 1 of the paper with problem Opt, and its stages.

Every tick (:meth:`NehmoPlanner.plan`): map each peer in reach into a trained pair model's frame;
evaluate ``V`` and ``∇V`` of all pairs at ``τ = t_plan`` from the current state (one batched call
per model); predict each peer under its worst case ``dⁱ = −d̄·sign(∂V/∂qⁱ)``; solve Opt; and if
the solve fails, is infeasible or misses the deadline, apply the fail-safe
``u = ū·sign(∂V/∂q¹)`` of the most critical pair, the HJI optimal control of that pair. Peers out
of reach are skipped; peers in reach that no model fits are reported as unmodelled (they are not
constrained, so a caller must treat them as a configuration error or accept the risk).

Around that core run the stages the settings switch on (:mod:`nehmo_core.planning.opt.pipeline`
says what each kind may change; :mod:`nehmo_core.planning.stages` holds them, all off in the
``paper`` preset): an announcer of speed bounds, row providers, objectives, command filters and
a fallback other than the paper's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.models.margins import CertifiedMargins
from nehmo_core.planning.models.pair_frame import constrained_pairs
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.fail_safe import HjiFailSafe
from nehmo_core.planning.opt.interface import (
    PlanResult,
    Telemetry,
    check_peers,
    goal_error,
    one_joint_vector,
)
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED, check_bound
from nehmo_core.planning.opt.pipeline import (
    Announcer,
    CommandFilter,
    Fallback,
    Objective,
    RowProvider,
    Stage,
)
from nehmo_core.planning.opt.problem import Constraints, LinearRows, OptProblem, project_step
from nehmo_core.planning.opt.problem import worst_case_disturbance as worst_case
from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.solvers.base import OptSolver, SqpSolver, make_solver
from nehmo_core.planning.solvers.native import loop
from nehmo_core.planning.stages import build_stages
from nehmo_core.robots.model import Cell

__all__ = ["NehmoPlanner"]


class NehmoPlanner:
    """NeHMO (or Opt + any pair value model) for arm ``arm_id`` of ``cell``."""

    announces = True  # it plans against its peers' announced bounds and announces its own

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
        self.robot = cell.arm(arm_id).robot
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
        s = self.settings
        self.margins = CertifiedMargins(
            self.models,
            [m.model_index for m in self.pairs.values()],
            s.epsilon,
            s.settled_epsilon,
            s.t_safe,
            s.certified_epsilon,
        )
        self.epsilon_source = self.margins.source
        self.settings = s.replace(epsilon=self.margins.epsilon)
        staged = build_stages(self)
        self.stages: tuple[Stage, ...] = staged.all
        self._announcer: Announcer | None = staged.announcer
        self._row_providers: tuple[RowProvider, ...] = staged.rows
        self._objectives: tuple[Objective, ...] = staged.objectives
        self._filters: tuple[CommandFilter, ...] = staged.filters
        self._fallback: Fallback = staged.fallback or HjiFailSafe(
            self.robot.dof, s.fail_safe_deadband
        )
        self.reset()

    def stage(self, name: str) -> Stage:
        """The stage named ``name`` (its settings group); KeyError if it is off."""
        for s in (*self.stages, self._fallback):
            if s.name == name:
                return s
        raise KeyError(f"no stage {name!r} in this planner (on: {[s.name for s in self.stages]})")

    def reset(self) -> None:
        """Forget everything of the last episode (stages included)."""
        self._last_current: tuple[object, PeerValues] | None = None  # see current()
        # the last solution, the next solve's start; None: start at the naive step (at reset, and
        # after a fail-safe step, a corner of the box that says nothing about the next solution)
        self._warm: np.ndarray | None = None
        self._hessian: np.ndarray | None = None  # the last solve's Lagrangian Hessian estimate
        self._fallback.reset()
        for stage in self.stages:
            stage.reset()

    # -- what stages and tools read ---------------------------------------------------------
    @property
    def announcement(self) -> float:
        """The speed bound this arm announced with its latest command (a fraction of ū)."""
        return self._announcer.announcement if self._announcer is not None else FULL_SPEED

    @property
    def speed_cap(self) -> float:
        """The fraction of ū this arm's commands keep (see the announcer stage)."""
        return self._announcer.speed_cap if self._announcer is not None else FULL_SPEED

    @property
    def guarded(self) -> int:
        """Commands the command filters shortened since the last reset."""
        return sum(f.shortened for f in self._filters)

    def group_margin(self, model_index: int, bound: float) -> float:
        """The margin [m] of model ``model_index``'s rows against peers planned at ``bound`` of
        full speed (:meth:`~nehmo_core.planning.models.margins.CertifiedMargins.group`)."""
        return self.margins.group(model_index, bound)

    def rows(self, q: np.ndarray) -> LinearRows | None:
        """The row providers' rows at ``q`` (None without a row provider)."""
        if not self._row_providers:
            return None
        if len(self._row_providers) == 1:
            return self._row_providers[0].rows(q)
        parts = [p.rows(q) for p in self._row_providers]
        return LinearRows(np.vstack([r.A for r in parts]), np.concatenate([r.b for r in parts]))

    def keep_rows(self, u: np.ndarray, rows: LinearRows | None) -> np.ndarray:
        """``u`` [rad/s], or the nearest command whose step keeps ``rows``."""
        if rows is None or rows.count == 0:
            return u
        t = self.settings.t_plan
        return project_step(t * u, rows, t * self.settings.u_max) / t

    def peer_bounds(self, peer_bounds: Mapping[str, float] | None) -> dict[str, float]:
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
            bounds = self.peer_bounds(None)
        key = (q.tobytes(), tuple((p, peers[p].tobytes(), bounds[p]) for p in ids))
        if self._last_current is not None and self._last_current[0] == key:
            return self._last_current[1]
        now = self.evaluate(q, peers, ids, bounds)
        self._last_current = (key, now)
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
                b * self.settings.t_plan, np.array([states[i] for i in members])
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
            predicted[:, n1:n12] += s.t_plan * worst_case(peer_grads, b * s.d_max)
            groups.append((m, predicted))
            horizons.append(b * s.t_safe)
            margins.append(self.group_margin(m, b))
        constraints = Constraints(
            self.models, groups, s.t_safe, s.epsilon, rows, tuple(horizons), tuple(margins)
        )
        return OptProblem(target, s.t_plan * s.u_max * cap, s.t_plan, constraints)

    def fail_safe_command(
        self, now: PeerValues, rows: LinearRows | None = None, cap: float = FULL_SPEED
    ) -> np.ndarray:
        """The fallback's command within ``cap·ū``, kept within ``rows``."""
        return self.keep_rows(self._fallback.command(now, cap * self.settings.u_max), rows)

    def fail_safe(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        """The fail-safe command (dof,) [rad/s] at this state: ``ū·sign(∂V/∂q¹)`` of the most
        critical constrained peer (or the fallback stage's command, e.g. maximin), kept within
        the row providers' rows; zero (hold) when no peer is constrained.

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
        now = self.current(q, others, self.peer_bounds(peer_bounds), only_known=True)
        return self.fail_safe_command(now, self.rows(q), self.speed_cap)

    # -- one tick -----------------------------------------------------------------------------
    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """One tick: the command for ``q_self`` among ``peers`` toward ``q_goal``.

        ``peer_bounds``: the speed bound (a fraction of d̄) each peer has announced and still
        keeps (:class:`~nehmo_core.planning.opt.peer_bounds.PeerBounds`); the peers in it take
        part in the announcements (they plan against this arm's), missing peers are planned at 1
        and treated as silent. The command's own announcement is ``telemetry.speed_bound``.
        """
        start = time.perf_counter()
        deadline = start + self.settings.deadline
        tick = self._tick(q_self, peers, q_goal, peer_bounds)
        for objective in self._objectives:
            objective.begin(tick)
        if self._announcer is not None:
            self._announcer.announce(tick)
        info: dict[str, Any] = {
            "peers_constrained": tuple(self.pairs),
            "peers_skipped": self.peers_skipped,
            "peers_unmodelled": self.peers_unmodelled,
            "speed_bound": tick.announced,
        }
        s = self.settings
        tick.rows = self.rows(tick.q)
        if not self.pairs:
            y_max = s.t_plan * s.u_max * tick.cap
            u = self.keep_rows(np.clip(-tick.error0, -y_max, y_max) / s.t_plan, tick.rows)
            self._warm = u * s.t_plan
            return PlanResult(u, Telemetry(time.perf_counter() - start, "unconstrained", **info))
        now = tick.now = self.current(tick.q, tick.peers, tick.bounds)
        target = self._target(tick, now)
        problem = self.problem(target, now, tick.rows, tick.cap)
        result, status = self._solve(problem, deadline)
        late = time.perf_counter() > deadline
        if late and result is not None and result.success:
            status = "timeout"
        if result is not None and result.success and not late:
            u = problem.velocity(result.y)
            self._warm = result.y
            if result.hessian is not None:
                self._hessian = result.hessian
            value_rows = result.constraint[: len(now.ids)]  # V rows first, then linear rows
            min_constraint = float(value_rows.min()) if len(value_rows) else math.nan
            fail_safe = False
        else:
            u = self.fail_safe_command(now, tick.rows, tick.cap)
            self._warm = None
            min_constraint, fail_safe = math.nan, True
        for command_filter in self._filters:
            u = command_filter.filter(tick, now, u)
        for objective in self._objectives:
            objective.after(tick, min_constraint)
        steered = {o.flag: tick.steered_by == o.name and not fail_safe for o in self._objectives}
        telemetry = Telemetry(
            solve_time=time.perf_counter() - start,
            status=status,
            fail_safe=fail_safe,
            min_value=float(now.values.min()),
            min_constraint=min_constraint,
            iterations=result.iterations if result is not None else 0,
            critical_peer=now.ids[now.critical],
            escaping=steered.get("escaping", False),
            evading=steered.get("evading", False),
            **info,
        )
        return PlanResult(u, telemetry)

    def _tick(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None,
    ) -> Tick:
        """The call's inputs, checked."""
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        goal = one_joint_vector(self.robot.check_q(q_goal, "q_goal"), "q_goal")
        others = _peer_vectors(self.cell, self.arm_id, peers)
        missing = [p for p in self.pairs if p not in others]
        if missing:
            raise InvalidValueError(
                "peers", f"must include every constrained arm {missing}", list(others)
            )
        return Tick(
            q=q,
            goal=goal,
            error0=goal_error(q, goal, self.robot, self.settings.wrap_goal),
            peers=others,
            bounds=self.peer_bounds(peer_bounds),
            participants=frozenset(p for p in peer_bounds or {} if p in self.pairs),
        )

    def _target(self, tick: Tick, now: PeerValues) -> np.ndarray:
        """Opt's target this tick: the first objective stage's stand-in for ``e₀`` (every
        objective sees every tick), else ``e₀``."""
        targets = [(o.name, o.target(tick, now)) for o in self._objectives]
        for name, target in targets:
            if target is not None:
                tick.steered_by = name
                return target
        return tick.error0

    def _solve(self, problem: OptProblem, deadline: float) -> tuple[Any, str]:
        """The solver's result from the warm start (None if it crashed) and its status."""
        try:
            hessian = self._hessian if self.settings.sqp_warm_hessian else None
            y_start = problem.naive_step() if self._warm is None else self._warm
            result = self.solver(problem, y_start, deadline, hessian)
            return result, result.status
        except Exception as exc:  # any solver crash must end in the fail-safe
            return None, f"failed ({type(exc).__name__})"


def _peer_vectors(cell: Cell, arm_id: str, peers: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
    """:func:`check_peers`, with one joint vector per peer (no batches)."""
    checked = check_peers(cell, arm_id, peers)
    return {p: one_joint_vector(q, f"peers[{p!r}]") for p, q in checked.items()}
