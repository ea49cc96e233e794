"""Episode outcomes and the paper's metrics, computed from episode logs.

Per episode (:class:`EpisodeResult`): the outcome — ``success`` (every arm within the setup's
tolerance of its goal, before any collision and within the time limit), ``collision`` (any
arm-arm or self-collision first) or ``stuck`` (neither by the time limit) — the joint-space
path length [rad] (sum over arms of ``Σ‖q_{k+1} − q_k‖₂``), and every plan() call's time. An
episode that was started but cannot be evaluated (its log is unreadable, a process crashed) is
an ``error`` with its reason (:meth:`EpisodeResult.failed`): it stays in every denominator as a
failure of its own kind. Messages of a log that fail the planners' validity rules are ignored
and counted per topic (``malformed``), never fatal.

Per row (:func:`aggregate`): SR, CR, stuck and errors [%] over every episode, planning time
[ms] (mean ± std over the steps of the timed arms: the arms running an Opt planner among the
setup's timed arms, else the timed arms; for centralized planners, one sample per episode:
the plan), MPL [rad] (mean ± std over successful episodes), fail-safe rate and solver statuses.

:func:`evaluate_log` derives an :class:`EpisodeResult` from a log alone;
:func:`nehmo_core.eval.episode.run_episode` derives the same result in memory.
"""

from __future__ import annotations

import math
import sys
import traceback
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.errors import NehmoError, one_line
from nehmo_core.eval.episode_log import EpisodeLog, EpisodeLogError, read_episode_log
from nehmo_core.eval.setups import OPT_KINDS, is_centralized
from nehmo_core.geometry.pybullet_world import Collision
from nehmo_core.planning.opt.interface import Telemetry
from nehmo_core.robots.model import Cell
from nehmo_core.sim.scenarios import goal_error

__all__ = [
    "OUTCOMES",
    "EpisodeResult",
    "RowMetrics",
    "aggregate",
    "evaluate_log",
    "evaluate_logs",
    "evaluate_or_error",
    "failed_episode",
    "format_metrics",
    "goal_distance",
    "path_lengths",
    "planning_times",
]

NOT_PLANNED = frozenset(
    {
        "deadline_missed",
        "stale_peer",
        "untrusted_peer",
        "no_own_state",
        "own_state_untrusted",
        "no_goal",
        "waiting_for_peers",
        "starting",
    }
)
"""Statuses of a planner node's commands for which no planning ran (holds, and a missed
deadline, whose solve time is NaN): their times are not planning times."""

OUTCOMES = ("success", "collision", "stuck", "error")


@dataclass(frozen=True)
class EpisodeResult:
    """The outcome and measurements of one episode."""

    outcome: str  # one of OUTCOMES
    end_ns: int  # episode time at the end [ns], from the first logged state of every arm
    ticks: int  # control ticks simulated
    path_lengths: dict[str, float]  # [rad] per arm
    kinds: dict[str, str]  # planner kind per arm
    timed_arms: tuple[str, ...]
    plan_times: dict[str, tuple[float, ...]]  # [s] every plan() call, per arm
    statuses: dict[str, dict[str, int]]  # solver status counts per arm
    fail_safe: dict[str, int]  # fail-safe commands per arm
    collisions: tuple[Collision, ...]  # found in the colliding tick
    final_errors: dict[str, float]  # [rad] goal distance per arm at the end (setup's norm)
    metadata: dict[str, Any] = field(default_factory=dict, compare=False)  # the logged JSON
    error: str = ""  # why an ``error`` episode could not be evaluated
    #: messages of the log ignored as malformed: topic -> count (the first reason per topic in
    #: ``malformed_reasons``)
    malformed: dict[str, int] = field(default_factory=dict, compare=False)
    malformed_reasons: dict[str, str] = field(default_factory=dict, compare=False)

    @classmethod
    def failed(
        cls,
        reason: str,
        kinds: Mapping[str, str] | None = None,
        metadata: Mapping[str, Any] | None = None,
    ) -> EpisodeResult:
        """An episode that was started but cannot be evaluated: outcome ``error``, ``reason``
        kept, no measurements (it adds no planning time and no path length)."""
        return cls(
            outcome="error",
            end_ns=0,
            ticks=0,
            path_lengths={},
            kinds=dict(kinds or {}),
            timed_arms=(),
            plan_times={},
            statuses={},
            fail_safe={},
            collisions=(),
            final_errors={},
            metadata=dict(metadata or {}),
            error=reason or "unknown error",
        )

    @property
    def end_time(self) -> float:
        return self.end_ns / 1e9

    @property
    def path_length(self) -> float:
        """Joint-space path length of the cell [rad] (sum over arms)."""
        return float(sum(self.path_lengths.values()))

    @property
    def collision_kind(self) -> str | None:
        """``"inter-arm"`` when the episode ended in a collision between two arms, ``"self"``
        when only an arm against itself, ``None`` without a collision."""
        if self.outcome != "collision":
            return None
        return "inter-arm" if any(c.arm_a != c.arm_b for c in self.collisions) else "self"

    def plan_time_samples(self) -> list[float]:
        """The planning times [s] this episode contributes to its row's mean ± std."""
        if not self.timed_arms:
            return []
        arms = [a for a in self.timed_arms if self.kinds[a] in OPT_KINDS] or list(self.timed_arms)
        if is_centralized(self.kinds):
            return [self.plan_times[arms[0]][0]] if self.plan_times[arms[0]] else []
        return [t for a in arms for t in self.plan_times[a]]

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["collisions"] = [asdict(c) for c in self.collisions]
        out["plan_times"] = {a: list(v) for a, v in self.plan_times.items()}
        out["timed_arms"] = list(self.timed_arms)
        return out


