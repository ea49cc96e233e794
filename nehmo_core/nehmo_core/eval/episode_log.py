"""One episode as a rosbag2 bag in the project's schema (:mod:`nehmo_core.logs.topics`).

Written per episode, in simulated time (``log_time`` = stamp [ns] from the episode start):

============================================ =====================================================
``/nehmo/scenario``                          the episode's metadata as JSON (cell, planners, rules)
``/<arm>/goal``                              goal configuration, once at t = 0
``/clock``, ``/<arm>/joint_states``          every control tick: positions [rad], and as velocity
                                             the command applied during the tick that ended there
``/<arm>/velocity_controller/commands``      each plan() result [rad/s], stamped when it takes
                                             effect (the tick after its observation)
``/<arm>/planner/status``                    its telemetry (:mod:`nehmo_core.eval.telemetry`)
``/nehmo/collisions``                        the colliding pairs, at the end of the colliding tick
============================================ =====================================================

:func:`read_episode_log` reads any log with these topics back, so a ROS recording is evaluated
like a batch one. It applies the planners' validity rules to what it reads (a recorder stores
whatever was published, a foreign node's garbage included): a joint state or goal must name the
arm's joints once each with finite positions (:meth:`~nehmo_core.robots.model.RobotModel
.joint_state`), a command must hold one finite value per joint within the velocity limits (the
bridge's rule), a status must decode, a collision must name arms of the cell. A message that
fails is ignored and counted per topic (:attr:`EpisodeLog.malformed`); so are the states of an
arm that disagree at one instant (two publishers on one topic). Only a log with nothing to
evaluate (no metadata, no goal, no instant with a valid state of every arm) is an error.
"""

from __future__ import annotations

import json
import math
from collections import Counter, defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.eval.telemetry import (
    StatusRecord,
    collisions_from_message,
    collisions_message,
    stamp,
    telemetry_from_status,
)
from nehmo_core.geometry.pybullet_world import Collision
from nehmo_core.logs import (
    CLOCK_TOPIC,
    COLLISIONS_TOPIC,
    SCENARIO_TOPIC,
    Clock,
    DiagnosticArray,
    DiagnosticStatus,
    Float64MultiArray,
    Header,
    JointState,
    LogWriter,
    String,
    command_topic,
    goal_topic,
    iter_log,
    joint_states_topic,
    status_topic,
)
from nehmo_core.logs.topics import split_arm_topic
from nehmo_core.robots.loader import cell_from_dict
from nehmo_core.robots.model import Cell

__all__ = [
    "EPISODE_FORMAT",
    "EPISODE_FORMAT_VERSION",
    "EpisodeLog",
    "EpisodeLogError",
    "EpisodeLogWriter",
    "cell_metadata",
    "read_episode_log",
]

EPISODE_FORMAT = "nehmo-episode"
EPISODE_FORMAT_VERSION = 1


_ARM_TOPICS = ("joint_states", "goal", "planner/status", "velocity_controller/commands")


class EpisodeLogError(NehmoError):
    """An episode log that lacks what the evaluation needs."""


def cell_metadata(cell: Cell) -> dict[str, Any]:
    """The cell as the mapping :func:`~nehmo_core.robots.loader.cell_from_dict` reads."""
    return {
        "name": cell.name,
        "arms": [
            {
                "id": a.arm_id,
                "robot": a.robot.name,
                "base": {"xyz": list(a.base.xyz), "rpy": list(a.base.rpy)},
            }
            for a in cell.arms
        ],
    }


