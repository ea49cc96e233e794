"""``docs/settings.md``: every planner setting by group, written from the declarations.

    ./run python -m nehmo_core.planning.settings.reference docs/settings.md

A test checks that the page is current, so the reference never drifts from the code.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

from nehmo_core.planning.settings.planner import PAPER_OPT, PRESETS, PlannerSettings

__all__ = ["markdown", "write_generated"]

INTRO = """\
# Planner settings

Written by `python -m nehmo_core.planning.settings.reference docs/settings.md` from the settings
dataclasses (`nehmo_core/nehmo_core/planning/settings/`); do not edit by hand.

Every setting is named `group.field`. The same name is used in Python
(`PlannerSettings().override({"hold.bound": 1.0})`), on the command line
(`nehmo evaluate ... --planner-setting hold.bound=1.0`), as a node parameter
(`--ros-args -p hold.bound:=1.0`) and in `nehmo_ros/config/arm_planner.yaml` (nested by group).
A value that breaks its rule is refused with the setting's name, the rule and the value; a flat
name of an earlier release (`hold_bound`) is refused with the name that replaced it.

Groups: `opt` (the paper's problem Opt), `margins`, `solver`, `fail_safe`, and one group per
stage beyond the paper (`hold`, `exact_guard`, `contact`, `actuator`, `silent_watch`,
`self_clearance`, `escape`; what each stage does: [architecture.md](architecture.md),
[planning.md](planning.md)).
"""


def _value(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, tuple):
        return ", ".join(f"{x:g}" for x in v)
    return f"{v:g}" if isinstance(v, float) else str(v)


def _cell(text: str) -> str:
    """``text`` fit for a Markdown table cell (a ``|`` would end the cell)."""
    return text.replace("|", "\\|")


def markdown() -> str:
    """The page's text."""
    out = [INTRO]
    presets = ", ".join(f"`{name}`" for name in PRESETS)
    out.append(f"\n## Presets\n\n{presets}. What `paper` (the `nehmo_paper` rows) changes:\n\n")
    out.extend(f"- `{k}` = {_value(v)}\n" for k, v in PAPER_OPT.items())
    for g in fields(PlannerSettings):
        group = getattr(PlannerSettings(), g.name)
        doc = (type(group).__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        doc = doc.replace("``", "`")
        out.append(f"\n## `{g.name}`\n\n{doc}\n\n| setting | default | unit | rule | meaning |\n")
        out.append("|---|---|---|---|---|\n")
        for f in fields(group):
            rule = f.metadata["rule"]
            out.append(
                f"| `{g.name}.{f.name}` | {_value(getattr(group, f.name))} | {rule.unit} "
                f"| {_cell(rule.describe())} | {_cell(rule.doc)} |\n"
            )
    return "".join(out)


def write_generated(
    module: str, what: str, render: Callable[[], str], argv: list[str] | None = None
) -> None:
    """The command line of a module that writes a generated file: ``python -m MODULE PATH``."""
    parser = argparse.ArgumentParser(prog=f"python -m {module}", description=f"write {what}")
    parser.add_argument("path", type=Path, help="the file to write")
    Path(parser.parse_args(argv).path).write_text(render())


def main(argv: list[str] | None = None) -> None:
    write_generated(
        __spec__.name, "the planner settings reference (docs/settings.md)", markdown, argv
    )


if __name__ == "__main__":
    main()
