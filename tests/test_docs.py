"""The README and ``docs/`` stay true to the code: links, commands, module names, the snippet.

A page that names a command, a module or a file that no longer exists fails here, with the
page, the line and the stale text:

* every relative link (and its ``#anchor`` on a Markdown page) resolves;
* every command line of a ``bash``/``sh``/``console`` block starts with an entry point that
  exists, and each distinct CLI (``nehmo <sub>``, ``orchestrate <sub>``, ``bench/*.py``, the
  project's ``python -m`` modules) answers ``--help`` with exit status 0;
* every dotted ``nehmo_core.…`` / ``nehmo_ros.…`` / ``sim_bridge.…`` name in backticks, and
  every import of a ``python`` block, resolves to a module or a module's attribute;
* the README's planning snippet runs and prints a joint-velocity command;
* the README stays a front page (≤ 200 lines) and ``docs/index.md`` links every page.
"""

from __future__ import annotations

import ast
import importlib
import importlib.metadata
import importlib.util
import json
import math
import os
import re
import shlex
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PAGES = [README, *sorted(DOCS.rglob("*.md"))]
VENV_BIN = Path(sys.executable).parent  # .venv/bin under ./run
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

# The lead engineer writes this page; the index links it already. While it does not exist, links
# to it are tolerated (and only to it); once it exists it is checked like every other page.
PENDING_PAGES = {DOCS / "architecture.md"}

# First words of command lines that a test cannot run, and why.
NOT_RUNNABLE = {
    "source": "sources a colcon install space, which exists only after a build",
    "cd": "changes the shell's directory; nothing to check",
    "export": "sets a variable of the shell; nothing to check",
    "docker": "needs a Docker engine (none in CI)",
    "colcon": "builds the ROS workspace (minutes; tests/test_colcon_workspace.py does it)",
    "ros2": "the ROS 2 CLI is not on PyPI; it exists only in the docker image",
}
# The project's packages: their console scripts and modules are asked for --help.
PROJECT_PACKAGES = ("nehmo_core", "nehmo_ros", "sim_bridge")
SHELL_BLOCKS = {"bash", "sh", "shell", "console"}
SUBCOMMAND = re.compile(r"^[a-z][a-z0-9_]*$")
ENV_ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
DOTTED = re.compile(r"(?<![\w./-])(?:nehmo_core|nehmo_ros|sim_bridge)(?:\.[A-Za-z_]\w*)+")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
INLINE_CODE = re.compile(r"(`+)((?:(?!\n\s*\n)[^`])+?)\1")  # within a paragraph
INLINE_COMMAND = re.compile(
    r"^(?:[A-Z_][A-Z0-9_]*=\S+\s+)*(?:\./run|python -m|nehmo|orchestrate)\s|^bench/\w+\.py(?:\s|$)"
)


@dataclass(frozen=True)
class Block:
    """A fenced code block: its page, the line of its first content line, language, lines."""

    page: Path
    line: int
    lang: str
    lines: tuple[str, ...]


@dataclass(frozen=True)
class Command:
    """One simple command of a shell block, as written, with its tokens."""

    page: Path
    line: int
    text: str
    argv: tuple[str, ...]

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}: `{self.text}`"


@dataclass(frozen=True)
class HelpJob:
    """A CLI to ask for ``--help``: a console script, a module or a script, with leading words."""

    kind: str  # console | module | script
    target: str
    words: tuple[str, ...]

    def name(self) -> str:
        return " ".join([self.target, *self.words, "--help"])


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


def _split_commands(text: str, page: Path, line: int) -> list[Command]:
    """The simple commands of one shell line (split at ``&&``, ``||``, ``;``, ``|``)."""
    lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    try:
        tokens = list(lexer)
    except ValueError as err:
        raise AssertionError(f"{_rel(page)}:{line}: cannot parse `{text}`: {err}") from err
    commands: list[Command] = []
    current: list[str] = []
    for token in [*tokens, ";"]:
        if token in {"&&", "||", ";", "|", "&"}:
            while current and ENV_ASSIGNMENT.match(current[0]):
                current.pop(0)  # VAR=value before a command
            if current:
                commands.append(Command(page, line, text, tuple(current)))
            current = []
        else:
            current.append(token)
    return commands


