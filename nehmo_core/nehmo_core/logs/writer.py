"""Writes rosbag2-compatible MCAP logs (profile ``ros2``, ``ros2msg`` schemas, ``cdr`` messages).

The file is written in small uncompressed chunks that are closed and flushed to the OS every
``flush_every`` messages or ``flush_interval_s`` seconds, whichever comes first, so a process
killed with SIGKILL loses at most the messages since the last flush; ``recover`` rewrites the
rest into a finished file. A finished file carries the usual summary (chunk indexes, statistics)
that seeking readers (``mcap``, ``rosbags``, ``ros2 bag``, Foxglove) use.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.logs.messages import String as StringMsg
from nehmo_core.logs.messages import message_class, message_definition, msgtype_of, serialize
from nehmo_core.logs.topics import SCENARIO_TOPIC, topic_type

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"


@dataclass(frozen=True)
class QosDescription:
    """The QoS a topic was offered with, stored in the channel metadata as rosbag2 does."""

    reliability: str = "reliable"  # "reliable" | "best_effort"
    depth: int = 10
    history: str = "keep_last"
    durability: str = "volatile"  # "volatile" | "transient_local"

    def to_yaml(self) -> str:
        """rosbag2 (Jazzy, metadata v9) ``offered_qos_profiles`` YAML for one publisher."""
        zero = "{sec: 0, nsec: 0}"
        return (
            f"- history: {self.history}\n  depth: {self.depth}\n"
            f"  reliability: {self.reliability}\n  durability: {self.durability}\n"
            f"  deadline: {zero}\n  lifespan: {zero}\n  liveliness: automatic\n"
            f"  liveliness_lease_duration: {zero}\n  avoid_ros_namespace_conventions: false"
        )


#: ROS 2's default QoS (KEEP_LAST 10, RELIABLE, VOLATILE).
DEFAULT_QOS = QosDescription()


@dataclass(frozen=True)
class WriterSettings:
    """How often the log is made durable: every `flush_every` messages or `flush_interval_s`."""

    flush_every: int = 50
    flush_interval_s: float = 0.5
    chunk_size: int = 256 * 1024  # [bytes] upper bound; chunks usually close on flush first

    def __post_init__(self) -> None:
        if self.flush_every < 1:
            raise InvalidValueError("flush_every", "must be >= 1", self.flush_every)
        if not self.flush_interval_s > 0:
            raise InvalidValueError("flush_interval_s", "must be > 0", self.flush_interval_s)
        if self.chunk_size < 1024:
            raise InvalidValueError("chunk_size", "must be >= 1024 bytes", self.chunk_size)

    @classmethod
    def crash_safe(cls) -> WriterSettings:
        """Flush after every message: nothing but the message being written can be lost."""
        return cls(flush_every=1)


class LogWriterError(NehmoError):
    """Misuse of a log writer (closed, a topic re-registered with another type, ...)."""


class LogWriter:
    """Writes one MCAP log; use as a context manager so the summary gets written.

    Topics are registered on first use. For the topics of the NeHMO schema (see
    :mod:`nehmo_core.logs.topics`) the message type is known; other topics need `msgtype`.
    """

    def __init__(
        self,
        path: str | Path,
        settings: WriterSettings | None = None,
        *,
        library: str = "nehmo_core",
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self.settings = settings or WriterSettings()
        self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(
            self._stream,
            chunk_size=self.settings.chunk_size,
            compression=CompressionType.NONE,
        )
        self._writer.start(profile=PROFILE, library=library)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._sequence: dict[int, int] = {}
        self._unflushed = 0
        self._last_flush = time.monotonic()
        self._closed = False
        self.message_count = 0

    # ------------------------------------------------------------------ registration
    def add_topic(
        self, topic: str, msgtype: str | None = None, qos: QosDescription = DEFAULT_QOS
    ) -> int:
        """Register `topic` (idempotent) and return its channel id."""
        self._check_open()
        msgtype = msgtype or topic_type(topic)
        if topic in self._channels:
            channel_id, known = self._channels[topic]
            if known != msgtype:
                raise LogWriterError(
                    f"topic {topic!r} is logged as {known}; cannot also log it as {msgtype}"
                )
            return channel_id
        message_class(msgtype)  # raises for a type we cannot describe
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._writer.register_schema(
                name=msgtype,
                encoding=SCHEMA_ENCODING,
                data=message_definition(msgtype).encode("utf-8"),
            )
        channel_id = self._writer.register_channel(
            topic=topic,
            message_encoding=MESSAGE_ENCODING,
            schema_id=self._schemas[msgtype],
            metadata={"offered_qos_profiles": qos.to_yaml()},
        )
        self._channels[topic] = (channel_id, msgtype)
        return channel_id

    # ------------------------------------------------------------------ writing
    def write(
        self,
        topic: str,
        msg: object,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Serialize `msg` (our dataclass or an rclpy message) and log it on `topic`.

        `log_time_ns` is the receive time [ns] (simulated or wall, one convention per log).
        """
        given = msgtype_of(msg)
        msgtype = self._channels[topic][1] if topic in self._channels else None
        msgtype = msgtype or topic_type_or_none(topic) or given
        if given != msgtype:
            raise LogWriterError(f"topic {topic!r} is logged as {msgtype}; got a {given}")
        self.write_raw(topic, serialize(msg, msgtype), log_time_ns, publish_time_ns, msgtype)

    def write_raw(
        self,
        topic: str,
        data: bytes,
        log_time_ns: int,
        publish_time_ns: int | None = None,
        msgtype: str | None = None,
    ) -> None:
        """Log pre-serialized CDR bytes (encapsulation header included) on `topic`."""
        channel_id = self.add_topic(topic, msgtype)
        if log_time_ns < 0:
            raise InvalidValueError("log_time_ns", "must be >= 0", log_time_ns)
        sequence = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = sequence + 1
        self._writer.add_message(
            channel_id=channel_id,
            log_time=int(log_time_ns),
            data=bytes(data),
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
            sequence=sequence,
        )
        self.message_count += 1
        self._unflushed += 1
        if (
            self._unflushed >= self.settings.flush_every
            or time.monotonic() - self._last_flush >= self.settings.flush_interval_s
        ):
            self.flush()

    def write_scenario(self, scenario: Mapping[str, Any], log_time_ns: int = 0) -> None:
        """Log the run's scenario description as JSON on ``/nehmo/scenario``."""
        text = json.dumps(scenario, sort_keys=True, allow_nan=False)
        self.write(SCENARIO_TOPIC, StringMsg(data=text), log_time_ns)
        self.flush()

    @property
    def pending(self) -> int:
        """Messages written since the last flush (lost if the process is killed now).

        ``write_raw`` checks ``flush_interval_s`` only when a message comes; a writer whose
        traffic may stop calls :meth:`flush` from a timer while this is nonzero.
        """
        return self._unflushed

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS (survives SIGKILL, not power loss)."""
        self._check_open()
        self._writer.flush()
        self._unflushed = 0
        self._last_flush = time.monotonic()

    # ------------------------------------------------------------------ closing
    def close(self) -> None:
        """Write the summary and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

    def _check_open(self) -> None:
        if self._closed:
            raise LogWriterError(f"log {str(self.path)!r} is already closed")

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def topic_type_or_none(topic: str) -> str | None:
    """Schema type of `topic`, or None for a topic outside the NeHMO schema."""
    try:
        return topic_type(topic)
    except NehmoError:
        return None
