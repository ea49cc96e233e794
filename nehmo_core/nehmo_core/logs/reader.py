"""Reads NeHMO MCAP logs back into typed records."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nehmo_core.errors import NehmoError
from nehmo_core.logs.messages import MESSAGE_TYPES, RosMessage, String, deserialize
from nehmo_core.logs.topics import SCENARIO_TOPIC


class LogFileError(NehmoError):
    """A log that is missing, not MCAP, not a ros2 log, or unfinished (see ``recover``)."""


@dataclass(frozen=True)
class LogRecord:
    """One logged message. `message` is decoded when its type is one of ours, else None."""

    topic: str
    msgtype: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes = field(repr=False)
    message: RosMessage | None


@dataclass(frozen=True)
class LogSummary:
    """What a log holds: topic → (type, message count), and the time span [ns]."""

    topics: dict[str, tuple[str, int]]
    start_ns: int
    end_ns: int
    profile: str
    message_count: int


def _check_file(path: Path) -> None:
    if not path.is_file():
        raise LogFileError(f"log {str(path)!r} does not exist")


def _unfinished(path: Path, err: Exception) -> LogFileError:
    return LogFileError(
        f"cannot read log {str(path)!r} ({type(err).__name__}: {err}); if the writer was killed, "
        f"rewrite it with: python -m nehmo_core.logs.recover {path} <fixed.mcap>"
    )


def iter_log(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[LogRecord]:
    """Every message of a finished log in log-time order, optionally only on `topics`."""
    from mcap.reader import make_reader

    path = Path(path)
    _check_file(path)
    with path.open("rb") as stream:
        reader = make_reader(stream)
        try:
            messages = reader.iter_messages(topics=list(topics) if topics else None)
            for schema, channel, message in messages:
                msgtype = schema.name if schema is not None else ""
                decoded = deserialize(message.data, msgtype) if msgtype in MESSAGE_TYPES else None
                yield LogRecord(
                    topic=channel.topic,
                    msgtype=msgtype,
                    log_time_ns=message.log_time,
                    publish_time_ns=message.publish_time,
                    sequence=message.sequence,
                    data=bytes(message.data),
                    message=decoded,
                )
        except NehmoError:
            raise
        except Exception as err:  # mcap raises several unrelated types on damaged files
            raise _unfinished(path, err) from None


def read_log(path: str | Path, topics: Iterable[str] | None = None) -> list[LogRecord]:
    """All records of a finished log (see :func:`iter_log`)."""
    return list(iter_log(path, topics))


def summarize(path: str | Path) -> LogSummary:
    """Topics, types, counts and time span of a finished log, from its summary section."""
    from mcap.reader import make_reader

    path = Path(path)
    _check_file(path)
    with path.open("rb") as stream:
        reader = make_reader(stream)
        try:
            header = reader.get_header()
            summary = reader.get_summary()
        except Exception as err:
            raise _unfinished(path, err) from None
        if summary is None or summary.statistics is None:
            raise _unfinished(path, ValueError("no summary section"))
        stats = summary.statistics
        topics = {
            ch.topic: (
                summary.schemas[ch.schema_id].name if ch.schema_id in summary.schemas else "",
                stats.channel_message_counts.get(ch.id, 0),
            )
            for ch in summary.channels.values()
        }
        return LogSummary(
            topics=topics,
            start_ns=stats.message_start_time,
            end_ns=stats.message_end_time,
            profile=header.profile,
            message_count=stats.message_count,
        )


def read_scenario(path: str | Path) -> dict[str, Any] | None:
    """The scenario JSON logged on ``/nehmo/scenario`` (the first one), or None."""
    for record in iter_log(path, [SCENARIO_TOPIC]):
        if isinstance(record.message, String):
            value = json.loads(record.message.data)
            return value if isinstance(value, dict) else {"scenario": value}
    return None
