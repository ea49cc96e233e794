"""One arm's control loop without a middleware: state buffer, solve worker, fail-safe rules.

The ``arm_planner`` node is a thin shell around :class:`ArmController` (tested without ROS;
the node's behaviour, not a planning algorithm, hence in ``nehmo_ros``). At tick ``k`` the
controller publishes the command solved from the observations of tick ``k − 1`` and hands those
of tick ``k`` to a worker thread: a solve has one period while the current command executes.

Rules, in order of precedence, for the command of a tick:

1. no fresh own state, own state untrusted (see below), or no goal yet → hold still;
2. the solve of the previous tick has not finished (missed deadline) → the fail-safe computed
   from the previous observations before that solve started (hold still once that fail-safe is
   older than ``peer_timeout``); any command planned from observations over ``plan_age`` (1.5)
   periods older than the tick (the process ran late) → hold still (``late_plan``): it was
   checked for a period that has passed;
3. a peer in the cell has never been heard from → hold still;
4. a peer's state is stale (older than ``peer_timeout``) or untrusted → ``stale_policy``: hold
   still (``hold``, the default) or the fail-safe against its latest valid state
   (``fail_safe``). Holding measured safer: with a silent NeHMO peer, 1 % collisions against
   10 % for the fail-safe (100 dual-UR5 episodes, ``python -m nehmo_ros.fault_episodes``);
5. the solver failed, was infeasible or late inside ``plan`` → the planner's fail-safe;
6. otherwise the planner's command.

Peers' announced speed bounds (:mod:`nehmo_core.planning.stages.speed_bounds`) come through
:meth:`ArmController.announce`; each valid joint state is checked against them, and every peer
is planned against the bound it still keeps (own: :attr:`ArmController.announcement`).
Every command is clipped to ±``u_max``; a non-finite one becomes a hold. A missed deadline
reports no solve time (NaN); the abandoned solve's time comes with the first command after it
finished (``Decision.late_solve_time``).

Joint states that are NaN/inf, of the wrong length or with unknown joint names are rejected
(counted) and leave the previous valid state in place, so a peer sending only garbage turns
stale. A valid state that moved further than the arm can (a *jump*: more than ``jump_margin +
2·speed·Δt`` on some joint, ``speed`` = ``d_max`` for peers and ``u_max`` for the own arm,
``Δt`` the larger of the receive and the header-stamp intervals) is kept but counted. A rejected
state or a jump makes that arm *untrusted* for ``peer_timeout``: its data broke the model the
safety argument rests on. Times here are monotonic seconds given by the caller.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.interface import Planner, Telemetry
from nehmo_core.planning.opt.peer_bounds import PeerBounds
from nehmo_core.robots.model import Cell
from nehmo_ros.control_settings import STALE_POLICIES, ControlSettings, Counters
from nehmo_ros.solve_worker import Decision, Observation, SolveWorker, zeros
from nehmo_ros.state_buffer import StateBuffer, order_joints

__all__ = [
    "STALE_POLICIES",
    "ArmController",
    "ControlSettings",
    "Decision",
    "Observation",
    "StateBuffer",
]


class ArmController:
    """Per-tick command of one arm: the planner runs in a worker, the rules above around it."""

    def __init__(
        self, cell: Cell, arm_id: str, planner: Planner, settings: ControlSettings | None = None
    ) -> None:
        self.cell, self.arm_id = cell, arm_id
        self.robot = cell.arm(arm_id).robot
        self.planner = planner
        self.settings = settings or ControlSettings()
        self.peer_ids = tuple(a for a in cell.arm_ids if a != arm_id)
        s = self.settings
        speed = {a: s.opt.u_max if a == arm_id else s.opt.d_max for a in cell.arm_ids}
        self.states = StateBuffer(cell, speed, s.jump_margin)
        self.counters = Counters()
        self._goal: np.ndarray | None = None
        self._goal_lock = threading.Lock()
        self._tick = 0
        self.last_observation: Observation | None = None
        self._submitted: Observation | None = None  # the job whose result is due next tick
        self._due: Observation | None = None  # this tick's job, not yet submitted
        self._abandoned: int | None = None  # tick of a late job whose solve time is not out yet
        self._fallback_lock = threading.Lock()
        #: (tick, fail-safe, observation stamp [ns]) of the latest job
        self._fallback: tuple[int, np.ndarray, int] | None = None
        self._finished: dict[int, float] = {}  # tick → solve time of jobs finished lately
        self._worker = SolveWorker(self._solve, name=f"solve_{arm_id}")
        self._bounds = PeerBounds(s.opt.d_max)
        self._bounds_lock = threading.Lock()
        self._paused = False  # held with zero commands, no planning
        self._resuming = False  # the next solve starts from an observation made after resume

    def telemetry(self, decision: Decision) -> Telemetry:
        """The planner-status telemetry of ``decision`` (the planner's own when it ran)."""
        if decision.telemetry is not None:
            return replace(decision.telemetry, status=decision.status)
        return Telemetry(decision.solve_time, decision.status, fail_safe=decision.fail_safe)

    # -- inputs (any thread) ----------------------------------------------------------------
    def set_goal(self, names: Sequence[str], position: Sequence[float]) -> np.ndarray:
        """Validate and store the goal [rad] (joint names, finiteness, joint limits)."""
        q = order_joints(self.robot, names, position, f"/{self.arm_id}/goal")
        q = self.robot.check_within_limits(q, f"/{self.arm_id}/goal")
        with self._goal_lock:
            self._goal = q
        return q

    @property
    def goal(self) -> np.ndarray | None:
        with self._goal_lock:
            return self._goal

    def update_state(
        self,
        arm_id: str,
        names: Sequence[str],
        position: Sequence[float],
        now: float,
        stamp_ns: int = 0,
    ) -> str | None:
        """:meth:`StateBuffer.update`; a stored peer state is also checked against the peer's
        announced speed bound (timed by its header stamp when it has one)."""
        note = self.states.update(arm_id, names, position, now, stamp_ns)
        if arm_id != self.arm_id and (note is None or note.startswith("jumped")):
            got = self.states.get(arm_id)
            if got is not None:
                t = stamp_ns / 1e9 if stamp_ns > 0 else now
                with self._bounds_lock:
                    self._bounds.observe(arm_id, t, got[0])
        return note

    def announce(self, arm_id: str, bound: float) -> None:
        """Record a peer's announced speed bound (a fraction of ``d_max``, in [0, 1])."""
        if arm_id not in self.peer_ids:
            raise InvalidValueError("arm_id", f"must name a peer {list(self.peer_ids)}", arm_id)
        with self._bounds_lock:
            self._bounds.announce(arm_id, bound)

    def peer_bounds(self) -> dict[str, float]:
        """The bound each announcing peer is planned against now (1: it broke its word or
        announces full speed); peers never heard from are left out (silent, full speed)."""
        with self._bounds_lock:
            return self._bounds.bounds(self.peer_ids)

    @property
    def announcement(self) -> float:
        """The speed bound this arm announces (its planner's; 1 when it announces nothing)."""
        return float(self.planner.announcement)

    def observe(self, now: float, stamp_ns: int = 0) -> Observation:
        """Snapshot of the buffers at ``now`` [s] (monotonic) for the current tick."""
        s = self.settings
        ages: dict[str, float] = {}
        peers: dict[str, np.ndarray] = {}
        stale, missing = [], []
        q_self = None
        for arm_id in self.cell.arm_ids:
            got = self.states.get(arm_id)
            ages[arm_id] = math.inf if got is None else now - got[1]
            if arm_id == self.arm_id:
                if got is not None and ages[arm_id] <= s.peer_timeout:
                    q_self = got[0]
                continue
            if got is None:
                missing.append(arm_id)
                continue
            peers[arm_id] = got[0]
            if ages[arm_id] > s.peer_timeout:
                stale.append(arm_id)
        untrusted = self.states.untrusted(now, s.peer_timeout)
        return Observation(
            self._tick,
            stamp_ns,
            q_self,
            peers,
            ages,
            tuple(stale),
            tuple(missing),
            self.goal,
            untrusted=tuple(a for a in untrusted if a != self.arm_id and a in peers),
            own_untrusted=self.arm_id in untrusted,
        )

    # -- the tick (timer thread) ------------------------------------------------------------
    def tick(
        self,
        now: float,
        stamp_ns: int = 0,
        send: Callable[[Decision], None] | None = None,
        solve: bool = True,
    ) -> Decision:
        """The command to publish now; starts the solve of this tick's observations (with
        ``solve`` False, :meth:`start_solve` does, later in the same tick). ``now`` [s] is
        monotonic time (staleness), ``stamp_ns`` the ROS time of the tick; ``send`` gets the
        decision before that solve starts (the command need not share the interpreter)."""
        obs = self.observe(now, stamp_ns)
        if self._paused or self._resuming:
            return self._held_tick(obs, send)
        decision = self._expire(self._collect(obs), obs)
        self._count(decision)
        self.last_observation = obs
        if send is not None:
            send(decision)
        self._due = replace(obs, in_flight=decision.velocity)
        if solve:
            self.start_solve()
        self._tick += 1
        return decision

    def start_solve(self) -> None:
        """Start the solve that :meth:`tick` left for later (nothing if none is due)."""
        due, self._due = self._due, None
        if due is not None and self._worker.submit(due):
            self._submitted = due

    def pause(self) -> None:
        """Hold the arm with zero commands and plan nothing until :meth:`resume`."""
        self._paused = True

    def resume(self) -> None:
        """Plan again, from the states observed from now on: the first command after resume is
        zero (its tick starts a solve on a fresh observation), the next one is that solve's."""
        if self._paused:
            self._paused, self._resuming = False, True

    @property
    def paused(self) -> bool:
        return self._paused

    def _held_tick(
        self, obs: Observation, send: Callable[[Decision], None] | None = None
    ) -> Decision:
        """A tick while paused or resuming: zero, every plan made before the pause dropped."""
        self._worker.take()  # a result planned before the pause is never commanded
        self._submitted = self._due = None
        status = "paused" if self._paused else "resuming"
        decision = Decision(
            zeros(self.robot.dof), status, hold=True, tick=obs.tick, observation_ns=obs.stamp_ns
        )
        self._count(decision)
        self.last_observation = obs
        if send is not None:
            send(decision)
        obs = replace(obs, in_flight=decision.velocity)
        if self._resuming and self._worker.submit(obs):  # busy with an old solve: next tick
            self._submitted, self._resuming = obs, False
        self._tick += 1
        return decision

    def _collect(self, current: Observation) -> Decision:
        """The command due at this tick (``current`` is this tick's observation)."""
        dof = self.robot.dof
        with self._fallback_lock:  # before the take: a job finishing in between is seen next time
            finished, self._finished = self._finished, {}
        late_tick, late_time = -1, math.nan
        if self._abandoned is not None and self._abandoned in finished:
            late_tick, self._abandoned = self._abandoned, None
            late_time = finished[late_tick]
        result = self._worker.take()  # a late result is dropped (its solve time is reported)
        expected, self._submitted = self._submitted, None
        if expected is not None and result is not None and result.tick == expected.tick:
            return replace(result, late_solve_time=late_time, late_tick=late_tick)
        if expected is None and self._tick == 0:
            return Decision(zeros(dof), "starting", hold=True)
        # The solve due now has not finished (or none could start: the worker was still busy).
        self.counters.deadline_misses += 1
        if expected is not None:
            self._abandoned = expected.tick
        source = expected or current
        late = Decision(
            zeros(dof),
            "deadline_missed",
            fail_safe=True,
            hold=True,
            tick=source.tick,
            observation_ns=source.stamp_ns,
            solve_time=math.nan,  # no solve finished in time
            stale=source.stale,
            missing=source.missing,
            untrusted=source.untrusted,
            ages=source.ages,
            late_solve_time=late_time,
            late_tick=late_tick,
        )
        with self._fallback_lock:
            fallback = self._fallback
        max_age = self.settings.peer_timeout / self.settings.period  # [ticks]
        if fallback is None or self._tick - fallback[0] > max_age:
            return late
        velocity = self._guard(fallback[1])
        if velocity is None:
            return replace(late, error="the fail-safe command is not finite")
        return replace(late, velocity=velocity, hold=False, observation_ns=fallback[2])

    def _expire(self, decision: Decision, current: Observation) -> Decision:
        """Rule 2's ``late_plan``: zero for a command planned > ``plan_age`` periods ago."""
        age_ns = current.stamp_ns - decision.observation_ns
        if decision.hold or age_ns <= self.settings.plan_age * 1e9 / self.settings.rate:
            return decision
        self.counters.late_plans += 1
        return replace(decision, velocity=zeros(self.robot.dof), status="late_plan", hold=True)

    def _guard(self, velocity: np.ndarray) -> np.ndarray | None:
        """``velocity`` [rad/s] clipped to ±u_max, or None when some value is not finite."""
        velocity = np.asarray(velocity, dtype=np.float64)
        if not np.all(np.isfinite(velocity)):
            return None
        u_max = self.settings.opt.u_max
        return np.clip(velocity, -u_max, u_max)

    def _count(self, decision: Decision) -> None:
        c = self.counters
        c.ticks += 1
        c.fail_safes += int(decision.fail_safe)
        c.holds += int(decision.hold)
        c.solver_errors += int(bool(decision.error) or decision.status.startswith("failed"))

    def stop(self) -> None:
        """Stop the worker thread."""
        self._worker.stop()

    def wait_idle(self, timeout: float) -> bool:
        """Wait up to ``timeout`` [s] for the solve in flight (lock-step runs); True if idle."""
        return self._worker.wait_idle(timeout)

    # -- the solve (worker thread) ----------------------------------------------------------
    def _solve(self, obs: Observation) -> Decision:
        start = time.perf_counter()
        try:
            decision = self._decide(obs)
        except Exception as exc:  # a planner crash must never reach the tick thread
            decision = self._failure(obs, exc)
        velocity = self._guard(decision.velocity)
        if velocity is None:
            velocity = zeros(self.robot.dof)
            decision = replace(decision, status="non_finite_command", hold=True, fail_safe=True)
        job_time = time.perf_counter() - start
        solve_time = decision.telemetry.solve_time if decision.telemetry else job_time
        with self._fallback_lock:
            self._finished[obs.tick] = solve_time
        return replace(
            decision,
            velocity=velocity,
            tick=obs.tick,
            observation_ns=obs.stamp_ns,
            solve_time=solve_time,
            stale=obs.stale,
            missing=obs.missing,
            untrusted=obs.untrusted,
            ages=obs.ages,
        )

    def _hold(self, status: str) -> Decision:
        return Decision(zeros(self.robot.dof), status, hold=True)

    @property
    def announces(self) -> bool:
        """Whether this arm's planner takes part in the speed-bound announcements."""
        return self.planner.announces

    def _fail_safe_velocity(
        self,
        q: np.ndarray,
        peers: Mapping[str, np.ndarray],
        bounds: Mapping[str, float] | None,
    ) -> np.ndarray:
        u = self.planner.fail_safe(q, peers, bounds)
        if u is None:  # planners without a value function: holding still is their safe act
            return zeros(self.robot.dof)
        return np.asarray(u, dtype=np.float64)

    def _decide(self, obs: Observation) -> Decision:
        if obs.in_flight is not None:  # a hold or a late fail-safe is not its last plan()
            self.planner.commanded(obs.in_flight)
        if obs.q_self is None:
            return self._hold("no_own_state")
        if obs.own_untrusted:
            return self._hold("own_state_untrusted")
        if obs.goal is None:
            return self._hold("no_goal")
        if obs.missing:
            return self._hold("waiting_for_peers")
        doubtful = obs.stale or obs.untrusted
        # the peers' bounds once per tick: the fail-safe and the solve then share one evaluation
        bounds = self.peer_bounds() if self.announces else None
        if doubtful and self.settings.stale_policy == "hold":
            # hold, and let a late solve of this tick fall back to holding too: never steer by
            # a stale or untrusted peer state
            fallback = zeros(self.robot.dof)
        else:
            fallback = self._fail_safe_velocity(obs.q_self, obs.peers, bounds)
        with self._fallback_lock:
            self._fallback = (obs.tick, fallback, obs.stamp_ns)
        if doubtful:
            status = "stale_peer" if obs.stale else "untrusted_peer"
            if self.settings.stale_policy == "hold":
                return self._hold(status)
            return Decision(fallback, status, fail_safe=True)
        result = self.planner.plan(obs.q_self, obs.peers, obs.goal, bounds)
        t = result.telemetry
        return Decision(result.velocity, t.status, fail_safe=t.fail_safe, telemetry=t)

    def _failure(self, obs: Observation, exc: Exception) -> Decision:
        error = f"{type(exc).__name__}: {exc}"
        with self._fallback_lock:
            fallback = self._fallback
        if fallback is not None and fallback[0] == obs.tick:
            return Decision(fallback[1], "failed", fail_safe=True, error=error)
        return Decision(zeros(self.robot.dof), "failed", fail_safe=True, hold=True, error=error)
