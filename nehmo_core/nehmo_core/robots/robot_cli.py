"""``nehmo robot``: check that a URDF describes an arm NeHMO can plan for.

    nehmo robot check path/to/arm.urdf [--tip LINK]

Prints the chain (joints, limits, speed bounds, links with collision geometry, what is ignored)
and exits 0, or prints one line naming what is missing and exits 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

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
    check.add_argument("urdf", type=Path, help="the URDF file")
    check.add_argument("--tip", help="the arm's last link (default: the one longest chain)")


def run(args: argparse.Namespace) -> int:
    report = check_urdf(args.urdf, args.tip)
    print(report.summary())
    return 0
