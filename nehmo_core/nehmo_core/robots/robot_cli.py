"""``nehmo robot``: check a URDF as an arm, and describe it so NeHMO can load it by name.

    nehmo robot check path/to/arm.urdf [--tip LINK]
    nehmo robot add path/to/arm.urdf --name NAME --dir ROBOTS [--tip LINK] [--srdf FILE]

``check`` prints the chain (joints, limits, speed bounds, links with collision geometry, what is
ignored) and exits 0, or prints one line naming what is missing and exits 2. ``add`` runs the
same check and writes ``ROBOTS/NAME/robot.yaml``; with ``NEHMO_ROBOTS=ROBOTS`` the robot then
loads by name in cells, task generation and the tools (pair models for it are not built yet).
"""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots.descriptions import ENV, robot_names, write_description
from nehmo_core.robots.urdf_check import check_urdf

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="robot_command", required=True, metavar="ACTION")
    check = sub.add_parser(
        "check",
        help="check a URDF as an arm: serial chain, limits, speed bounds, collision geometry",
        description="check a URDF as an arm: serial chain, limits, speed bounds, collision "
        "geometry on every moving link, mesh files",
    )
    add = sub.add_parser(
        "add",
        help="check a URDF and write its robot description (robot.yaml) into a folder",
        description="check a URDF and write DIR/NAME/robot.yaml; name DIR in NEHMO_ROBOTS to "
        "load the robot by name",
    )
    for p in (check, add):
        p.add_argument("urdf", type=Path, help="the URDF file")
        p.add_argument("--tip", help="the arm's last link (default: the one longest chain)")
    add.add_argument("--name", required=True, help="the robot's name (letters, digits, _)")
    add.add_argument("--dir", type=Path, required=True, help="the folder of robot descriptions")
    add.add_argument("--srdf", type=Path, help="an SRDF with the disabled self-collision pairs")


def run(args: argparse.Namespace) -> int:
    report = check_urdf(args.urdf, args.tip)
    if args.robot_command == "check":
        print(report.summary())
        return 0
    if not re.fullmatch(r"[a-z][a-z0-9_]*", args.name):
        raise InvalidValueError("--name", "must be lower-case letters, digits and _", args.name)
    if args.name in robot_names():
        raise InvalidValueError("--name", "must not name a robot that exists", args.name)
    out = write_description(args.dir, args.name, args.urdf, report.tip, args.srdf)
    print(report.summary())
    print(f"wrote {out}; load it by name with {ENV}={args.dir.resolve()}{os.pathsep}...")
    return 0
