"""The arm_planner's parameter file, written from the node's parameter declarations.

``nehmo_ros/config/arm_planner.yaml`` is this module's output (a test checks that it is):

    ./run python -m nehmo_ros.param_file nehmo_ros/config/arm_planner.yaml

Planner settings nest by group, so ``fail_safe: {slack: 0.005}`` sets the parameter
``hold.bound`` (ROS 2 joins nested keys of a parameter file with dots).
"""

from __future__ import annotations

import math
from typing import Any

from nehmo_core.planning.settings.reference import write_generated
from nehmo_ros.arm_planner import PARAMS
from nehmo_ros.node_support import Param

__all__ = ["parameter_file"]

HEADER = """\
# Default parameters of the arm_planner node (use with `--ros-args --params-file <this file>`).
# Written by `python -m nehmo_ros.param_file PATH` from the node's declarations: do not edit.
# `arm_id` and `cell` have no defaults: each planner gets its own arm_id, and all planners and
# the bridge share one cell (a shipped name such as dual_ur5, or a cell YAML path).
# Planner settings are grouped as in PlannerSettings (docs/settings.md).
/**:
  ros__parameters:
"""
REQUIRED = ("arm_id", "cell")


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f"'{v}'" if v == "" else v
    if isinstance(v, float) and math.isinf(v):
        return ".inf" if v > 0 else "-.inf"
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(v)


def _line(indent: int, key: str, p: Param) -> str:
    text = f"{' ' * indent}{key}: {_value(p.default)}"
    return f"{text:<33} # {p.description}\n"


def parameter_file() -> str:
    """The YAML text: the node's own parameters, then one block per settings group."""
    out = [HEADER]
    groups: dict[str, list[tuple[str, Param]]] = {}
    for name, p in PARAMS.items():
        if name in REQUIRED:
            continue
        group, _, key = name.rpartition(".")
        if group:
            groups.setdefault(group, []).append((key, p))
        else:
            out.append(_line(4, name, p))
    for group, items in groups.items():
        out.append(f"    {group}:\n")
        out.extend(_line(6, key, p) for key, p in items)
    return "".join(out)


def main(argv: list[str] | None = None) -> None:
    """Write the file to the path given (pybullet's banner on stdout cannot end up in it)."""
    what = "the arm_planner parameter file from the node's declarations"
    write_generated("nehmo_ros.param_file", what, parameter_file, argv)


if __name__ == "__main__":
    main()