def path_lengths(positions: Mapping[str, np.ndarray]) -> dict[str, float]:
    """``Σ‖q_{k+1} − q_k‖₂`` [rad] per arm of a trajectory ``positions[arm]`` (T, dof)."""
    return {
        a: float(np.linalg.norm(np.diff(np.asarray(q), axis=0), axis=1).sum())
        for a, q in positions.items()
    }


def goal_distance(q: np.ndarray, goal: np.ndarray, cell: Cell, arm_id: str, norm: str) -> float:
    """Wrapped joint-space distance [rad] of one arm to its goal: L2 norm or max-abs."""
    e = goal_error(q, goal, cell.arm(arm_id).robot)
    return float(np.abs(e).max()) if norm == "max" else float(np.linalg.norm(e))


def planning_times(telemetry: Sequence[Telemetry]) -> tuple[float, ...]:
    """The solve times [s] of the commands for which planning ran (see :data:`NOT_PLANNED`)."""
    return tuple(
        t.solve_time
        for t in telemetry
        if t.status not in NOT_PLANNED and math.isfinite(t.solve_time)
    )


def _first_success(log: EpisodeLog, norm: str, tolerance: float) -> int | None:
    for k in range(len(log.stamps)):
        if all(
            goal_distance(log.positions[a][k], log.goals[a], log.cell, a, norm) < tolerance
            for a in log.cell.arm_ids
        ):
            return k
    return None


def evaluate_log(path_or_log: str | Path | EpisodeLog) -> EpisodeResult:
    """The :class:`EpisodeResult` of a logged episode, from the log alone."""
    log = path_or_log if isinstance(path_or_log, EpisodeLog) else read_episode_log(path_or_log)
    meta = log.metadata
    try:
        norm = meta["success"]["norm"]
        tolerance = float(meta["success"]["tolerance"])
        limit_ns = int(meta["control"]["max_ticks"]) * int(meta["control"]["period_ns"])
        period_ns = int(meta["control"]["period_ns"])
        kinds = {a: str(meta["planners"][a]) for a in log.cell.arm_ids}
        timed = tuple(meta["timed_arms"])
    except (KeyError, TypeError, ValueError) as exc:
        raise EpisodeLogError(f"{log.path}: episode metadata lacks {exc}") from None
    t0 = int(log.stamps[0])  # episode times are counted from the first complete state
    limit_ns += t0
    k_success = _first_success(log, norm, tolerance)
    success_ns = int(log.stamps[k_success]) if k_success is not None else None
    collision_ns, collisions = log.collisions[0] if log.collisions else (None, [])
    if (
        collision_ns is not None
        and collision_ns <= limit_ns
        and (success_ns is None or collision_ns <= success_ns)
    ):
        outcome, end_ns = "collision", int(collision_ns)
    elif success_ns is not None and success_ns <= limit_ns:
        outcome, end_ns, collisions = "success", success_ns, []
    else:
        outcome, end_ns, collisions = "stuck", min(limit_ns, int(log.stamps[-1])), []
    keep = log.stamps <= end_ns
    positions = {a: q[keep] for a, q in log.positions.items()}
    last = {a: q[-1] for a, q in positions.items()}
    plan_times: dict[str, tuple[float, ...]] = {}
    statuses: dict[str, dict[str, int]] = {}
    fail_safe: dict[str, int] = {}
    for a in log.cell.arm_ids:
        records = [r for _, r in log.statuses[a] if t0 <= r.observation_ns < end_ns]
        plan_times[a] = planning_times([r.telemetry for r in records])
        statuses[a] = dict(Counter(r.telemetry.status for r in records))
        fail_safe[a] = sum(r.telemetry.fail_safe for r in records)
    return EpisodeResult(
        outcome=outcome,
        end_ns=end_ns - t0,
        ticks=(end_ns - t0) // period_ns,
        path_lengths=path_lengths(positions),
        kinds=kinds,
        timed_arms=timed,
        plan_times=plan_times,
        statuses=statuses,
        fail_safe=fail_safe,
        collisions=tuple(collisions),
        final_errors={
            a: goal_distance(last[a], log.goals[a], log.cell, a, norm) for a in log.cell.arm_ids
        },
        metadata=meta,
        malformed=dict(log.malformed),
        malformed_reasons=dict(log.malformed_reasons),
    )


