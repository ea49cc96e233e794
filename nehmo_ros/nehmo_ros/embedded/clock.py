"""Time, Duration and clocks of the embedded runtime (the parts of rclpy.time/clock we use).

A node's clock is ROS time: wall time, or, with the parameter ``use_sim_time`` true, the latest
time received on ``/clock`` (0 until the first message), as in rclpy.
"""

from __future__ import annotations

import threading
import time
from enum import IntEnum

from nehmo_core.logs.messages import Time as TimeMsg

_NS = 1_000_000_000


class ClockType(IntEnum):
    """As ``rclpy.clock.ClockType``."""

    UNINITIALIZED = 0
    ROS_TIME = 1
    SYSTEM_TIME = 2
    STEADY_TIME = 3


class Duration:
    """A signed span of time [ns]."""

    __slots__ = ("nanoseconds",)

    def __init__(self, *, seconds: float = 0, nanoseconds: int = 0) -> None:
        self.nanoseconds = round(seconds * _NS) + int(nanoseconds)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Duration) and other.nanoseconds == self.nanoseconds

    def __lt__(self, other: Duration) -> bool:
        return self.nanoseconds < other.nanoseconds

    def __le__(self, other: Duration) -> bool:
        return self.nanoseconds <= other.nanoseconds

    def __hash__(self) -> int:
        return hash(self.nanoseconds)

    def __repr__(self) -> str:
        return f"Duration(nanoseconds={self.nanoseconds})"


class Time:
    """A point in time [ns since the epoch of its clock] (as ``rclpy.time.Time``)."""

    __slots__ = ("clock_type", "nanoseconds")

    def __init__(
        self,
        *,
        seconds: float = 0,
        nanoseconds: int = 0,
        clock_type: ClockType = ClockType.SYSTEM_TIME,
    ) -> None:
        total = round(seconds * _NS) + int(nanoseconds)
        if total < 0:
            raise ValueError(f"Time must be >= 0; got {total} ns")
        self.nanoseconds = total
        self.clock_type = clock_type

    def seconds_nanoseconds(self) -> tuple[int, int]:
        """(whole seconds, remaining nanoseconds)."""
        return divmod(self.nanoseconds, _NS)

    def to_msg(self) -> TimeMsg:
        """As a builtin_interfaces/Time message."""
        sec, nanosec = self.seconds_nanoseconds()
        return TimeMsg(sec=sec, nanosec=nanosec)

    @classmethod
    def from_msg(cls, msg: TimeMsg, clock_type: ClockType = ClockType.ROS_TIME) -> Time:
        """From a builtin_interfaces/Time message."""
        return cls(nanoseconds=msg.sec * _NS + msg.nanosec, clock_type=clock_type)

    def __add__(self, other: Duration) -> Time:
        return Time(nanoseconds=self.nanoseconds + other.nanoseconds, clock_type=self.clock_type)

    def __sub__(self, other: Time | Duration) -> Time | Duration:
        if isinstance(other, Time):
            return Duration(nanoseconds=self.nanoseconds - other.nanoseconds)
        return Time(nanoseconds=self.nanoseconds - other.nanoseconds, clock_type=self.clock_type)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Time) and (other.nanoseconds, other.clock_type) == (
            self.nanoseconds,
            self.clock_type,
        )

    def __lt__(self, other: Time) -> bool:
        return self.nanoseconds < other.nanoseconds

    def __le__(self, other: Time) -> bool:
        return self.nanoseconds <= other.nanoseconds

    def __hash__(self) -> int:
        return hash((self.nanoseconds, self.clock_type))

    def __repr__(self) -> str:
        return f"Time(nanoseconds={self.nanoseconds}, clock_type={self.clock_type.name})"


class Clock:
    """A clock of one type; ROS-time clocks can be switched to simulated time."""

    def __init__(self, *, clock_type: ClockType = ClockType.SYSTEM_TIME) -> None:
        self.clock_type = clock_type
        self._lock = threading.Lock()
        self._sim_active = False
        self._sim_ns = 0

    def now(self) -> Time:
        """The current time of this clock."""
        if self.clock_type == ClockType.STEADY_TIME:
            ns = time.monotonic_ns()
        elif self._sim_active:
            ns = self._sim_ns
        else:
            ns = time.time_ns()
        return Time(nanoseconds=ns, clock_type=self.clock_type)

    @property
    def ros_time_is_active(self) -> bool:
        """True when this clock follows ``/clock``."""
        return self._sim_active

    def _set_ros_time_is_active(self, active: bool) -> None:
        if self.clock_type != ClockType.ROS_TIME:
            raise RuntimeError("only a ROS_TIME clock can follow /clock")
        with self._lock:
            self._sim_active = active

    def _set_ros_time(self, nanoseconds: int) -> None:
        with self._lock:
            self._sim_ns = int(nanoseconds)


class ROSClock(Clock):
    """The ROS-time clock of a node."""

    def __init__(self) -> None:
        super().__init__(clock_type=ClockType.ROS_TIME)
