"""The batch episode runner: one scenario, one planner per arm, no middleware.

Control runs at ``rate`` (25 Hz) with the worker-thread latency model of the ROS planner: the
solve started from the observations at tick ``k`` runs while the command planned at tick
``k − 1`` executes, so **the command applied during tick k was planned from the observations
at tick k − 1** (during tick 0 no command exists yet and the arms hold still). Each tick, the
:class:`~nehmo_core.sim.cell_sim.CellSimulator` integrates the velocities and checks every arm
pair and every arm's self-collision exactly at ``substeps`` instants (4 at 25 Hz: every 10 ms,
the authors' spacing). Speed bounds announced by NeHMO planners with their commands (see
:mod:`~nehmo_core.planning.stages.speed_bounds`) are heard by the others at the next tick and
checked against the observed motion. The episode stops at the first collision, when every arm is
within the tolerance of its goal (checked at tick boundaries), or at the time limit. With
``EpisodeSettings.stalls`` (off by default) planner processes stall now and then, as on an
overloaded machine (:mod:`nehmo_core.eval.stalls`).
"""

from __future__ import annotations

import zlib
from collections import Counter
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.eval.episode_log import EpisodeLogWriter, cell_metadata
from nehmo_core.eval.metrics import EpisodeResult, goal_distance, path_lengths
from nehmo_core.eval.setups import SUCCESS_NORMS, Setup
from nehmo_core.eval.stalls import Stalls, StallSchedule
from nehmo_core.eval.telemetry import status_message
from nehmo_core.geometry.pybullet_world import Collision
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.opt.peer_bounds import PeerBounds
from nehmo_core.robots.model import Cell
from nehmo_core.sim.actuators import ACTUATOR_MODELS
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenarios import Scenario

__all__ = ["EpisodeSettings", "run_episode"]


@dataclass(frozen=True)
class EpisodeSettings:
    """Control rate [Hz], time limit [s], collision sub-steps and the success rule."""

    rate: float = 25.0
    time_limit: float = 20.0
    substeps: int = 4
    success_norm: str = "l2"
    success_tolerance: float = 0.1  # [rad]
    self_collision: bool = True
    actuators: str = "ideal"  # how arms carry commands out (nehmo_core.sim.actuators)
    stalls: Stalls = field(default_factory=Stalls)  # overloaded processes (eval.stalls)

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise InvalidValueError("rate", "must be > 0 [Hz]", self.rate)
        if not self.time_limit > 0:
            raise InvalidValueError("time_limit", "must be > 0 [s]", self.time_limit)
        if self.substeps < 1:
            raise InvalidValueError("substeps", "must be >= 1", self.substeps)
        if self.success_norm not in SUCCESS_NORMS:
            raise UnknownNameError("success norm", self.success_norm, SUCCESS_NORMS)
        if not self.success_tolerance > 0:
            raise InvalidValueError("success_tolerance", "must be > 0", self.success_tolerance)
        if self.actuators not in ACTUATOR_MODELS:
            raise UnknownNameError("actuator model", self.actuators, ACTUATOR_MODELS)

    @classmethod
    def for_setup(cls, setup: Setup, **overrides: Any) -> EpisodeSettings:
        """The settings of an evaluation setup (its time limit and success rule)."""
        base = {
            "time_limit": setup.time_limit,
            "success_norm": setup.success_norm,
            "success_tolerance": setup.success_tolerance,
        }
        return cls(**{**base, **overrides})

    @property
    def period_ns(self) -> int:
        """Control period [ns]."""
        return round(1e9 / self.rate)

    @property
    def max_ticks(self) -> int:
        return round(self.time_limit * self.rate)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _metadata(
    cell: Cell,
    scenario: Scenario,
    kinds: Mapping[str, str],
    timed_arms: tuple[str, ...],
    settings: EpisodeSettings,
    extra: Mapping[str, Any],
) -> dict[str, Any]:
    return {
        **extra,
        "cell": cell_metadata(cell),
        "planners": dict(kinds),
        "timed_arms": list(timed_arms),
        "control": {
            "rate_hz": settings.rate,
            "period_ns": settings.period_ns,
            "latency_ticks": 1,
            "substeps": settings.substeps,
            "self_collision": settings.self_collision,
            "time_limit": settings.time_limit,
            "max_ticks": settings.max_ticks,
            **({"stalls": settings.stalls.to_dict()} if settings.stalls.rate > 0 else {}),
        },
        "success": {"norm": settings.success_norm, "tolerance": settings.success_tolerance},
        "start": {a: [float(v) for v in scenario.start[a]] for a in cell.arm_ids},
        "goal": {a: [float(v) for v in scenario.goal[a]] for a in cell.arm_ids},
    }


