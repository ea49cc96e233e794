"""Error messages as one line (console entry points print one line, never a traceback)."""

from __future__ import annotations

__all__ = ["one_line"]


def one_line(err: BaseException, limit: int = 600) -> str:
    """``err`` as one line (multi-line messages joined, very long ones shortened)."""
    text = " ".join(part.strip() for part in str(err).splitlines() if part.strip())
    text = text or type(err).__name__
    return text if len(text) <= limit else text[: limit - 4] + " ..."
