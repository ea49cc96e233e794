"""Shared by the node-suite benches: the machine line and writing ``<stem>.json``/``.md``."""

from __future__ import annotations

import json
import os
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any


def cpu_model() -> str:
    """The CPU's model name (from ``/proc/cpuinfo``), or the architecture where it is not at hand:
    timings from different CPUs are not comparable."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_at_end(extra: str = "") -> str:
    """Architecture, CPU model, cores, load average now (the end of a run) and Python version."""
    load = os.getloadavg()
    return (
        f"{platform.machine()} ({cpu_model()}), {os.cpu_count()} cores, load average "
        f"{load[0]:.1f} at the end, python {platform.python_version()}{extra}"
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
