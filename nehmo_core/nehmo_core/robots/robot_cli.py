"""``nehmo robot``: check a URDF as an arm, and describe it so NeHMO can load it by name.

    nehmo robot check path/to/arm.urdf [--tip LINK]
    nehmo robot add path/to/arm.urdf --name NAME --dir ROBOTS [--tip LINK] [--srdf FILE]

``check`` prints the chain (joints, limits, speed bounds, links with collision geometry, what is
ignored) and exits 0, or prints one line naming what is missing and exits 2. ``add`` runs the
same check and writes ``ROBOTS/NAME/robot.yaml`` with keypoints for its learned distances
(:func:`default_keypoints`); with ``NEHMO_ROBOTS=ROBOTS`` the robot then loads by name in cells,
task generation and the tools, and ``nehmo pair build NAME OTHER`` makes its pair models.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
from pathlib import Path
from typing import Any

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots.descriptions import ENV, robot_names, write_description
from nehmo_core.robots.loader import robot_from_urdf
from nehmo_core.robots.model import RobotModel
from nehmo_core.robots.urdf_check import check_urdf

__all__ = ["add_arguments", "default_keypoints", "run"]

KEYPOINT_SPACING = 0.12
"""[m] Largest gap between keypoints along a link (more are placed between two origins)."""


def default_keypoints(robot: RobotModel) -> tuple[list[str], list[list[Any]]]:
    """Keypoints for a robot's learned distances: the chain's link origins, root to tip, that
    are apart (more than 1 cm, in some configuration) from the previous one kept, and points
    between consecutive ones at most :data:`KEYPOINT_SPACING` apart. A hand wider than its
    flange axis needs ``keypoint_points`` added by hand (see the Panda's description)."""
    import numpy as np
    import torch

    from nehmo_core.geometry.kinematics import ArmKinematics

    kin = ArmKinematics(robot)
    rng = np.random.default_rng(0)
    lo, hi = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
    q = torch.from_numpy(np.vstack([np.zeros(robot.dof), rng.uniform(lo, hi, (16, robot.dof))]))
    with torch.no_grad():
        tf = kin.link_transforms(q)
    kept: list[str] = []
    for name in tf:  # root to tip
        p = tf[name][:, :3, 3].numpy()
        if not kept or np.linalg.norm(p - tf[kept[-1]][:, :3, 3].numpy(), axis=1).max() > 0.01:
            kept.append(name)
    segments: list[list[Any]] = []
    for a, b in itertools.pairwise(kept):
        gap = float(np.linalg.norm(tf[a][0, :3, 3] - tf[b][0, :3, 3]))
        if (k := int(gap // KEYPOINT_SPACING)) > 0:
            segments.append([a, b, k])
    return kept, segments


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
    robot = robot_from_urdf(args.name, args.urdf, report.tip, args.srdf)
    keypoints, segments = default_keypoints(robot)
    from nehmo_core.pairs.reach import horizontal_reach

    reach = round(horizontal_reach(robot), 4)
    facts = {"keypoints": keypoints, "keypoint_segments": segments, "reach_m": reach}
    out = write_description(args.dir, args.name, args.urdf, report.tip, args.srdf, facts)
    print(report.summary())
    print(f"  keypoints: {', '.join(keypoints)} (+{sum(k for *_, k in segments)} between them)")
    print(f"  reach: {reach:.3f} m (horizontal, collision geometry)")
    print(f"wrote {out}; load it by name with {ENV}={args.dir.resolve()}{os.pathsep}...")
    return 0
