"""The pages that ``test_docs.py`` and ``test_docs_commands.py`` check (the README and
``docs/``), parsed once: fenced code blocks, the prose with the blocks blanked, inline code.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PAGES = [README, *sorted(DOCS.rglob("*.md"))]


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
INLINE_CODE = re.compile(r"(`+)((?:(?!\n\s*\n)[^`])+?)\1")  # within a paragraph


@dataclass(frozen=True)
class Block:
    """A fenced code block: its page, the line of its first content line, language, lines."""

    page: Path
    line: int
    lang: str
    lines: tuple[str, ...]


def _rel(page: Path) -> str:
    return str(page.relative_to(ROOT))


def _parse(page: Path) -> tuple[list[Block], list[tuple[int, str]]]:
    """The page's fenced blocks, and its prose lines (number, text) outside them."""
    blocks: list[Block] = []
    prose: list[tuple[int, str]] = []
    fence: str | None = None
    lang = ""
    start = 0
    body: list[str] = []
    for number, line in enumerate(page.read_text().splitlines(), 1):
        stripped = line.strip()
        if fence is None:
            match = re.match(r"^(```+|~~~+)\s*([\w+-]*)", stripped)
            if match:
                fence, lang, start, body = match.group(1), match.group(2).lower(), number + 1, []
            else:
                prose.append((number, line))
        elif stripped.startswith(fence) and stripped.strip(fence[0]) == "":
            blocks.append(Block(page, start, lang, tuple(body)))
            fence = None
        else:
            body.append(line)
    assert fence is None, f"{_rel(page)}:{start - 1}: code block is never closed"
    return blocks, prose


PARSED = {page: _parse(page) for page in PAGES}


def _prose_text(page: Path) -> str:
    """The page with its code blocks blanked (line numbers kept)."""
    lines = [""] * len(page.read_text().splitlines())
    for number, line in PARSED[page][1]:
        lines[number - 1] = line
    return "\n".join(lines)


PROSE = {page: _prose_text(page) for page in PAGES}


def _line(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def _inline_spans(page: Path) -> list[tuple[int, str]]:
    """``(line, content)`` of every inline code span, a span over two lines joined by a space."""
    text = PROSE[page]
    return [
        (_line(text, m.start()), " ".join(m.group(2).split())) for m in INLINE_CODE.finditer(text)
    ]


def _find_spec(name: str) -> object | None:
    """The module spec of ``name``, or None (also when a parent package is missing)."""
    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
