"""Where pair value models come from: the planner kinds that solve Opt and the variant each
uses, and sources written ``[KIND=]SOURCE`` (a shipped pair name, ``synthetic``, a training run
directory or a ``.safetensors`` file), as the ``--value-model`` option and the planner node's
``model`` parameter take them; snapshots of path sources for a reproducible evaluation. The
registry that loads them: :mod:`nehmo_core.planning.models.registry`.
"""

from __future__ import annotations

import hashlib
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from nehmo_core.errors import InvalidValueError, ModelFileError
from nehmo_core.hjr.model_files import OPTIONAL_VALUE_FUNCTIONS, SHIPPED_VALUE_FUNCTIONS

__all__ = [
    "OPT_KINDS",
    "SHIPPED",
    "SYNTHETIC",
    "ValueModelSource",
    "model_sources",
    "parse_value_models",
    "snapshot_value_models",
]

OPT_KINDS: dict[str, str] = {
    "nehmo": "bc+sym",
    "nehmo_paper": "bc+sym",
    "nehmo_no_sym": "bc",
    "opt_deepreach": "deepreach",
    "nehmo_wrap": "bc+sym",
}
"""Planner kinds solving problem Opt, with the value-function variant each row uses."""
SHIPPED = "shipped"
"""The ``model`` text naming the shipped value functions of the cell's robot pairs."""
SYNTHETIC = "synthetic"


@dataclass(frozen=True)
class ValueModelSource:
    """Where pair value models come from, for one Opt kind (``kind``) or every one (None)."""

    source: str
    kind: str | None = None

    def __str__(self) -> str:
        return self.source if self.kind is None else f"{self.kind}={self.source}"


def parse_value_models(items: Sequence[str]) -> tuple[ValueModelSource, ...]:
    """Parse ``[KIND=]SOURCE`` strings (see the module docstring)."""
    out = []
    for item in items:
        head, sep, tail = item.partition("=")
        if sep and head in OPT_KINDS:
            out.append(ValueModelSource(tail, head))
        elif sep and "/" not in head and "." not in head:
            raise InvalidValueError(
                "value model", f"must be [KIND=]SOURCE with KIND in {sorted(OPT_KINDS)}", item
            )
        else:
            out.append(ValueModelSource(item))
        if not out[-1].source:
            raise InvalidValueError("value model", "must name a source after '='", item)
    return tuple(out)


def _weights_file(source: Path) -> Path:
    """The weights a path source loads (as :func:`load_value_function` does)."""
    if source.is_dir():
        model = source / "model.safetensors"
        return model if model.exists() else source / "checkpoint.safetensors"
    return source


def snapshot_value_models(
    sources: Sequence[ValueModelSource], directory: str | Path
) -> tuple[ValueModelSource, ...]:
    """Copy every path source's weights (and JSON sidecar) under ``directory``.

    A training run rewrites its checkpoint in place; evaluating a snapshot makes every worker
    (and every later re-run) use the same weights. Shipped names and ``synthetic`` pass through.
    """
    out = []
    for s in sources:
        named = s.source in SHIPPED_VALUE_FUNCTIONS or s.source in OPTIONAL_VALUE_FUNCTIONS
        if s.source == SYNTHETIC or named:
            out.append(s)
            continue
        src = _weights_file(Path(s.source))
        if not src.is_file():
            raise ModelFileError(f"value model {s.source!r}: no weights file {src}")
        digest = hashlib.sha256(src.read_bytes()).hexdigest()[:12]
        dest = Path(directory) / f"{Path(s.source).name}_{digest}" / src.name
        dest.parent.mkdir(parents=True, exist_ok=True)
        sidecar = src.with_suffix(".json")
        if sidecar.exists():
            shutil.copy2(sidecar, dest.with_suffix(".json"))
        shutil.copy2(src, dest)
        out.append(ValueModelSource(str(dest), s.kind))
    return tuple(out)


def model_sources(model: str) -> tuple[ValueModelSource, ...]:
    """The value-model sources a comma-separated text names (none for ``shipped``).

    The text form is what the planner node's ``model`` parameter and the orchestrator take:
    ``shipped`` (or empty), ``synthetic``, or ``[KIND=]SOURCE`` items separated by commas.
    """
    text = model.strip()
    if text in ("", SHIPPED):
        return ()
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise InvalidValueError(
            "model", "must be 'shipped', 'synthetic' or [KIND=]PATH items", model
        )
    return parse_value_models(items)
