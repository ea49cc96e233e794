"""A Foxglove layout for a NeHMO bag or a live run, written for a cell's arms.

``nehmo_ros/config/foxglove_layout.json`` is this module's output for the dual-UR5 cell (a test
checks that it is); for another cell:

    ./run python -m nehmo_ros.foxglove_layout five_ur5 my_layout.json

Import it in Foxglove (Layouts → Import from file) and open a bag written by the recorder (or
connect to a live run through a Foxglove bridge). Panels: a 3D view of every planner's markers
(critical pair coloured by V, goal, mode) in the ``world`` frame; a plot of each arm's smallest
``V``; a plot of the first arm's joint-velocity commands; the planners' modes over time (their
status message); and the raw status of the first arm.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from nehmo_core.errors import NehmoError
from nehmo_core.logs.topics import command_topic, markers_topic, min_value_topic, status_topic
from nehmo_core.robots import load_cell

__all__ = ["foxglove_layout"]


def _path(value: str) -> dict[str, Any]:
    return {"value": value, "enabled": True, "timestampMethod": "receiveTime"}


def foxglove_layout(arm_ids: Sequence[str], joints: int) -> dict[str, Any]:
    """The layout (Foxglove's JSON layout format) for arms ``arm_ids``."""
    first = arm_ids[0]
    config: dict[str, Any] = {
        "3D!markers": {
            "followTf": "world",
            "topics": {markers_topic(a): {"visible": True} for a in arm_ids},
            "scene": {"transforms": {"showLabel": False}},
        },
        "Plot!value": {
            "title": "smallest V per arm [m]",
            "paths": [_path(f"{min_value_topic(a)}.data") for a in arm_ids],
            "showLegend": True,
            "isSynced": True,
        },
        "Plot!commands": {
            "title": f"{first} joint-velocity commands [rad/s]",
            "paths": [_path(f"{command_topic(first)}.data[{j}]") for j in range(joints)],
            "showLegend": True,
            "isSynced": True,
        },
        "StateTransitions!modes": {
            "paths": [_path(f"{status_topic(a)}.message") for a in arm_ids],
            "isSynced": True,
        },
        "RawMessages!status": {"topicPath": status_topic(first), "expansion": "all"},
    }
    layout = {
        "direction": "row",
        "first": "3D!markers",
        "second": {
            "direction": "column",
            "first": "Plot!value",
            "second": {
                "direction": "column",
                "first": "Plot!commands",
                "second": {
                    "direction": "row",
                    "first": "StateTransitions!modes",
                    "second": "RawMessages!status",
                },
            },
            "splitPercentage": 33,
        },
        "splitPercentage": 55,
    }
    return {
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": layout,
    }


def layout_text(cell_name: str) -> str:
    cell = load_cell(cell_name)
    joints = cell.arm(cell.arm_ids[0]).robot.dof
    return json.dumps(foxglove_layout(list(cell.arm_ids), joints), indent=2) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m nehmo_ros.foxglove_layout",
        description="Write a Foxglove layout for a cell's arms (import it in Foxglove).",
    )
    parser.add_argument("cell", help="shipped cell name (dual_ur5, ...) or a cell YAML path")
    parser.add_argument("out", type=Path, help="the layout file to write (.json)")
    args = parser.parse_args(argv)
    try:
        text = layout_text(args.cell)
    except NehmoError as err:
        parser.error(str(err))
    args.out.write_text(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
