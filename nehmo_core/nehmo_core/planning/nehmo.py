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

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.fail_safe import HjiFailSafe
from nehmo_core.planning.opt.interface import PlanResult, Telemetry, one_joint_vector
from nehmo_core.planning.opt.pairs import PeerPairs
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.pipeline import (
    Announcer,
    CommandFilter,
    Fallback,
    Objective,
    PeerRowProvider,
    RowProvider,
    Stage,
    peer_vectors,
    read_tick,
)
from nehmo_core.planning.opt.problem import LinearRows, OptProblem, project_step, stack_rows
from nehmo_core.planning.opt.tick import NO_PEERS, PeerValues, Tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.base import OptSolver, make_solver, ready_solver
from nehmo_core.planning.stages import build_stages
from nehmo_core.robots.model import Cell

__all__ = ["NehmoPlanner"]

Bounds = Mapping[str, float]  # each peer's speed bound, a fraction of d̄
Poses = Mapping[str, np.ndarray]  # each peer's joint vector
States = Mapping[str, ArrayLike]  # each peer's joint vector, as a caller gives it


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
        self.solver = ready_solver(solver or make_solver(self.settings), self.models, self.settings)
        self.opt = PeerPairs(cell, arm_id, self.models, self.settings)
        self.pairs, self.margins = self.opt.pairs, self.opt.margins
        self.settings = self.opt.settings  # ε raised by the certified margins
        self.peers_skipped, self.peers_unmodelled = self.opt.skipped, self.opt.unmodelled
        self.epsilon_source = self.margins.source
        s = self.settings
        staged = build_stages(self)
        self.stages: tuple[Stage, ...] = staged.all
        self._announcer: Announcer | None = staged.announcer
        self._row_providers: tuple[RowProvider, ...] = staged.rows
        self._peer_rows: tuple[PeerRowProvider, ...] = staged.peer_rows
        self._objectives: tuple[Objective, ...] = staged.objectives
        self._filters: tuple[CommandFilter, ...] = staged.filters
        self._fallback: Fallback = HjiFailSafe(self.robot.dof, s.fail_safe.deadband)
        self.reset()

    def stage(self, name: str) -> Stage:
        """The stage named ``name`` (its settings group); KeyError if it is off."""
        for s in (*self.stages, self._fallback):
            if s.name == name:
                return s
        raise KeyError(f"no stage {name!r} in this planner (on: {[s.name for s in self.stages]})")

    def close(self) -> None:
        """Release what the stages hold (shared PyBullet worlds; also when garbage-collected)."""
        for stage in (*self.stages, self._fallback):
            stage.close()

    def reset(self) -> None:
        """Forget everything of the last episode (stages included)."""
        self.opt.forget()
        # the last solution, the next solve's start; None: start at the naive step (at reset, and
        # after a fail-safe step, a corner of the box that says nothing about the next solution)
        self._warm: np.ndarray | None = None
        self._hessian: np.ndarray | None = None  # the last solve's Lagrangian Hessian estimate
        self._sent = np.zeros(self.robot.dof)  # the last command: it runs during the next plan
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
        """The margin [m] rows of model ``model_index`` keep against peers at ``bound``."""
        return self.opt.group_margin(model_index, bound)

    def evaluate(self, q: np.ndarray, peers: Poses, ids: list[str], bounds: Bounds) -> PeerValues:
        """:meth:`PeerPairs.evaluate` (uncached)."""
        return self.opt.evaluate(q, peers, ids, bounds)

    def current(
        self, q: np.ndarray, peers: Poses, bounds: Bounds | None = None, only_known: bool = False
    ) -> PeerValues:
        """:meth:`PeerPairs.current` (the last evaluation is kept)."""
        return self.opt.current(q, peers, bounds, only_known)

    def problem(
        self,
        target: np.ndarray,
        now: PeerValues,
        rows: LinearRows | None = None,
        cap: float = FULL_SPEED,
    ) -> OptProblem:
        """:meth:`PeerPairs.problem`: Opt toward ``target`` (a stand-in for ``e₀``)."""
        return self.opt.problem(target, now, rows, cap)

    def rows(self, q: np.ndarray) -> LinearRows | None:
        """The row providers' rows (None without one) for a step from observed ``q``: built
        where the command in flight takes the arm (:meth:`ahead`), where the step starts."""
        if not self._row_providers:
            return None
        start = self.ahead(q)
        return stack_rows(*(p.rows(start) for p in self._row_providers))

    def commanded(self, u: ArrayLike) -> None:
        """The command [rad/s] running while the next :meth:`plan` does, when a control loop
        sent another than the last ``plan()`` result (a hold, a late fail-safe)."""
        self._sent = one_joint_vector(self.robot.check_q(u, "u"), "u")

    def ahead(self, q: np.ndarray) -> np.ndarray:
        """Where observed ``q`` goes in one ``opt.tick`` under the command in flight (``q``
        itself with ``self_clearance.ahead`` off)."""
        s = self.settings
        return q + s.opt.tick * self._sent if s.self_clearance.ahead else q

    def keep_rows(self, u: np.ndarray, rows: LinearRows | None) -> np.ndarray:
        """``u`` [rad/s], or the nearest command whose step keeps ``rows``."""
        if rows is None or rows.count == 0:
            return u
        t = self.settings.opt.t_plan
        return project_step(t * u, rows, t * self.settings.opt.u_max) / t

    def fail_safe_command(
        self, now: PeerValues, rows: LinearRows | None = None, cap: float = FULL_SPEED
    ) -> np.ndarray:
        """The fallback's command within ``cap·ū``, kept within ``rows``."""
        return self.keep_rows(self._fallback.command(now, cap * self.settings.opt.u_max), rows)

    def fail_safe(
        self, q_self: ArrayLike, peers: States, peer_bounds: Bounds | None = None
    ) -> np.ndarray:
        """The fail-safe command (dof,) [rad/s] at this state: ``ū·sign(∂V/∂q¹)`` of the most
        critical constrained peer, kept within the row providers' rows; zero (hold) when no
        peer is constrained. Cheap (one value-and-gradient evaluation); a ROS node computes it
        ahead of each solve so that a solve that overruns its tick still has a safe command to
        fall back on (a solve from the same state then reuses that evaluation).
        Peers missing from ``peers`` are left out (the caller decides what a missing peer means).
        ``peer_bounds`` and the arm's own speed cap as in :meth:`plan`.
        """
        q = one_joint_vector(self.robot.check_q(q_self, "q_self"), "q_self")
        others = peer_vectors(self.cell, self.arm_id, peers)
        if not any(p in others for p in self.pairs):
            return np.zeros(self.robot.dof)
        now = self.current(q, others, self.opt.bounds(peer_bounds), only_known=True)
        return self.fail_safe_command(now, self.rows(q), self.speed_cap)

    # -- one tick -----------------------------------------------------------------------------
    def plan(
        self, q_self: ArrayLike, peers: States, q_goal: ArrayLike, peer_bounds: Bounds | None = None
    ) -> PlanResult:
        """One tick: the command for ``q_self`` among ``peers`` toward ``q_goal``.

        ``peer_bounds``: the speed bound (a fraction of d̄) each peer has announced and still
        keeps (:class:`~nehmo_core.planning.opt.peer_bounds.PeerBounds`); the peers in it take
        part in the announcements (they plan against this arm's), missing peers are planned at 1
        and treated as silent. The command's own announcement is ``telemetry.speed_bound``.
        """
        start = time.perf_counter()
        deadline = start + self.settings.opt.deadline
        tick = read_tick(self, q_self, peers, q_goal, self.opt.bounds(peer_bounds), peer_bounds)
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
            y_max = s.opt.t_plan * s.opt.u_max * tick.cap
            u = self.keep_rows(np.clip(-tick.error0, -y_max, y_max) / s.opt.t_plan, tick.rows)
            for command_filter in self._filters:  # no peer to guard against: they see none
                u = command_filter.filter(tick, NO_PEERS, u)
            self._warm = u * s.opt.t_plan
            self._sent = u
            return PlanResult(u, Telemetry(time.perf_counter() - start, "unconstrained", **info))
        now = self.current(tick.q, tick.peers, tick.bounds)
        tick.rows = stack_rows(tick.rows, *(p.peer_rows(tick, now) for p in self._peer_rows))
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
        tick.fail_safe = fail_safe
        for command_filter in self._filters:
            u = command_filter.filter(tick, now, u)
        self._sent = u
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
            hessian = self._hessian if self.settings.solver.sqp_warm_hessian else None
            y_start = problem.naive_step() if self._warm is None else self._warm
            result = self.solver(problem, y_start, deadline, hessian)
            return result, result.status
        except Exception as exc:  # any solver crash must end in the fail-safe
            return None, f"failed ({type(exc).__name__})"