def _shell_commands() -> list[Command]:
    """Every command of every shell block, continuation lines joined; ``console``: ``$`` lines."""
    out: list[Command] = []
    for page, (blocks, _) in PARSED.items():
        for block in blocks:
            if block.lang not in SHELL_BLOCKS:
                continue
            pending, first = "", 0
            for offset, raw in enumerate(block.lines):
                line = raw.strip()
                if block.lang == "console" and not pending:
                    if not line.startswith("$ "):
                        continue  # output
                    line = line[2:]
                if not pending:
                    first = block.line + offset
                if line.endswith("\\"):
                    pending += line[:-1] + " "
                    continue
                text = (pending + line).strip()
                pending = ""
                if text and not text.startswith("#"):
                    out.extend(_split_commands(text, page, first))
    return out


def _inline_commands() -> list[Command]:
    """Commands in backticks in the prose: ``./run ...``, ``python -m ...``, ``nehmo ...``,
    ``orchestrate ...`` and ``bench/<script>.py ...`` (placeholders such as ``<cmd>`` skipped)."""
    out: list[Command] = []
    for page in PAGES:
        for number, text in _inline_spans(page):
            if "<" in text or not INLINE_COMMAND.match(text):
                continue
            try:
                argv = shlex.split(text)
            except ValueError as err:
                raise AssertionError(
                    f"{_rel(page)}:{number}: cannot parse `{text}`: {err}"
                ) from err
            while argv and ENV_ASSIGNMENT.match(argv[0]):
                argv.pop(0)
            if argv[0].startswith("bench/"):
                argv.insert(0, "python")
            out.append(Command(page, number, text, tuple(argv)))
    return out


COMMANDS = _shell_commands() + _inline_commands()


def _console_script(name: str) -> importlib.metadata.EntryPoint | None:
    found = importlib.metadata.entry_points(group="console_scripts", name=name)
    return next(iter(found), None)


def _find_spec(name: str) -> object | None:
    """The module spec of ``name``, or None (also when a parent package is missing)."""
    try:
        return importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None


def _words(args: tuple[str, ...]) -> tuple[str, ...]:
    """Leading subcommand words (``distance generate``), up to the first flag or argument."""
    words: list[str] = []
    for arg in args:
        if not SUBCOMMAND.match(arg):
            break
        words.append(arg)
    return tuple(words)


def _check(argv: tuple[str, ...], in_venv: bool, jobs: set[HelpJob]) -> str | None:
    """Why ``argv``'s entry point does not exist (None: it does); adds ``--help`` jobs."""
    program, args = argv[0], argv[1:]
    if program == "./run":
        if not args or args[0] == "demo":
            jobs.add(HelpJob("module", "nehmo_ros.demo", ()))
            return None
        if args[0] == "test":
            script = ROOT / "scripts" / "test.sh"
            return None if os.access(script, os.X_OK) else f"{_rel(script)} is not executable"
        return _check(args, True, jobs)
    if program in NOT_RUNNABLE:
        return None
    if program in {"bash", "sh"}:
        if len(args) >= 2 and args[0] == "-c":
            for inner in _split_commands(args[1], README, 0):
                if (why := _check(inner.argv, in_venv, jobs)) is not None:
                    return why
            return None
        return f"`{program}` without -c: nothing to check"
    if program in {"python", "python3"}:
        if in_venv and not (VENV_BIN / program).exists():
            return f"{program} is not in {VENV_BIN}"
        if len(args) >= 2 and args[0] == "-m":
            if _find_spec(args[1]) is None:
                return f"module {args[1]} does not exist"
            if args[1].split(".")[0] in PROJECT_PACKAGES:
                jobs.add(HelpJob("module", args[1], ()))
            return None
        if not args:
            return None  # the interpreter itself
        if not args[0].startswith("-"):
            script = ROOT / args[0]
            if not script.is_file():
                return f"script {args[0]} does not exist"
            if script.parent == ROOT / "bench":
                jobs.add(HelpJob("script", args[0], ()))
            return None
        return "python without a module or a script"
    entry = _console_script(Path(program).name)
    if "/" not in program:
        if entry is not None and entry.value.split(".")[0] in PROJECT_PACKAGES:
            if in_venv and not (VENV_BIN / program).exists():
                return f"{program} is not installed in {VENV_BIN}"
            jobs.add(HelpJob("console", program, _words(args)))
            return None
        if in_venv and (VENV_BIN / program).exists():
            return None  # a tool of the environment (ruff, pytest, ...)
        return f"`{program}` is neither a project command nor in {VENV_BIN}"
    parts = Path(program).parts
    if parts[:2] == ("ros_ws", "install"):
        # <install>/<package>/lib/<package>/<executable>: a console script of that package
        package = parts[2] if len(parts) == 6 else ""
        if not (ROOT / package / "setup.py").is_file() or parts[3:5] != ("lib", package):
            return f"{program} is not an install-space executable of a package of ros_ws/"
        if entry is None or entry.value.split(".")[0] != package:
            return f"{package} declares no executable {parts[-1]}"
        jobs.add(HelpJob("console", parts[-1], ()))
        return None
    return None if (ROOT / program).exists() else f"{program} does not exist"


