"""Finished-episode records, so an interrupted run can resume (``nehmo evaluate --resume``).

A finished episode leaves ``<bag>.done.json`` beside its bag: a fingerprint of what it ran
(setup or task, row, scenario, planner settings, value models …), its wall time and what it
used. A resumed run reuses the bag of an episode whose record carries the same fingerprint and
whose bag reads back; every other episode runs again (its old record is removed first, so a
bag being rewritten is never vouched for).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from nehmo_core.eval.metrics import EpisodeResult, evaluate_or_error

__all__ = ["fingerprint", "forget", "read_finished", "write_record"]


def _path(log_path: Path) -> Path:
    return log_path.with_name(log_path.name + ".done.json")


def fingerprint(**what: Any) -> str:
    """A digest of what makes an episode the same episode."""
    text = json.dumps(what, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def write_record(log_path: Path, digest: str, wall: float, used: dict[str, Any]) -> None:
    path = _path(log_path)
    tmp = path.with_suffix(".tmp")
    record = {"fingerprint": digest, "wall_seconds": wall, "used": used}
    tmp.write_text(json.dumps(record, default=str) + "\n")
    tmp.replace(path)


def forget(log_path: Path) -> None:
    """Remove the record of an episode about to run again."""
    _path(log_path).unlink(missing_ok=True)


def read_finished(
    log_path: Path, digest: str
) -> tuple[EpisodeResult, float, dict[str, Any]] | None:
    """The result (from its bag), wall time and usage of an episode an earlier run finished
    with the same fingerprint, or None."""
    try:
        record = json.loads(_path(log_path).read_text())
    except (OSError, ValueError):
        return None
    if record.get("fingerprint") != digest:
        return None
    result = evaluate_or_error(log_path)
    if result.outcome == "error":
        return None
    return result, float(record["wall_seconds"]), dict(record["used"])
