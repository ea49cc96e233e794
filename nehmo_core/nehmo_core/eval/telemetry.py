"""Planner telemetry and simulator collisions as standard ROS messages (the log schema).

``/<arm_id>/planner/status`` carries a ``diagnostic_msgs/DiagnosticStatus``: ``name`` is
``<arm_id>/planner``, ``hardware_id`` the arm id, ``message`` the solver status, ``level`` OK
(WARN when the fail-safe acted), and ``values`` the :class:`~nehmo_core.planning.Telemetry`
fields plus the planner kind and the stamp [ns] of the observation the command was planned
from. Floats are written with ``repr`` so they read back bit for bit.

``/nehmo/collisions`` carries a ``diagnostic_msgs/DiagnosticArray`` with one ERROR status per
colliding pair (self-collisions have ``arm_a == arm_b``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.pybullet_world import Collision
from nehmo_core.logs.messages import DiagnosticArray, DiagnosticStatus, Header, KeyValue, Time
from nehmo_core.planning.opt.interface import Telemetry

__all__ = [
    "StatusRecord",
    "collisions_from_message",
    "collisions_message",
    "stamp",
    "status_message",
    "telemetry_from_status",
]


def stamp(ns: int) -> Time:
    """``builtin_interfaces/Time`` of ``ns`` nanoseconds."""
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def _ids(values: Sequence[str]) -> str:
    return ",".join(values)


def status_message(
    arm_id: str, kind: str, telemetry: Telemetry, observation_ns: int
) -> DiagnosticStatus:
    """The status of one plan() call, planned from the observations at ``observation_ns``."""
    t = telemetry
    values = {
        "planner": kind,
        "observation_ns": str(int(observation_ns)),
        "solve_time": repr(float(t.solve_time)),
        "fail_safe": "true" if t.fail_safe else "false",
        "min_value": repr(float(t.min_value)),
        "min_constraint": repr(float(t.min_constraint)),
        "iterations": str(int(t.iterations)),
        "peers_constrained": _ids(t.peers_constrained),
        "peers_skipped": _ids(t.peers_skipped),
        "peers_unmodelled": _ids(t.peers_unmodelled),
        "critical_peer": t.critical_peer or "",
        "escaping": "true" if t.escaping else "false",
        "evading": "true" if t.evading else "false",
        "speed_bound": repr(float(t.speed_bound)),
    }
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if t.fail_safe else DiagnosticStatus.OK,
        name=f"{arm_id}/planner",
        message=t.status,
        hardware_id=arm_id,
        values=[KeyValue(key=k, value=v) for k, v in values.items()],
    )


@dataclass(frozen=True)
class StatusRecord:
    """A decoded planner status: the telemetry, the planner kind and the observation stamp."""

    arm_id: str
    kind: str
    observation_ns: int
    telemetry: Telemetry


def _float(values: dict[str, str], key: str) -> float:
    text = values.get(key, "nan")
    try:
        return float(text)
    except ValueError:
        raise NehmoError(f"planner status field {key!r} is not a number: {text!r}") from None


def _split(text: str) -> tuple[str, ...]:
    return tuple(p for p in text.split(",") if p)


def telemetry_from_status(msg: DiagnosticStatus) -> StatusRecord:
    """Decode a message written by :func:`status_message`."""
    values = {kv.key: kv.value for kv in msg.values}
    for key in ("planner", "observation_ns", "solve_time"):
        if key not in values:
            raise NehmoError(f"planner status of {msg.hardware_id!r} lacks the field {key!r}")
    telemetry = Telemetry(
        solve_time=_float(values, "solve_time"),
        status=msg.message,
        fail_safe=values.get("fail_safe") == "true",
        min_value=_float(values, "min_value") if "min_value" in values else math.inf,
        min_constraint=_float(values, "min_constraint"),
        iterations=int(values.get("iterations", "0")),
        peers_constrained=_split(values.get("peers_constrained", "")),
        peers_skipped=_split(values.get("peers_skipped", "")),
        peers_unmodelled=_split(values.get("peers_unmodelled", "")),
        critical_peer=values.get("critical_peer") or None,
        escaping=values.get("escaping") == "true",
        evading=values.get("evading") == "true",
        speed_bound=_float(values, "speed_bound") if "speed_bound" in values else 1.0,
    )
    return StatusRecord(
        msg.hardware_id, values["planner"], int(values["observation_ns"]), telemetry
    )


def collisions_message(collisions: Sequence[Collision], time_ns: int) -> DiagnosticArray:
    """One ERROR status per collision, stamped ``time_ns``."""
    status = [
        DiagnosticStatus(
            level=DiagnosticStatus.ERROR,
            name=f"{c.arm_a}/{c.link_a}|{c.arm_b}/{c.link_b}",
            message="self-collision" if c.arm_a == c.arm_b else "collision",
            hardware_id=c.arm_a,
            values=[
                KeyValue(key="arm_a", value=c.arm_a),
                KeyValue(key="link_a", value=c.link_a),
                KeyValue(key="arm_b", value=c.arm_b),
                KeyValue(key="link_b", value=c.link_b),
                KeyValue(key="distance", value=repr(float(c.distance))),
            ],
        )
        for c in collisions
    ]
    return DiagnosticArray(header=Header(stamp=stamp(time_ns), frame_id="world"), status=status)


def collisions_from_message(msg: DiagnosticArray) -> list[Collision]:
    """Decode a message written by :func:`collisions_message`."""
    out = []
    for s in msg.status:
        v = {kv.key: kv.value for kv in s.values}
        out.append(
            Collision(
                v.get("arm_a", ""),
                v.get("link_a", ""),
                v.get("arm_b", ""),
                v.get("link_b", ""),
                float(v.get("distance", "nan")),
            )
        )
    return out
