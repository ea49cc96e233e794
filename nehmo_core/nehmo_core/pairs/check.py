"""The first stage of a pair build: what the robots are, whether the mirror map holds, and the
pair manifest that registers the pair in its model folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from nehmo_core.errors import ModelFileError, NehmoError
from nehmo_core.robots import registry

__all__ = ["MIRROR_TOLERANCE", "judge_mirror", "pair_names", "robot_figures", "write_manifest"]

MIRROR_TOLERANCE = 0.002
"""[m] Largest mean change of the exact pair distance under the mirror maps, within 0.3 m of
contact, for which a build trains ``bc+sym`` (the UR5's meshes: 0.7 mm); above it, ``bc``."""


def pair_names(robot_1: str, robot_2: str, tag: str = "any") -> tuple[str, ...]:
    """The pair (and, for two robots, the swapped game) a build makes: ``A_B_<tag>`` first
    (``tag`` is ``any`` unless a build covers a part of the base distances, e.g. ``far``)."""
    first = f"{robot_1}_{robot_2}_{tag}"
    return (first,) if robot_1 == robot_2 else (first, f"{robot_2}_{robot_1}_{tag}")


def robot_figures(name: str, reach_samples: int, seed: int) -> dict[str, Any]:
    """A robot's joint count, mirror map (or why it has none) and reach; one clear error when
    it cannot have pair models (a moving link without collision geometry, from the loader; no
    base-yaw first joint). The learned distance's keypoints are placed in the collision geometry
    by the distance stage, so the description needs none."""
    from nehmo_core.geometry.symmetry import find_mirror_map
    from nehmo_core.pairs.reach import horizontal_reach
    from nehmo_core.planning.models.pair_frame import base_yaw_joint
    from nehmo_core.robots.loader import load_robot

    robot = load_robot(name)
    if base_yaw_joint(robot) is None:
        raise ModelFileError(
            f"robot {name!r}: its first joint does not turn the arm about the base's vertical "
            "axis, so one model cannot serve every layout"
        )
    try:
        mirror = find_mirror_map(robot)
        found: dict[str, Any] = {"sign": list(mirror.sign), "offset": list(mirror.offset)}
    except NehmoError as exc:
        found = {"none": str(exc)}
    reach = horizontal_reach(robot, reach_samples, seed)
    return {"dof": robot.dof, "mirror_map": found, "reach_m": reach}


def judge_mirror(result: dict[str, Any]) -> dict[str, Any]:
    """The mirror check's result with the variant it decides and why."""
    compared = result.get("compared_states", result["near_contact_states"])
    symmetric = compared > 0 and result["mean_abs_diff_near_m"] <= MIRROR_TOLERANCE
    return {
        **result,
        "variant": "bc+sym" if symmetric else "bc",
        "why": (
            f"mean |d(x) - d(f(x))| over {compared} states within "
            f"{result.get('compared_within_m', 0.3):.2f} m of contact "
            f"{1000 * result['mean_abs_diff_near_m']:.1f} mm "
            f"{'<=' if symmetric else '>'} {1000 * MIRROR_TOLERANCE:.0f} mm: "
            + ("the mirror map holds; bc+sym" if symmetric else "no exact mirror map; bc")
        ),
    }


def write_manifest(
    models: Path,
    robots: tuple[str, str],
    base_range: tuple[float, float],
    variant: str,
    tag: str = "any",
) -> Path:
    """``<pair>.pairs.yaml`` in ``models``: the pair (and its swapped game for two robots)."""
    names = pair_names(*robots, tag)
    entries: list[dict[str, Any]] = [
        {
            "name": names[0],
            "robots": list(robots),
            "conditioned": True,
            "base_range": [float(base_range[0]), float(base_range[1])],
            "values": [variant],
        }
    ]
    if len(names) == 2:
        entries.append(
            {
                "name": names[1],
                "robots": [robots[1], robots[0]],
                "swapped": names[0],
                "values": [variant],
            }
        )
    path = models / f"{names[0]}{registry.MANIFEST_SUFFIX}"
    header = (
        f"# Written by nehmo pair build {robots[0]} {robots[1]}: the pair's models are the "
        "files beside it.\n"
    )
    path.write_text(header + yaml.safe_dump({"pairs": entries}, sort_keys=False))
    return path
