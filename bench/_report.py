"""Shared by the node-suite benches: the machine line and writing ``<stem>.json``/``.md``."""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any


def machine_at_end(extra: str = "") -> str:
    """Architecture, cores, load average now (the end of a run) and Python version."""
    load = os.getloadavg()
    return (
        f"{platform.machine()}, {os.cpu_count()} cores, load average {load[0]:.1f} at the end,"
        f" python {platform.python_version()}{extra}"
    )


def write_report(
    directory: Path, stem: str, result: dict[str, Any], markdown: Callable[[dict[str, Any]], str]
) -> str:
    """Write ``result`` as JSON and its markdown next to it; return the markdown."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{stem}.json").write_text(json.dumps(result, indent=1) + "\n")
    text = markdown(result)
    (directory / f"{stem}.md").write_text(text)
    return text
