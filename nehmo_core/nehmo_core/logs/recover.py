"""Recover a bag whose writer died (SIGKILL, power loss, disk full) into a new, finished bag.

Seeking readers reject an MCAP file without its summary and footer, and ``ros2 bag`` and
``rosbags`` need the bag's ``metadata.yaml``, which the writer writes on close. This module
reads the damaged MCAP file(s) sequentially, without seeking, keeps every schema, channel,
message and metadata record up to the point where the data stops making sense (a truncated
record, or a chunk whose checksum fails, e.g. one torn by a write that failed on a full disk:
its length field then runs into the records after it), and rewrites them into a new bag
directory (MCAP file, ``rosbag2`` metadata record, ``metadata.yaml``)::

    python -m nehmo_core.logs.recover broken_bag fixed_bag

The source (a bag directory, or a bare ``.mcap`` file) is only read. An existing output is not
overwritten unless asked (``--force``), so swapping the two arguments cannot destroy a log.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.logs.messages import message_definition, type_hash, typestore
from nehmo_core.logs.reader import LogFileError
from nehmo_core.logs.writer import (
    DEFAULT_QOS,
    METADATA_RECORD,
    LogWriter,
    LogWriterError,
    WriterSettings,
    remove_bag,
)

if TYPE_CHECKING:
    from mcap.records import Channel, Schema

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class RecoveryReport:
    """What `recover` kept; `stopped_by` names why reading stopped ("" for a clean end)."""

    messages: int
    channels: int
    schemas: int
    metadata: int
    complete: bool
    stopped_by: str


def source_files(src: Path) -> list[Path]:
    """The MCAP files of a (possibly unfinished) bag directory, or ``[src]`` for a file."""
    if src.is_file():
        return [src]
    if not src.is_dir():
        raise LogFileError(f"log {str(src)!r} does not exist")
    files = sorted(src.glob("*.mcap"), key=_split_index)
    if not files:
        raise LogFileError(f"{str(src)!r} holds no .mcap file to recover")
    return files


def _split_index(path: Path) -> tuple[int, str]:
    tail = path.stem.rpartition("_")[2]
    return (int(tail) if tail.isdigit() else -1, path.name)


def _prepare_output(src: Path, dst: Path, overwrite: bool) -> None:
    if src.resolve() == dst.resolve() or src.resolve() in dst.resolve().parents:
        raise LogFileError("recover writes a new bag: give an output path outside the input")
    if dst.is_file() or (dst.is_dir() and any(dst.iterdir())):
        if not overwrite:
            raise LogFileError(
                f"output {str(dst)!r} exists; recover does not overwrite it (remove it, choose "
                "another path or pass --force)"
            )
        try:
            remove_bag(dst)
        except LogWriterError as err:
            raise LogFileError(f"output {err}") from None
    if not dst.parent.is_dir():
        raise LogFileError(f"output directory {str(dst.parent)!r} does not exist")


def _check_magic(file: Path) -> None:
    with file.open("rb") as stream:
        head = stream.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise LogFileError(f"{str(file)!r} holds no readable MCAP header (not an MCAP file)")


class _Copier:
    """Moves the records of one source file into the output writer."""

    def __init__(self, writer: LogWriter) -> None:
        self.writer = writer
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.channel_ids: dict[int, int] = {}
        self.messages = 0
        self.metadata = 0

    def channel_id(self, old_id: int) -> int | None:
        """Output channel of source channel `old_id`, registered on first use."""
        if old_id in self.channel_ids:
            return self.channel_ids[old_id]
        channel = self.channels.get(old_id)
        if channel is None:
            return None  # a message whose channel record was lost: cannot be typed
        schema = self.schemas.get(channel.schema_id)
        msgtype = schema.name if schema is not None else ""
        metadata = dict(channel.metadata)
        known = msgtype in typestore().types
        if "offered_qos_profiles" not in metadata:
            metadata["offered_qos_profiles"] = DEFAULT_QOS.to_yaml()
        if "topic_type_hash" not in metadata and known:
            metadata["topic_type_hash"] = type_hash(msgtype)
        if schema is not None:
            encoding, data = schema.encoding, schema.data
        elif known:
            encoding, data = "ros2msg", message_definition(msgtype).encode()
        else:
            return None
        self.channel_ids[old_id] = self.writer.add_channel(
            channel.topic, msgtype, encoding, data, metadata
        )
        return self.channel_ids[old_id]


def recover(src: str | Path, dst: str | Path, overwrite: bool = False) -> RecoveryReport:
    """Rewrite every readable record of the bag (or ``.mcap`` file) `src` into a new, finished
    bag directory `dst` (an existing non-empty `dst` is an error unless `overwrite`)."""
    src, dst = Path(src), Path(dst)
    files = source_files(src)
    _prepare_output(src, dst, overwrite)
    _check_magic(files[0])
    try:
        writer = LogWriter(dst, WriterSettings(flush_every=10_000, flush_interval_s=3600.0))
    except InvalidValueError as err:
        raise LogFileError(f"cannot write the recovered bag: {err}") from None
    copiers: list[_Copier] = []
    complete, stopped_by = True, ""
    with writer:
        for file in files:
            copier = _Copier(writer)
            copiers.append(copier)
            file_complete, stopped_by = _copy_file(file, copier)
            complete = complete and file_complete
            if stopped_by:
                break
        for copier in copiers:  # channels that never got a message
            for old_id in list(copier.channels):
                copier.channel_id(old_id)
    return RecoveryReport(
        messages=sum(c.messages for c in copiers),
        channels=len(writer.topics),
        schemas=len(set(writer.topics.values())),
        metadata=sum(c.metadata for c in copiers),
        complete=complete and not stopped_by,
        stopped_by=stopped_by,
    )


def _copy_file(file: Path, copier: _Copier) -> tuple[bool, str]:
    """Copy one file's records; (whether its footer was reached, why reading stopped)."""
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    complete, stopped_by, started = False, "", False
    with file.open("rb") as stream:
        try:
            reader = StreamReader(stream, validate_crcs=True, record_size_limit=1 << 30)
            for record in reader.records:
                if isinstance(record, Header):
                    started = True
                elif not started:
                    raise LogFileError(f"{str(file)!r} does not start with an MCAP header")
                elif isinstance(record, Schema):
                    copier.schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    copier.channels.setdefault(record.id, record)
                elif isinstance(record, Message):
                    channel_id = copier.channel_id(record.channel_id)
                    if channel_id is None:
                        continue
                    copier.writer.add_message(
                        channel_id, record.log_time, record.publish_time, record.sequence,
                        record.data,
                    )  # fmt: skip
                    copier.messages += 1
                elif isinstance(record, Metadata) and record.name != METADATA_RECORD:
                    copier.writer.add_metadata(record.name, record.metadata)
                    copier.metadata += 1
                elif isinstance(record, Footer):
                    complete = True
        except LogFileError:
            raise
        except Exception as err:  # the cut: truncated record, bad magic, bad chunk, ...
            stopped_by = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
    if not started:
        raise LogFileError(f"{str(file)!r} holds no readable MCAP header ({stopped_by})")
    return complete, stopped_by


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_core.logs.recover broken_bag fixed_bag``."""
    parser = argparse.ArgumentParser(
        prog="python -m nehmo_core.logs.recover",
        description="Rewrite the readable part of a damaged bag (or .mcap file) into a new bag.",
    )
    parser.add_argument("src", help="the damaged bag directory or .mcap file (left untouched)")
    parser.add_argument("dst", help="the bag directory to write")
    parser.add_argument("--force", action="store_true", help="replace an existing bag at dst")
    args = parser.parse_args(argv)
    try:
        report = recover(args.src, args.dst, overwrite=args.force)
    except NehmoError as err:
        print(f"recover: error: {err}", file=sys.stderr)
        return 1
    except OSError as err:
        print(f"recover: error: cannot read {args.src} or write {args.dst}: {err}", file=sys.stderr)
        return 1
    state = "complete file" if report.complete else f"cut found ({report.stopped_by})"
    print(
        f"recover: {report.messages} messages on {report.channels} channels "
        f"({report.schemas} schemas, {report.metadata} metadata records) written to "
        f"{args.dst}; {state}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
