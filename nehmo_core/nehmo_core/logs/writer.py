"""Writes rosbag2 bags: a directory with one MCAP file and, once closed, ``metadata.yaml``.

A bag ``run/`` holds ``run/run_0.mcap`` (profile ``ros2``; schemas ``pkg/msg/Type`` in
``ros2msg`` with their dependencies; ``cdr`` channels carrying ``offered_qos_profiles`` and
``topic_type_hash``; a ``rosbag2`` metadata record) and ``run/metadata.yaml`` (rosbag2 Jazzy,
version 9), as ``ros2 bag record -s mcap`` writes them, so ``ros2 bag``, Foxglove, ``rosbags``
and ``mcap`` open it.

The MCAP file is written in small uncompressed chunks that are closed and flushed to the OS
every ``flush_every`` messages or ``flush_interval_s`` seconds, whichever comes first, so a
process killed with SIGKILL loses at most the messages since the last flush; ``recover``
rewrites the rest into a finished bag. ``metadata.yaml`` is written last, on close: a bag
without it was not closed.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import yaml

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.logs.messages import String as StringMsg
from nehmo_core.logs.messages import (
    message_definition,
    msgtype_of,
    serialize,
    type_hash,
)
from nehmo_core.logs.topics import SCENARIO_TOPIC, topic_type

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
METADATA_FILE = "metadata.yaml"
METADATA_RECORD = "rosbag2"
ROSBAG2_VERSION = 9
ROS_DISTRO = "jazzy"


def mcap_file_name(bag: str | Path, index: int = 0) -> str:
    """Name of the `index`-th MCAP file of bag directory `bag` (``<dirname>_<index>.mcap``)."""
    return f"{Path(bag).name}_{index}.mcap"


@dataclass(frozen=True)
class QosDescription:
    """The QoS a topic was offered with, stored as rosbag2 stores it (channel and metadata)."""

    reliability: str = "reliable"  # "reliable" | "best_effort"
    depth: int = 10
    history: str = "keep_last"
    durability: str = "volatile"  # "volatile" | "transient_local"

    def to_dict(self) -> dict[str, Any]:
        """One profile as rosbag2 (Jazzy, metadata v9) writes it."""
        zero = {"sec": 0, "nsec": 0}
        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": dict(zero),
            "lifespan": dict(zero),
            "liveliness": "automatic",
            "liveliness_lease_duration": dict(zero),
            "avoid_ros_namespace_conventions": False,
        }

    def to_yaml(self) -> str:
        """The ``offered_qos_profiles`` channel metadata (YAML list) for one publisher."""
        return _dump_yaml([self.to_dict()])


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


@dataclass
class _Topic:
    channel_id: int
    msgtype: str
    qos_profiles: list[Any]
    type_hash: str
    count: int = 0
    sequence: int = field(default=0)


def _dump_yaml(value: object) -> str:
    return yaml.safe_dump(value, sort_keys=False, default_flow_style=False).strip()


def check_bag_path(path: str | Path, parameter: str = "path") -> Path:
    """`path` as a bag directory to create: not an ``.mcap`` name, new or empty."""
    bag = Path(path)
    if bag.suffix == ".mcap":
        raise InvalidValueError(
            parameter,
            "must name a bag directory (the MCAP file and metadata.yaml go inside it), "
            "not an .mcap file",
            str(bag),
        )
    if bag.exists() and (not bag.is_dir() or any(bag.iterdir())):
        raise InvalidValueError(
            parameter, "must be a new or empty directory (bags are never overwritten)", str(bag)
        )
    return bag


def remove_bag(path: str | Path) -> bool:
    """Delete the bag directory `path` (``metadata.yaml``, ``.mcap`` files, the directory).

    Returns False when there is nothing at `path`. Refuses (:class:`LogWriterError`) a file or
    a directory holding anything else, so it cannot delete what is not a bag.
    """
    bag = Path(path)
    if not bag.exists():
        return False
    parts = list(bag.iterdir()) if bag.is_dir() else []
    strangers = [p.name for p in parts if not _bag_part(p)]
    if not bag.is_dir() or strangers:
        raise LogWriterError(
            f"{str(bag)!r} is not a bag directory (holds {strangers}); not removing it"
        )
    for part in parts:
        part.unlink()
    bag.rmdir()
    return True


def _bag_part(path: Path) -> bool:
    return path.is_file() and (
        path.suffix == ".mcap" or path.name in (METADATA_FILE, METADATA_FILE + ".tmp")
    )


class LogWriter:
    """Writes one bag directory; use as a context manager so the bag gets finished.

    Topics are registered on first use. For the topics of the NeHMO schema (see
    :mod:`nehmo_core.logs.topics`) the message type is known; other topics need `msgtype`.
    `custom_data` (str → str) goes to ``metadata.yaml``'s ``custom_data``.
    """

    def __init__(
        self,
        path: str | Path,
        settings: WriterSettings | None = None,
        *,
        library: str = "nehmo_core",
        custom_data: Mapping[str, str] | None = None,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = check_bag_path(path)
        self.settings = settings or WriterSettings()
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / mcap_file_name(self.path)
        self._stream: IO[bytes] = open(self.mcap_path, "wb")  # noqa: SIM115 (closed in close())
        self._writer = Writer(
            self._stream,
            chunk_size=self.settings.chunk_size,
            compression=CompressionType.NONE,
        )
        self._writer.start(profile=PROFILE, library=library)
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _Topic] = {}
        self._by_channel: dict[int, _Topic] = {}
        self._unflushed = 0
        self._last_flush = time.monotonic()
        self._closed = False
        self._start_ns: int | None = None
        self._end_ns = 0
        self.message_count = 0

    @property
    def topics(self) -> dict[str, str]:
        """Registered topics → message type."""
        return {topic: t.msgtype for topic, t in self._topics.items()}

    # ------------------------------------------------------------------ registration
    def add_topic(
        self, topic: str, msgtype: str | None = None, qos: QosDescription = DEFAULT_QOS
    ) -> int:
        """Register `topic` (idempotent) and return its channel id."""
        self._check_open()
        msgtype = msgtype or topic_type(topic)
        if topic in self._topics:
            return self._known_channel(topic, msgtype)
        digest = type_hash(msgtype)  # raises for a type the typestore does not know
        metadata = {"offered_qos_profiles": qos.to_yaml(), "topic_type_hash": digest}
        return self.add_channel(
            topic, msgtype, SCHEMA_ENCODING, message_definition(msgtype).encode(), metadata
        )

    def add_channel(
        self,
        topic: str,
        msgtype: str,
        schema_encoding: str,
        schema_data: bytes,
        metadata: Mapping[str, str],
    ) -> int:
        """Register `topic` with a given schema and channel metadata (what ``recover`` keeps).

        ``metadata`` should hold ``offered_qos_profiles`` (YAML) and ``topic_type_hash``.
        """
        self._check_open()
        if topic in self._topics:
            return self._known_channel(topic, msgtype)
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._writer.register_schema(
                name=msgtype, encoding=schema_encoding, data=schema_data
            )
        channel_id = self._writer.register_channel(
            topic=topic,
            message_encoding=MESSAGE_ENCODING,
            schema_id=self._schemas[msgtype],
            metadata=dict(metadata),
        )
        profiles = yaml.safe_load(metadata.get("offered_qos_profiles", "") or "[]")
        entry = _Topic(
            channel_id,
            msgtype,
            profiles if isinstance(profiles, list) else [],
            metadata.get("topic_type_hash", ""),
        )
        self._topics[topic] = entry
        self._by_channel[channel_id] = entry
        return channel_id

    def _known_channel(self, topic: str, msgtype: str) -> int:
        known = self._topics[topic]
        if known.msgtype != msgtype:
            raise LogWriterError(
                f"topic {topic!r} is logged as {known.msgtype}; cannot also log it as {msgtype}"
            )
        return known.channel_id

    # ------------------------------------------------------------------ writing
    def write(
        self,
        topic: str,
        msg: object,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Serialize `msg` (a typestore message, e.g. built by :mod:`.messages`) on `topic`.

        `log_time_ns` is the receive time [ns] (simulated or wall, one convention per log).
        """
        given = msgtype_of(msg)
        known = self._topics.get(topic)
        msgtype = known.msgtype if known else (topic_type_or_none(topic) or given)
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
        sequence = self._topics[topic].sequence
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        self.add_message(channel_id, log_time_ns, publish, sequence, data)

    def add_message(
        self, channel_id: int, log_time_ns: int, publish_time_ns: int, sequence: int, data: bytes
    ) -> None:
        """Log `data` on a registered channel with an explicit sequence number."""
        self._check_open()
        if log_time_ns < 0:
            raise InvalidValueError("log_time_ns", "must be >= 0", log_time_ns)
        entry = self._by_channel.get(channel_id)
        if entry is None:
            raise LogWriterError(f"channel {channel_id} is not registered")
        self._writer.add_message(
            channel_id=channel_id,
            log_time=int(log_time_ns),
            data=bytes(data),
            publish_time=int(publish_time_ns),
            sequence=int(sequence) & 0xFFFFFFFF,
        )
        entry.sequence = int(sequence) + 1
        entry.count += 1
        self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
        self._end_ns = max(self._end_ns, log_time_ns)
        self.message_count += 1
        self._unflushed += 1
        if (
            self._unflushed >= self.settings.flush_every
            or time.monotonic() - self._last_flush >= self.settings.flush_interval_s
        ):
            self.flush()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """An MCAP metadata record (name ``rosbag2`` is reserved for the bag metadata)."""
        self._check_open()
        if name == METADATA_RECORD:
            raise LogWriterError(f"metadata record {name!r} is written by the writer on close")
        self._writer.add_metadata(name, dict(data))

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
    def bag_metadata(self) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping of the bag as written so far."""
        start = self._start_ns or 0
        duration = self._end_ns - start if self.message_count else 0

        def times() -> dict[str, Any]:  # fresh mappings: the YAML holds no anchors
            return {
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
            }

        name = self.mcap_path.name
        return {
            "version": ROSBAG2_VERSION,
            "storage_identifier": "mcap",
            **times(),
            "message_count": self.message_count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": topic,
                        "type": t.msgtype,
                        "serialization_format": MESSAGE_ENCODING,
                        "offered_qos_profiles": t.qos_profiles,
                        "type_description_hash": t.type_hash,
                    },
                    "message_count": t.count,
                }
                for topic, t in self._topics.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [name],
            "files": [{"path": name, **times(), "message_count": self.message_count}],
            "custom_data": dict(self.custom_data),
            "ros_distro": ROS_DISTRO,
        }

    def close(self) -> None:
        """Finish the MCAP file (metadata record, summary), then write ``metadata.yaml``.

        Idempotent. A writer that failed while closing leaves a bag without ``metadata.yaml``,
        which ``recover`` repairs.
        """
        if self._closed:
            return
        self._closed = True
        info = self.bag_metadata()
        try:
            self._writer.add_metadata(
                METADATA_RECORD,
                {"serialized_metadata": _dump_yaml(info), "ROS_DISTRO": ROS_DISTRO},
            )
            self._writer.finish()
        finally:
            self._stream.close()
        text = _dump_yaml({"rosbag2_bagfile_information": info}) + "\n"
        tmp = self.path / (METADATA_FILE + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, self.path / METADATA_FILE)

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
