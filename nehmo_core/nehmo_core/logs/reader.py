"""Reads NeHMO logs (rosbag2 bag directories, or a bare ``.mcap`` file) back into records."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nehmo_core.errors import NehmoError
from nehmo_core.logs.messages import String, deserialize, typestore
from nehmo_core.logs.topics import SCENARIO_TOPIC
from nehmo_core.logs.writer import METADATA_FILE


class LogFileError(NehmoError):
    """A log that is missing, not MCAP, not a ros2 log, or unfinished (see ``recover``)."""


@dataclass(frozen=True)
class LogRecord:
    """One logged message. `message` is the typestore instance for a ROS 2 Jazzy type the
    typestore knows (all of the suite's), else None."""

    topic: str
    msgtype: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes = field(repr=False)
    message: Any
    decode_error: str = ""  # why the bytes do not decode as ``msgtype`` (``message`` is None)


@dataclass(frozen=True)
class LogSummary:
    """What a log holds: topic → (type, message count), and the time span [ns]."""

    topics: dict[str, tuple[str, int]]
    start_ns: int
    end_ns: int
    profile: str
    message_count: int


def _unfinished(path: Path, why: str) -> LogFileError:
    return LogFileError(
        f"cannot read log {str(path)!r} ({why}); if the writer was killed, rewrite it with: "
        f"python -m nehmo_core.logs.recover {path} <fixed_bag_dir>"
    )


def bag_files(path: str | Path) -> list[Path]:
    """The MCAP files of a finished bag directory (from its ``metadata.yaml``), or ``[path]``
    for a bare ``.mcap`` file. Raises :class:`LogFileError` for a missing or unfinished log."""
    path = Path(path)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise LogFileError(f"log {str(path)!r} does not exist")
    meta = path / METADATA_FILE
    if not meta.is_file():
        if not any(path.glob("*.mcap")):
            raise LogFileError(
                f"{str(path)!r} is not a bag directory (no {METADATA_FILE}, no .mcap)"
            )
        raise _unfinished(path, f"no {METADATA_FILE}: the bag was not closed")
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        names = [str(n) for n in info["relative_file_paths"]]
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError) as err:
        raise LogFileError(f"{str(meta)!r} is not rosbag2 metadata ({err})") from None
    storage = info.get("storage_identifier", "mcap")
    if storage != "mcap":
        raise LogFileError(f"bag {str(path)!r} uses storage {storage!r}; only mcap is read")
    files = [path / n for n in names]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise LogFileError(f"bag {str(path)!r} lacks the files {missing} its metadata lists")
    return files


def _decode(msgtype: str, data: bytes) -> Any:
    if msgtype not in typestore().types:
        return None
    return deserialize(data, msgtype)


def _open(stream: Any, file: Path) -> Any:
    """An MCAP reader of ``stream``, or :class:`LogFileError` naming ``file``."""
    from mcap.reader import make_reader

    try:
        return make_reader(stream)
    except Exception as err:  # mcap raises several unrelated types on files that are not MCAP
        raise LogFileError(
            f"{file}: not a readable MCAP log ({type(err).__name__}: {err})"
        ) from None


def iter_log(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[LogRecord]:
    """Every message of a finished log in log-time order (per file), optionally only `topics`."""
    wanted = list(topics) if topics else None
    for file in bag_files(path):
        with file.open("rb") as stream:
            reader = _open(stream, file)
            try:
                for schema, channel, message in reader.iter_messages(topics=wanted):
                    msgtype = schema.name if schema is not None else ""
                    try:
                        decoded, why = _decode(msgtype, message.data), ""
                    except Exception as err:  # one undecodable message; the log goes on
                        decoded, why = None, f"{type(err).__name__}: {err}"
                    yield LogRecord(
                        topic=channel.topic,
                        msgtype=msgtype,
                        log_time_ns=message.log_time,
                        publish_time_ns=message.publish_time,
                        sequence=message.sequence,
                        data=bytes(message.data),
                        message=decoded,
                        decode_error=why,
                    )
            except NehmoError:
                raise
            except Exception as err:  # mcap raises several unrelated types on damaged files
                raise _unfinished(Path(path), f"{type(err).__name__}: {err}") from None


def read_log(path: str | Path, topics: Iterable[str] | None = None) -> list[LogRecord]:
    """All records of a finished log (see :func:`iter_log`)."""
    return list(iter_log(path, topics))


def summarize(path: str | Path) -> LogSummary:
    """Topics, types, counts and time span of a finished log, from its MCAP summaries."""
    topics: dict[str, tuple[str, int]] = {}
    start, end, count, profile = None, 0, 0, ""
    for file in bag_files(path):
        with file.open("rb") as stream:
            reader = _open(stream, file)
            try:
                profile = reader.get_header().profile
                summary = reader.get_summary()
            except Exception as err:
                raise _unfinished(Path(path), f"{type(err).__name__}: {err}") from None
            if summary is None or summary.statistics is None:
                raise _unfinished(Path(path), f"{file.name} has no summary section")
            stats = summary.statistics
            for ch in summary.channels.values():
                schema = summary.schemas.get(ch.schema_id)
                known = topics.get(ch.topic, ("", 0))[1]
                n = stats.channel_message_counts.get(ch.id, 0)
                topics[ch.topic] = (schema.name if schema else "", known + n)
            if stats.message_count:
                first = stats.message_start_time
                start = first if start is None else min(start, first)
                end = max(end, stats.message_end_time)
            count += stats.message_count
    return LogSummary(
        topics=topics, start_ns=start or 0, end_ns=end, profile=profile, message_count=count
    )


def read_scenario(path: str | Path) -> dict[str, Any] | None:
    """The scenario JSON logged on ``/nehmo/scenario`` (the first one), or None."""
    for record in iter_log(path, [SCENARIO_TOPIC]):
        if isinstance(record.message, String):
            value = json.loads(record.message.data)
            return value if isinstance(value, dict) else {"scenario": value}
    return None