def evaluate_or_error(
    path_or_log: str | Path | EpisodeLog, kinds: Mapping[str, str] | None = None
) -> EpisodeResult:
    """:func:`evaluate_log`, or an ``error`` result naming why the log cannot be evaluated
    (missing, unfinished, not an episode log, no complete state): the episode stays counted."""
    try:
        return evaluate_log(path_or_log)
    except (NehmoError, OSError) as exc:
        return EpisodeResult.failed(one_line(exc), kinds)


def evaluate_logs(
    paths: Sequence[Path],
    kinds: Mapping[str, str] | None = None,
    executor: Any = None,
    known: Sequence[EpisodeResult | None] | None = None,
) -> list[EpisodeResult]:
    """:func:`evaluate_or_error` for each bag, in order, except where ``known`` (aligned with
    ``paths``) holds an ``error`` result (an episode that raised: it stays as it is); spread over
    ``executor``'s workers when it is a local process pool (the bags are on this machine), else
    one after another."""
    from concurrent.futures import ProcessPoolExecutor

    out: list[EpisodeResult | None] = [
        r if r is not None and r.outcome == "error" else None
        for r in (known or [None] * len(paths))
    ]
    read = [k for k, r in enumerate(out) if r is None]
    todo = [paths[k] for k in read]
    if isinstance(executor, ProcessPoolExecutor) and len(todo) > 1:
        found = executor.map(evaluate_or_error, todo, [kinds] * len(todo), chunksize=4)
    else:
        found = (evaluate_or_error(p, kinds) for p in todo)
    for k, result in zip(read, found, strict=True):
        out[k] = result
    return [r for r in out if r is not None]


def failed_episode(what: str, exc: BaseException) -> EpisodeResult:
    """The ``error`` result of an episode that raised ``exc`` (called in the ``except`` block):
    the traceback goes to stderr under ``what`` (which episode), the reason into the result."""
    reason = f"{type(exc).__name__}: {one_line(exc)}"
    print(f"{what} failed: {reason}\n{traceback.format_exc()}", file=sys.stderr, flush=True)
    return EpisodeResult.failed(reason)


@dataclass(frozen=True)
class RowMetrics:
    """The paper's metrics over the episodes of one row."""

    episodes: int
    successes: int
    collisions: int
    stuck: int
    plan_time_ms: tuple[float, float]  # mean, std over plan_time_samples
    plan_time_samples: int
    mpl: tuple[float, float]  # [rad] mean, std over successes (nan without successes)
    fail_safe_rate: float  # fail-safe commands / commands of the timed Opt arms
    statuses: dict[str, int]
    self_collisions: int = 0  # the collisions of an arm with itself only (in ``collisions``)
    errors: int = 0  # episodes that could not be evaluated (in ``episodes``, never successes)
    error_reasons: tuple[str, ...] = ()  # one per error episode
    malformed: dict[str, int] = field(default_factory=dict)  # ignored messages per topic

    @property
    def sr(self) -> float:
        return 100.0 * self.successes / self.episodes if self.episodes else math.nan

    @property
    def cr(self) -> float:
        """Episodes ending in any collision [%] (the authors' code counts self-collisions)."""
        return 100.0 * self.collisions / self.episodes if self.episodes else math.nan

    @property
    def cr_inter_arm(self) -> float:
        """Episodes ending in a collision between arms [%]: the paper's CR."""
        inter = self.collisions - self.self_collisions
        return 100.0 * inter / self.episodes if self.episodes else math.nan

    @property
    def self_collision_rate(self) -> float:
        """Episodes ending in an arm's collision with itself only [%]."""
        return 100.0 * self.self_collisions / self.episodes if self.episodes else math.nan

    @property
    def stuck_rate(self) -> float:
        return 100.0 * self.stuck / self.episodes if self.episodes else math.nan

    @property
    def error_rate(self) -> float:
        """Episodes that could not be evaluated [%] (failures of their own kind)."""
        return 100.0 * self.errors / self.episodes if self.episodes else math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "episodes": self.episodes,
            "successes": self.successes,
            "collisions": self.collisions,
            "stuck": self.stuck,
            "sr": self.sr,
            "cr": self.cr,
            "self_collisions": self.self_collisions,
            "cr_inter_arm": self.cr_inter_arm,
            "self_collision_rate": self.self_collision_rate,
            "stuck_rate": self.stuck_rate,
            "errors": self.errors,
            "error_rate": self.error_rate,
            "error_reasons": list(self.error_reasons),
            "malformed_messages": dict(self.malformed),
            "plan_time_ms": {"mean": self.plan_time_ms[0], "std": self.plan_time_ms[1]},
            "plan_time_samples": self.plan_time_samples,
            "mpl": {"mean": self.mpl[0], "std": self.mpl[1]},
            "fail_safe_rate": self.fail_safe_rate,
            "statuses": self.statuses,
        }


