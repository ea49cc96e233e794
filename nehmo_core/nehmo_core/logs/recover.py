"""Recover an MCAP log whose writer died (SIGKILL, power loss, disk full).

Seeking readers reject a file without its summary and footer. This module reads the damaged
file sequentially, without seeking, keeps every schema, channel, message and metadata record up
to the point where the data stops making sense (a truncated record, or a chunk whose checksum
fails, e.g. one torn by a write that failed on a full disk: its length field then runs into the
records after it), and rewrites them into a finished file::

    python -m nehmo_core.logs.recover broken.mcap fixed.mcap

The damaged file is only read. An existing output file is not overwritten unless asked
(``--force``), so swapping the two arguments cannot destroy a log.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from nehmo_core.errors import NehmoError
from nehmo_core.logs.reader import LogFileError

if TYPE_CHECKING:
    from mcap.records import Channel
    from mcap.writer import Writer


@dataclass(frozen=True)
class RecoveryReport:
    """What `recover` kept; `stopped_by` names why reading stopped ("" for a clean end)."""

    messages: int
    channels: int
    schemas: int
    metadata: int
    complete: bool
    stopped_by: str


def recover(src: str | Path, dst: str | Path, overwrite: bool = False) -> RecoveryReport:
    """Rewrite every readable record of `src` into a finished MCAP file `dst` (an existing
    `dst` is an error unless `overwrite`)."""
    from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise LogFileError(f"log {str(src)!r} does not exist")
    if src.resolve() == dst.resolve():
        raise LogFileError("recover writes a new file: give an output path other than the input")
    if dst.exists() and not overwrite:
        raise LogFileError(
            f"output {str(dst)!r} exists; recover does not overwrite it (remove it, choose "
            "another path or pass --force)"
        )
    if not dst.parent.is_dir():
        raise LogFileError(f"output directory {str(dst.parent)!r} does not exist")

    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    pending_channels: dict[int, Channel] = {}
    n_messages = n_metadata = 0
    complete = False
    stopped_by = ""
    started = False
    with src.open("rb") as stream_in, dst.open("wb") as stream_out:
        writer = Writer(stream_out, compression=CompressionType.NONE)
        try:
            reader = StreamReader(stream_in, validate_crcs=True, record_size_limit=1 << 30)
            for record in reader.records:
                if isinstance(record, Header):
                    writer.start(profile=record.profile, library=record.library)
                    started = True
                elif not started:
                    raise LogFileError(f"{str(src)!r} does not start with an MCAP header")
                elif isinstance(record, Schema) and record.id not in schema_ids:
                    schema_ids[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data
                    )
                elif isinstance(record, Channel) and record.id not in channel_ids:
                    pending_channels[record.id] = record
                elif isinstance(record, Message):
                    channel_id = _channel_id(
                        writer, record.channel_id, pending_channels, channel_ids, schema_ids
                    )
                    if channel_id is None:
                        continue  # a message whose channel record was lost: cannot be typed
                    writer.add_message(
                        channel_id,
                        record.log_time,
                        record.data,
                        record.publish_time,
                        record.sequence,
                    )
                    n_messages += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, record.metadata)
                    n_metadata += 1
                elif isinstance(record, Footer):
                    complete = True
        except LogFileError:
            raise
        except Exception as err:  # the cut: truncated record, bad magic, bad chunk, ...
            stopped_by = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
        if not started:
            raise LogFileError(f"{str(src)!r} holds no readable MCAP header ({stopped_by})")
        for record_id in list(pending_channels):  # channels that never got a message
            _channel_id(writer, record_id, pending_channels, channel_ids, schema_ids)
        writer.finish()
    return RecoveryReport(
        messages=n_messages,
        channels=len(channel_ids),
        schemas=len(schema_ids),
        metadata=n_metadata,
        complete=complete,
        stopped_by=stopped_by,
    )


def _channel_id(
    writer: Writer,
    old_id: int,
    pending: dict[int, Channel],
    channel_ids: dict[int, int],
    schema_ids: dict[int, int],
) -> int | None:
    """New id of channel `old_id`, registering it on first use (after its schema)."""
    if old_id in channel_ids:
        return channel_ids[old_id]
    channel = pending.pop(old_id, None)
    if channel is None:
        return None
    schema_id = schema_ids.get(channel.schema_id, 0)
    channel_ids[old_id] = writer.register_channel(
        channel.topic, channel.message_encoding, schema_id, dict(channel.metadata)
    )
    return channel_ids[old_id]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_core.logs.recover broken.mcap fixed.mcap``."""
    parser = argparse.ArgumentParser(
        prog="python -m nehmo_core.logs.recover",
        description="Rewrite the readable part of a damaged MCAP log into a finished file.",
    )
    parser.add_argument("src", help="the damaged log (left untouched)")
    parser.add_argument("dst", help="the recovered log to write")
    parser.add_argument("--force", action="store_true", help="overwrite an existing dst")
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