class EpisodeLogWriter:
    """Writes the topics of one episode to the new bag directory `path`; a context manager
    (the bag is finished on exit)."""

    def __init__(self, path: str | Path, cell: Cell) -> None:
        self.cell = cell
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._log = LogWriter(self.path)

    def scenario(self, metadata: Mapping[str, Any]) -> None:
        self._log.write_scenario(
            {"format": EPISODE_FORMAT, "version": EPISODE_FORMAT_VERSION, **metadata}
        )

    def _joint_state(self, arm_id: str, t_ns: int, q: np.ndarray, v: np.ndarray) -> JointState:
        return JointState(
            header=Header(stamp=stamp(t_ns), frame_id=""),
            name=list(self.cell.arm(arm_id).robot.joint_names),
            position=np.asarray(q, dtype=np.float64),
            velocity=np.asarray(v, dtype=np.float64),
        )

    def goals(self, goals: Mapping[str, np.ndarray]) -> None:
        for arm_id, q in goals.items():
            msg = self._joint_state(arm_id, 0, q, np.zeros(0))
            self._log.write(goal_topic(arm_id), msg, 0)

    def tick(
        self, t_ns: int, q: Mapping[str, np.ndarray], velocity: Mapping[str, np.ndarray]
    ) -> None:
        """The clock and every arm's joint state at ``t_ns``."""
        self._log.write(CLOCK_TOPIC, Clock(clock=stamp(t_ns)), t_ns)
        for arm_id, qa in q.items():
            msg = self._joint_state(arm_id, t_ns, qa, velocity[arm_id])
            self._log.write(joint_states_topic(arm_id), msg, t_ns)

    def plan(self, arm_id: str, t_ns: int, velocity: np.ndarray, status: DiagnosticStatus) -> None:
        """A command taking effect at ``t_ns`` and the planner status that produced it."""
        cmd = Float64MultiArray(data=np.asarray(velocity, dtype=np.float64))
        self._log.write(command_topic(arm_id), cmd, t_ns)
        self._log.write(status_topic(arm_id), status, t_ns)

    def collisions(self, t_ns: int, collisions: list[Collision]) -> None:
        self._log.write(COLLISIONS_TOPIC, collisions_message(collisions, t_ns), t_ns)

    def close(self) -> None:
        self._log.close()

    def __enter__(self) -> EpisodeLogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


