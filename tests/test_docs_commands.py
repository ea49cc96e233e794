"""The commands of the README and ``docs/`` exist and answer ``--help``.

A page that names a command that no longer exists fails here, with the page, the line and the
stale text:

* every command line of a ``bash``/``sh``/``console`` block, and every ``./run …``,
  ``python -m …``, ``nehmo …``, ``orchestrate …`` or ``bench/*.py`` command in backticks,
  starts with an entry point that exists;
* each distinct CLI (``nehmo <sub>``, ``orchestrate <sub>``, ``bench/*.py``, the project's
  ``python -m`` modules) answers ``--help`` with exit status 0.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from _docs_pages import PAGES, PARSED, README, ROOT, _find_spec, _inline_spans, _rel

VENV_BIN = Path(sys.executable).parent  # .venv/bin under ./run


# First words of command lines that a test cannot run, and why.
NOT_RUNNABLE = {
    "source": "sources a colcon install space, which exists only after a build",
    "cd": "changes the shell's directory; nothing to check",
    "export": "sets a variable of the shell; nothing to check",
    "docker": "needs a Docker engine (none in CI)",
    "colcon": "builds the ROS workspace (minutes; tests/ros/test_colcon_workspace.py does it)",
    "ros2": "the ROS 2 CLI is not on PyPI; it exists only in the docker image",
}
# The project's packages: their console scripts and modules are asked for --help.
PROJECT_PACKAGES = ("nehmo_core", "nehmo_ros", "sim_bridge")
SHELL_BLOCKS = {"bash", "sh", "shell", "console"}
SUBCOMMAND = re.compile(r"^[a-z][a-z0-9_]*$")
ENV_ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")


INLINE_COMMAND = re.compile(
    r"^(?:[A-Z_][A-Z0-9_]*=\S+\s+)*(?:\./run|python -m|nehmo|orchestrate)\s|^bench/\w+\.py(?:\s|$)"
)


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