class _Recorder:
    """The in-memory account of an episode (and its log, when one is written)."""

    def __init__(self, cell: Cell, log: EpisodeLogWriter | None) -> None:
        self.cell = cell
        self.log = log
        self.positions: dict[str, list[np.ndarray]] = {a: [] for a in cell.arm_ids}
        self.plan_times: dict[str, list[float]] = {a: [] for a in cell.arm_ids}
        self.statuses: dict[str, Counter[str]] = {a: Counter() for a in cell.arm_ids}
        self.fail_safe: dict[str, int] = dict.fromkeys(cell.arm_ids, 0)

    def tick(self, t_ns: int, q: Mapping[str, np.ndarray], v: Mapping[str, np.ndarray]) -> None:
        for a in self.cell.arm_ids:
            self.positions[a].append(q[a].copy())
        if self.log is not None:
            self.log.tick(t_ns, q, v)


def run_episode(
    cell: Cell,
    scenario: Scenario,
    planners: Mapping[str, Planner],
    settings: EpisodeSettings | None = None,
    *,
    kinds: Mapping[str, str] | None = None,
    timed_arms: tuple[str, ...] | None = None,
    simulator: CellSimulator | None = None,
    log_path: str | Path | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> EpisodeResult:
    """Run one episode and return its result; write its log to the bag ``log_path`` if given.

    ``planners`` holds one planner per arm id; ``kinds`` names them in the log and metrics
    (default: the class name). ``simulator`` may be reused across episodes of the same cell
    (its sub-steps must match ``settings``). ``metadata`` is added to the logged scenario JSON.
    """
    s = settings or EpisodeSettings()
    missing = set(cell.arm_ids) - set(planners)
    if missing:
        raise InvalidValueError("planners", f"must hold a planner for arms {sorted(missing)}", [])
    kinds = dict(kinds) if kinds is not None else {a: type(p).__name__ for a, p in planners.items()}
    timed = tuple(timed_arms) if timed_arms is not None else cell.arm_ids
    if simulator is not None and (
        simulator.substeps != s.substeps
        or simulator.self_collision != s.self_collision
        or {m.name for m in simulator.actuators.values()} != {s.actuators}
    ):
        raise InvalidValueError(
            "simulator",
            f"must use substeps={s.substeps} and actuators={s.actuators!r} as the settings",
            simulator.substeps,
        )
    sim = simulator or CellSimulator(
        cell, substeps=s.substeps, self_collision=s.self_collision, actuators=s.actuators
    )
    log = EpisodeLogWriter(log_path, cell) if log_path is not None else None
    try:
        if log is not None:
            log.scenario(_metadata(cell, scenario, kinds, timed, s, metadata or {}))
            log.goals(scenario.goal)
        return _loop(cell, scenario, planners, s, sim, _Recorder(cell, log), kinds, timed)
    finally:
        if log is not None:
            log.close()
        if simulator is None:
            sim.close()


def reached(
    cell: Cell, q: Mapping[str, np.ndarray], scenario: Scenario, s: EpisodeSettings
) -> bool:
    """Every arm within the success tolerance of its goal (the episode's success rule)."""
    return all(
        goal_distance(q[a], scenario.goal[a], cell, a, s.success_norm) < s.success_tolerance
        for a in cell.arm_ids
    )


def _loop(
    cell: Cell,
    scenario: Scenario,
    planners: Mapping[str, Planner],
    s: EpisodeSettings,
    sim: CellSimulator,
    rec: _Recorder,
    kinds: dict[str, str],
    timed: tuple[str, ...],
) -> EpisodeResult:
    # the sensor noise of a non-ideal actuator model: a stream per scenario
    start = np.concatenate([scenario.start[a] for a in cell.arm_ids])
    sim.reset(scenario.start, seed=zlib.crc32(start.tobytes()))
    for planner in planners.values():
        planner.reset()
    period_ns, dt = s.period_ns, s.period_ns / 1e9
    hold = {a.arm_id: np.zeros(a.robot.dof) for a in cell.arms}
    rec.tick(0, sim.positions(), hold)
    pending: dict[str, tuple[np.ndarray, int]] = {}  # each arm's latest plan and its tick
    stalls = StallSchedule(s.stalls, cell.arm_ids, zlib.crc32(start.tobytes()) + 1)
    sent: dict[str, tuple[np.ndarray, int]] = {a: (hold[a], 0) for a in cell.arm_ids}
    # announced speed bounds: heard one tick after they are made, checked against the motion
    nehmo = [p for p in planners.values() if isinstance(p, NehmoPlanner)]
    bounds = PeerBounds(max((p.settings.opt.d_max for p in nehmo), default=1.0))
    outcome, ticks, collisions = "stuck", 0, []
    if reached(cell, sim.positions(), scenario, s):
        outcome = "success"
    else:
        for k in range(s.max_ticks):
            observed = sim.observed()
            stalled = stalls.at(k)
            for a in cell.arm_ids:  # what each arm's planner publishes at this tick
                if a not in stalled:
                    sent[a] = (_due(pending.get(a), hold[a], k, s.stalls.expire_stale), k)
            applied = {  # the actuator side: a command drives its arm for hold_ticks periods
                a: sent[a][0] if k - sent[a][1] < s.stalls.hold_ticks else hold[a]
                for a in cell.arm_ids
            }
            planned = {}
            for a in cell.arm_ids:
                bounds.observe(a, k * dt, observed[a])
            heard = bounds.bounds()
            announced = {}
            for a in cell.arm_ids:  # the worker thread: plans from tick k, used in tick k + 1
                if a in stalled:
                    continue
                planner = planners[a]
                peer_bounds = {p: b for p, b in heard.items() if p != a}
                result = planner.plan(
                    observed[a],
                    observed,
                    scenario.goal[a],
                    peer_bounds if planner.announces else None,
                )
                planned[a] = np.array(result.velocity, dtype=np.float64)
                t = result.telemetry
                if planner.announces:
                    announced[a] = t.speed_bound
                rec.plan_times[a].append(float(t.solve_time))
                rec.statuses[a][t.status] += 1
                rec.fail_safe[a] += int(t.fail_safe)
                if rec.log is not None:
                    status = status_message(a, kinds[a], t, k * period_ns)
                    rec.log.plan(a, (k + 1) * period_ns, planned[a], status)
            for a, b in announced.items():
                bounds.announce(a, b)
            step = sim.step(applied, dt)
            pending.update((a, (v, k)) for a, v in planned.items())
            ticks = k + 1
            rec.tick(ticks * period_ns, sim.positions(), applied)
            if step.collisions:
                collisions = list(step.collisions)
                if rec.log is not None:
                    rec.log.collisions(ticks * period_ns, collisions)
                outcome = "collision"
                break
            if reached(cell, sim.positions(), scenario, s):
                outcome = "success"
                break
    return _result(cell, scenario, s, rec, kinds, timed, outcome, ticks, collisions)


def _due(
    plan: tuple[np.ndarray, int] | None, hold: np.ndarray, tick: int, expire: bool
) -> np.ndarray:
    """The command published at ``tick``: the latest plan (zero before the first, and with
    ``expire`` when it was planned more than one period ago, after a stall)."""
    if plan is None or (expire and plan[1] < tick - 1):
        return hold
    return plan[0]


def _result(
    cell: Cell,
    scenario: Scenario,
    s: EpisodeSettings,
    rec: _Recorder,
    kinds: dict[str, str],
    timed: tuple[str, ...],
    outcome: str,
    ticks: int,
    collisions: list[Collision],
) -> EpisodeResult:
    positions = {a: np.array(v) for a, v in rec.positions.items()}
    return EpisodeResult(
        outcome=outcome,
        end_ns=ticks * s.period_ns,
        ticks=ticks,
        path_lengths=path_lengths(positions),
        kinds=kinds,
        timed_arms=timed,
        plan_times={a: tuple(v) for a, v in rec.plan_times.items()},
        statuses={a: dict(c) for a, c in rec.statuses.items()},
        fail_safe=dict(rec.fail_safe),
        collisions=tuple(collisions),
        final_errors={
            a: goal_distance(positions[a][-1], scenario.goal[a], cell, a, s.success_norm)
            for a in cell.arm_ids
        },
        metadata={},
    )