def _mean_std(x: Sequence[float]) -> tuple[float, float]:
    if not x:
        return math.nan, math.nan
    a = np.asarray(x, dtype=np.float64)
    return float(a.mean()), float(a.std())


def aggregate(results: Sequence[EpisodeResult]) -> RowMetrics:
    """SR, CR (all collisions, and self-collisions apart), stuck, errors, planning time, MPL
    and fail-safe rate over ``results``: every episode counts in the rates' denominator,
    ``error`` episodes included."""
    unknown = sorted({r.outcome for r in results} - set(OUTCOMES))
    if unknown:
        raise ValueError(f"episode outcomes must be among {OUTCOMES}, got {unknown}")
    counts = Counter(r.outcome for r in results)
    malformed: Counter[str] = Counter()
    for r in results:
        malformed.update(r.malformed)
    times = [t * 1e3 for r in results for t in r.plan_time_samples()]
    mpl = [r.path_length for r in results if r.outcome == "success"]
    statuses: Counter[str] = Counter()
    fail, calls = 0, 0
    for r in results:
        arms = [a for a in r.timed_arms if r.kinds[a] in OPT_KINDS]
        for a in arms:
            statuses.update(r.statuses[a])
            fail += r.fail_safe[a]
            calls += len(r.plan_times[a])
    return RowMetrics(
        episodes=len(results),
        successes=counts["success"],
        collisions=counts["collision"],
        stuck=counts["stuck"],
        plan_time_ms=_mean_std(times),
        plan_time_samples=len(times),
        mpl=_mean_std(mpl),
        fail_safe_rate=fail / calls if calls else math.nan,
        statuses=dict(statuses),
        self_collisions=sum(r.collision_kind == "self" for r in results),
        errors=counts["error"],
        error_reasons=tuple(r.error for r in results if r.outcome == "error"),
        malformed=dict(sorted(malformed.items())),
    )


def format_metrics(metrics: Mapping[str, Any] | None) -> str:
    """One line of a row's metrics (:meth:`RowMetrics.to_dict`), naming errors and ignored
    malformed messages when there are any."""
    if metrics is None or not metrics.get("episodes"):
        return "no episode was run"
    n = metrics["episodes"]

    def pm(pair: Mapping[str, Any], unit: str) -> str:
        mean, std = pair.get("mean"), pair.get("std")
        if mean is None or not math.isfinite(mean):
            return "–"
        return f"{mean:.2f} ± {std:.2f} {unit}"

    line = (
        f"SR {metrics['sr']:.0f} % ({metrics['successes']} of {n})"
        f"  CR {metrics.get('cr_inter_arm', metrics['cr']):.0f} %"
        f"  self {metrics.get('self_collision_rate', 0.0):.0f} %"
        f"  stuck {metrics['stuck_rate']:.0f} %"
        f"  plan time {pm(metrics['plan_time_ms'], 'ms')}  MPL {pm(metrics['mpl'], 'rad')}"
        f"  ({n} episode{'s' if n != 1 else ''})"
    )
    reasons = list(metrics.get("error_reasons") or [])
    if metrics.get("errors"):
        grouped = Counter(reasons)
        listed = "; ".join(f"{r}" + (f" (x{c})" if c > 1 else "") for r, c in grouped.items())
        line += f" · {metrics['errors']} error{'s' if metrics['errors'] != 1 else ''}: {listed}"
    malformed = metrics.get("malformed_messages") or {}
    if malformed:
        listed = ", ".join(f"{t}: {c:,}" for t, c in malformed.items())
        line += f" · malformed messages ignored: {listed}"
    return line