def _help_jobs() -> tuple[dict[HelpJob, list[str]], list[str]]:
    """The ``--help`` jobs, each with where the docs use it; the stale commands."""
    jobs: dict[HelpJob, list[str]] = {}
    stale = []
    for command in COMMANDS:
        found: set[HelpJob] = set()
        why = _check(command.argv, False, found)
        if why is not None:
            stale.append(f"{command.where()}: {why}")
        for job in found:
            jobs.setdefault(job, []).append(command.where())
    return jobs, stale


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
    for pending in PENDING_PAGES:
        assert pending.resolve() in linked, f"docs/index.md does not link {_rel(pending)}"


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
    pending = {p.resolve() for p in PENDING_PAGES}
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
                if dest not in pending:
                    broken.append(f"{where}: {path} does not exist")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{where}: {dest.name} has no heading #{anchor}")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_command_entry_points_exist() -> None:
    assert COMMANDS, "no shell commands found in README.md or docs/"
    _, stale = _help_jobs()
    assert not stale, "commands whose entry point does not exist:\n" + "\n".join(stale)


# Runs --help jobs in one interpreter, so the imports (torch, pybullet, rclpy) load once.
_HELP_RUNNER = r"""
import contextlib, importlib.metadata, io, json, os, runpy, sys, traceback
jobs, result_file = json.loads(sys.argv[1]), sys.argv[2]
results = []
for job in jobs:
    kind, target, words = job["kind"], job["target"], job["words"]
    buf = io.StringIO()
    code = 0
    path = list(sys.path)
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            sys.argv = [target, *words, "--help"]
            if kind == "console":
                (ep,) = importlib.metadata.entry_points(group="console_scripts", name=target)
                code = ep.load()() or 0
            elif kind == "module":
                runpy.run_module(target, run_name="__main__", alter_sys=True)
            else:
                sys.path.insert(0, os.path.dirname(os.path.abspath(target)))
                runpy.run_path(target, run_name="__main__")
    except SystemExit as exit_:
        code = exit_.code or 0
    except BaseException:
        code = "raised:\n" + traceback.format_exc(limit=5)
    finally:
        sys.path[:] = path
    if code == 0 and not buf.getvalue().strip():
        code = "0 but printed nothing"
    results.append({**job, "code": code, "output": buf.getvalue()[-1500:]})
with open(result_file, "w") as f:
    json.dump(results, f)
"""


def test_documented_clis_answer_help() -> None:
    jobs, _ = _help_jobs()
    assert any(j.target == "nehmo" for j in jobs), "no `nehmo` command found in the docs"
    # two interpreters side by side (2 cores): console scripts and modules, then bench scripts
    ordered = sorted(jobs, key=lambda j: (j.kind, j.target, j.words))
    groups = [
        [j for j in ordered if j.kind != "script"],
        [j for j in ordered if j.kind == "script"],
    ]
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        procs = []
        for n, group in enumerate(g for g in groups if g):
            result_file = Path(tmp) / f"help{n}.json"
            payload = json.dumps(
                [{"kind": j.kind, "target": j.target, "words": j.words} for j in group]
            )
            procs.append(
                (
                    result_file,
                    subprocess.Popen(
                        [sys.executable, "-c", _HELP_RUNNER, payload, str(result_file)],
                        cwd=ROOT,
                        stdout=subprocess.PIPE,
                        stderr=subprocess.STDOUT,
                        text=True,
                    ),
                )
            )
        for result_file, proc in procs:
            try:
                output, _ = proc.communicate(timeout=300)
            except subprocess.TimeoutExpired as err:
                proc.kill()
                output, _ = proc.communicate()
                raise AssertionError(
                    f"--help of the docs' CLIs took > 300 s:\n{output[-3000:]}"
                ) from err
            assert result_file.exists(), f"the --help runner failed:\n{output[-3000:]}"
            for r in json.loads(result_file.read_text()):
                if r["code"] != 0:
                    job = HelpJob(r["kind"], r["target"], tuple(r["words"]))
                    used = jobs[job]
                    failures.append(
                        f"`{job.name()}` exited {r['code']} (used at {'; '.join(used[:3])}):\n"
                        f"{r['output']}"
                    )
    assert not failures, "documented commands that fail --help:\n" + "\n".join(failures)


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
