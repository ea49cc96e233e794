"""Error messages as one line (console entry points print one line, never a traceback)."""

from __future__ import annotations

from nehmo_core.errors import one_line

__all__ = ["one_line"]
