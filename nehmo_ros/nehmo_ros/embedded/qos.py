"""QoS profiles of the embedded runtime, with rclpy's names and defaults."""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Any


class HistoryPolicy(IntEnum):
    """As ``rclpy.qos.HistoryPolicy``."""

    SYSTEM_DEFAULT = 0
    KEEP_LAST = 1
    KEEP_ALL = 2


class ReliabilityPolicy(IntEnum):
    """As ``rclpy.qos.ReliabilityPolicy``."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class DurabilityPolicy(IntEnum):
    """As ``rclpy.qos.DurabilityPolicy``."""

    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


@dataclass(frozen=True, kw_only=True)
class QoSProfile:
    """History, depth, reliability, durability; the defaults are ROS 2's default profile."""

    history: HistoryPolicy = HistoryPolicy.KEEP_LAST
    depth: int = 10
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    durability: DurabilityPolicy = DurabilityPolicy.VOLATILE

    def __post_init__(self) -> None:
        if self.history != HistoryPolicy.KEEP_ALL and self.depth < 1:
            raise ValueError(f"QoS `depth` must be >= 1 for KEEP_LAST; got {self.depth}")


#: ROS 2 default: KEEP_LAST 10, RELIABLE, VOLATILE.
qos_profile_default = QoSProfile()
#: ROS 2 sensor data: KEEP_LAST 5, BEST_EFFORT, VOLATILE.
qos_profile_sensor_data = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
#: What rclpy's TimeSource uses to read ``/clock``.
qos_profile_clock = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


def as_profile(qos: QoSProfile | int) -> QoSProfile:
    """rclpy accepts a plain depth wherever a profile is expected."""
    if isinstance(qos, QoSProfile):
        return qos
    if isinstance(qos, int) and not isinstance(qos, bool):
        return QoSProfile(depth=qos)
    raise TypeError(f"qos_profile must be a QoSProfile or a history depth; got {qos!r}")


def to_cyclone(profile: QoSProfile) -> Any:
    """The cyclonedds ``Qos`` of `profile` (reliable writers block at most 100 ms, as rmw)."""
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.util import duration

    history = (
        Policy.History.KeepAll
        if profile.history == HistoryPolicy.KEEP_ALL
        else Policy.History.KeepLast(profile.depth)
    )
    reliability = (
        Policy.Reliability.BestEffort
        if profile.reliability == ReliabilityPolicy.BEST_EFFORT
        else Policy.Reliability.Reliable(duration(milliseconds=100))
    )
    durability = (
        Policy.Durability.TransientLocal
        if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        else Policy.Durability.Volatile
    )
    return Qos(history, reliability, durability)
