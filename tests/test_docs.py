"""The README and ``docs/`` stay true to the code: links, module names, the snippet, the pages.

A page that names a module or a file that no longer exists fails here, with the page, the line
and the stale text:

* every relative link (and its ``#anchor`` on a Markdown page) resolves;
* every dotted ``nehmo_core.…`` / ``nehmo_ros.…`` / ``sim_bridge.…`` name in backticks, and
  every import of a ``python`` block, resolves to a module or a module's attribute;
* the README's planning snippet runs and prints a joint-velocity command;
* the README stays a front page (≤ 200 lines), ``docs/index.md`` links every page, and every
  page starts with a title.

The commands on these pages: ``test_docs_commands.py``.
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import importlib.util
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest
from _docs_pages import (
    DOCS,
    INLINE_CODE,
    LINK,
    PAGES,
    PARSED,
    PROSE,
    README,
    Block,
    _find_spec,
    _inline_spans,
    _line,
    _parse,
    _rel,
)

README_MAX_LINES = 200
README_SECTIONS = (
    "Prerequisites",
    "Quick start",
    "Planning for one arm",
    "Running the node suite",
    "Layout",
    "Results on fresh seeds",
    "Limitations",
    "Documentation",
)


DOTTED = re.compile(r"(?<![\w./-])(?:nehmo_core|nehmo_ros|sim_bridge)(?:\.[A-Za-z_]\w*)+")


def test_readme_is_a_front_page() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
    )
    headings = [line for line in lines if line.startswith("## ")]
    for section in README_SECTIONS:
        assert f"## {section}" in headings, f"README.md lacks the section ## {section}"


def test_index_links_every_page() -> None:
    index = DOCS / "index.md"
    linked = {
        (index.parent / target.split("#")[0]).resolve()
        for target in LINK.findall(index.read_text())
        if "://" not in target
    }
    pages = {p.resolve() for p in DOCS.rglob("*.md")} - {index.resolve()}
    missing = sorted(_rel(p) for p in pages - linked)
    assert not missing, f"docs/index.md does not link {missing}"


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown page."""
    seen: dict[str, int] = {}
    out = set()
    for _, line in PARSED[page][1] if page in PARSED else _parse(page)[1]:
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not match:
            continue
        slug = re.sub(r"[^\w\- ]", "", match.group(1).lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        out.add(slug if count == 0 else f"{slug}-{count}")
    return out


def test_relative_links_resolve() -> None:
    broken = []
    for page in PAGES:
        # inline code blanked, so that link syntax inside it does not count
        text = INLINE_CODE.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), PROSE[page])
        for match in LINK.finditer(text):
            target = match.group(1)
            if re.match(r"^[a-z]+:", target):
                continue  # http(s), mailto
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            where = f"{_rel(page)}:{_line(text, match.start())}: link ({target})"
            if not dest.exists():
                broken.append(f"{where}: {path} does not exist")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{where}: {dest.name} has no heading #{anchor}")
    assert not broken, "broken links:\n" + "\n".join(broken)


def _resolve(dotted: str) -> str | None:
    """Why ``dotted`` names no module or module attribute (None: it does)."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        name = ".".join(parts[:i])
        if _find_spec(name) is not None:
            break
    else:
        return f"no module {parts[0]}"
    obj: object = importlib.import_module(name)
    for attr in parts[i:]:
        if not hasattr(obj, attr):
            return f"{name} has no submodule or attribute {attr}"
        obj = getattr(obj, attr)
        name = f"{name}.{attr}"
    return None


def _python_imports(block: Block) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every import in a python block."""
    tree = ast.parse("\n".join(block.lines))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [(block.line + node.lineno - 1, f"{node.module}.{a.name}") for a in node.names]
        elif isinstance(node, ast.Import):
            out += [(block.line + node.lineno - 1, a.name) for a in node.names]
    return out


def test_module_names_resolve() -> None:
    names: list[tuple[Path, int, str]] = []
    for page, (blocks, _) in PARSED.items():
        for number, span in _inline_spans(page):
            names += [(page, number, m) for m in DOTTED.findall(span)]
        for block in blocks:
            if block.lang in {"python", "py"}:
                names += [(page, n, name) for n, name in _python_imports(block)]
    assert any(name.startswith("nehmo_core.") for _, _, name in names)
    stale = [
        f"{_rel(page)}:{number}: `{name}`: {why}"
        for page, number, name in names
        if (why := _resolve(name)) is not None
    ]
    assert not stale, "module names that do not resolve:\n" + "\n".join(stale)


def _readme_snippet() -> Block:
    blocks, _ = PARSED[README]
    text = README.read_text().splitlines()
    start = next(i for i, line in enumerate(text, 1) if line.startswith("## Planning for one arm"))
    end = next(
        (i for i, line in enumerate(text, 1) if i > start and line.startswith("## ")), len(text)
    )
    found = [b for b in blocks if b.lang == "python" and start < b.line < end]
    assert found, "README.md: no ```python block under ## Planning for one arm"
    return found[0]


def test_readme_planning_snippet_prints_a_command(tmp_path: Path) -> None:
    snippet = _readme_snippet()
    code = "\n".join(snippet.lines)
    assert len(snippet.lines) <= 15, f"README.md:{snippet.line}: the snippet should stay short"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    where = f"README.md:{snippet.line}: the planning snippet"
    assert proc.returncode == 0, f"{where} failed:\n{proc.stderr[-3000:]}"
    vectors = [
        [float(x) for x in body.replace(",", " ").split()]
        for body in re.findall(r"\[([-+0-9.eE\s,]+)\]", proc.stdout)
    ]
    commands = [v for v in vectors if len(v) == 6 and all(math.isfinite(x) for x in v)]
    assert commands, f"{where} printed no 6-joint velocity command:\n{proc.stdout[-2000:]}"
    assert all(abs(x) <= 0.5 + 1e-9 for x in commands[0]), f"{where}: beyond ū: {commands[0]}"


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_pages_have_a_title(page: Path) -> None:
    first = page.read_text().splitlines()[0]
    assert first.startswith("# "), f"{_rel(page)}:1: a page starts with a # title"