@dataclass
class EpisodeLog:
    """What an episode log holds, as arrays: ``positions[arm]`` (T, dof) at ``stamps`` (T,) [ns]."""

    path: Path
    metadata: dict[str, Any]
    cell: Cell
    goals: dict[str, np.ndarray]
    stamps: np.ndarray
    positions: dict[str, np.ndarray]
    statuses: dict[str, list[tuple[int, StatusRecord]]] = field(default_factory=dict)
    commands: dict[str, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    collisions: list[tuple[int, list[Collision]]] = field(default_factory=list)
    #: messages ignored as malformed, per topic, and the first reason per topic
    malformed: dict[str, int] = field(default_factory=dict)
    malformed_reasons: dict[str, str] = field(default_factory=dict)


class _Malformed(Exception):
    """A message that fails the validity rules (the reason is the message)."""


def _command(data: Any, cell: Cell, arm_id: str) -> np.ndarray:
    robot = cell.arm(arm_id).robot
    values = np.asarray(data, dtype=np.float64)
    limits = np.array([j.velocity for j in robot.joints])
    if values.shape != (robot.dof,) or not np.all(np.isfinite(values)):
        raise _Malformed(f"needs {robot.dof} finite values, got {values.tolist()[:8]}")
    if np.any(np.abs(values) > limits + 1e-9):
        raise _Malformed(f"exceeds the velocity limits {limits.tolist()} rad/s")
    return values


def _collisions(msg: DiagnosticArray, cell: Cell) -> list[Collision]:
    found = collisions_from_message(msg)
    arms = set(cell.arm_ids)
    strangers = sorted({a for c in found for a in (c.arm_a, c.arm_b)} - arms)
    if strangers:
        raise _Malformed(f"names arms {strangers} that are not in the cell")
    return found


def _decoded(rec: Any, cell: Cell, arm_id: str | None, what: str, topic: str) -> Any:
    """The checked content of one record; raises :class:`_Malformed` with the reason."""
    msg = rec.message
    if rec.decode_error:
        raise _Malformed(f"cannot be decoded ({rec.decode_error})")
    try:
        if arm_id is None:
            if isinstance(msg, DiagnosticArray):
                return _collisions(msg, cell)
        elif what in ("joint_states", "goal") and isinstance(msg, JointState):
            return cell.arm(arm_id).robot.joint_state(msg.name, msg.position, topic)
        elif what == "planner/status" and isinstance(msg, DiagnosticStatus):
            record = telemetry_from_status(msg)
            solve = record.telemetry.solve_time
            if record.observation_ns < 0 or solve < 0 or math.isinf(solve):
                raise _Malformed(f"observation {record.observation_ns} ns, solve time {solve} s")
            return record
        elif what == "velocity_controller/commands" and isinstance(msg, Float64MultiArray):
            return _command(msg.data, cell, arm_id)
    except _Malformed:
        raise
    except (NehmoError, ValueError, TypeError) as err:
        raise _Malformed(str(err)) from None
    raise _Malformed(f"is a {rec.msgtype or 'message of unknown type'}, not what {topic} carries")


def _episode_metadata(path: Path) -> tuple[dict[str, Any] | None, int]:
    """The first message on ``/nehmo/scenario`` that is this format's JSON object, and how
    many other messages came before it (another publisher's)."""
    others = 0
    for record in iter_log(path, [SCENARIO_TOPIC]):
        try:
            value = json.loads(record.message.data) if isinstance(record.message, String) else None
        except (ValueError, TypeError):
            value = None
        if isinstance(value, dict) and value.get("format") == EPISODE_FORMAT:
            return value, others
        others += 1
    return None, others


def read_episode_log(path: str | Path) -> EpisodeLog:
    """Read an episode log (bag directory, or a bare ``.mcap`` file) written by
    :class:`EpisodeLogWriter` or a recorder (same topics)."""
    p = Path(path)
    metadata, foreign = _episode_metadata(p)
    if metadata is None:
        raise EpisodeLogError(f"{p}: no {EPISODE_FORMAT!r} metadata on /nehmo/scenario")
    if "cell" not in metadata:
        raise EpisodeLogError(f"{p}: episode metadata lacks the cell")
    cell = cell_from_dict(metadata["cell"], source=f"{p.name}:cell")
    goals: dict[str, np.ndarray] = {}
    by_stamp: dict[int, dict[str, list[np.ndarray]]] = defaultdict(lambda: defaultdict(list))
    statuses: dict[str, list[tuple[int, StatusRecord]]] = {a: [] for a in cell.arm_ids}
    commands: dict[str, list[tuple[int, np.ndarray]]] = {a: [] for a in cell.arm_ids}
    collisions: list[tuple[int, list[Collision]]] = []
    malformed: Counter[str] = Counter()
    reasons: dict[str, str] = {}

    def ignore(topic: str, count: int, why: str) -> None:
        malformed[topic] += count
        reasons.setdefault(topic, why)

    if foreign:
        ignore(SCENARIO_TOPIC, foreign, "not the episode's metadata (JSON of another format)")
    for arm_id, q in (metadata.get("goal") or {}).items():  # the episode's own goals
        if arm_id in statuses:
            try:
                goals[arm_id] = cell.arm(arm_id).robot.check_q(q, f"metadata goal of {arm_id}")
            except (NehmoError, ValueError, TypeError) as err:
                raise EpisodeLogError(f"{p}: {err}") from None

    for rec in iter_log(p):
        if rec.topic == COLLISIONS_TOPIC:
            arm_id, what = None, ""
        else:
            split = split_arm_topic(rec.topic)
            if split is None or split[0] not in statuses:
                continue
            arm_id, what = split
            if what not in _ARM_TOPICS:
                continue
        try:
            value = _decoded(rec, cell, arm_id, what, rec.topic)
        except _Malformed as why:
            ignore(rec.topic, 1, str(why))
            continue
        if arm_id is None:
            if value:
                collisions.append((rec.log_time_ns, value))
        elif what == "joint_states":
            by_stamp[rec.log_time_ns][arm_id].append(value)
        elif what == "goal":
            goals.setdefault(arm_id, value)  # when the metadata has none: the first valid one
        elif what == "planner/status":
            statuses[arm_id].append((rec.log_time_ns, value))
        else:
            commands[arm_id].append((rec.log_time_ns, value))
    states: dict[int, dict[str, np.ndarray]] = {}
    for t, per_arm in by_stamp.items():
        states[t] = {}
        for arm_id, qs in per_arm.items():
            if all(np.array_equal(q, qs[0]) for q in qs[1:]):
                states[t][arm_id] = qs[0]
            else:  # two publishers disagree: neither is trusted at this instant
                ignore(
                    joint_states_topic(arm_id),
                    len(qs),
                    f"{len(qs)} different states of {arm_id!r} at one time ({t} ns)",
                )
    missing = [a for a in cell.arm_ids if a not in goals]
    if missing:
        raise EpisodeLogError(f"{p}: no goal logged for arms {missing}")
    complete = sorted(t for t, q in states.items() if len(q) == len(cell.arms))
    if not complete:
        ignored = f" ({sum(malformed.values())} malformed messages ignored)" if malformed else ""
        raise EpisodeLogError(f"{p}: no instant with a valid joint state of every arm{ignored}")
    positions = {a: np.array([states[t][a] for t in complete]) for a in cell.arm_ids}
    return EpisodeLog(
        path=p,
        metadata=metadata,
        cell=cell,
        goals=goals,
        stamps=np.array(complete, dtype=np.int64),
        positions=positions,
        statuses=statuses,
        commands=commands,
        collisions=collisions,
        malformed=dict(sorted(malformed.items())),
        malformed_reasons={t: reasons[t] for t in sorted(reasons)},
    )
