"""Robots as description files: a URDF (+ SRDF) and a small ``robot.yaml`` beside it.

A robot ``NAME`` is a folder ``NAME/`` holding ``robot.yaml``::

    name: NAME
    urdf: NAME.urdf                 # relative to the folder, absolute, or example-robot-data:PATH
    srdf: NAME.srdf                 # optional: disabled self-collision pairs
    tip: LAST_LINK                  # the arm's last link (the chain runs root -> tip)
    facts:                          # optional (RobotFacts): learned-distance keypoints,
      keypoints: [...]              # CHOMP's sphere radius, the scenario sampler's ranges
      keypoint_segments: [[a, b, k], ...]
      keypoint_points: [[link, x, y, z], ...]   # points fixed in a link frame [m]
      sphere_radius: 0.08
      sampling_ranges: [[low, high], ...]
      reach_m: 0.99                 # horizontal reach of the collision geometry [m]
      accel_limits: [...]           # per joint [rad/s²] (the realistic actuator model)
      accel_source: "..."           # where those limits come from

The shipped robots live in ``nehmo_core/robots/data/``; more folders of robots can be named in
the environment variable ``NEHMO_ROBOTS`` (separated like ``PATH``), e.g. where
``nehmo robot add`` wrote one. A name found twice is an error (which one would be meant?).
"""

from __future__ import annotations

import importlib.metadata
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nehmo_core.errors import InvalidValueError, ModelFileError, UnknownNameError
from nehmo_core.robots.model import RobotFacts

__all__ = [
    "DATA_DIR",
    "ENV",
    "RobotDescription",
    "description_paths",
    "example_robot_data_share",
    "load_description",
    "robot_description",
    "robot_names",
    "write_description",
]

DATA_DIR = Path(__file__).resolve().parent / "data"
ENV = "NEHMO_ROBOTS"
EXAMPLE_ROBOT_DATA = "example-robot-data:"
_KEYS = {"name", "urdf", "srdf", "tip", "facts"}
_FACT_KEYS = {
    "keypoints",
    "keypoint_segments",
    "keypoint_points",
    "sphere_radius",
    "sampling_ranges",
    "reach_m",
    "accel_limits",
    "accel_source",
}


@dataclass(frozen=True)
class RobotDescription:
    """A robot's ``robot.yaml``: where its URDF and SRDF are, its tip link and its facts."""

    name: str
    urdf: Path
    tip: str
    srdf: Path | None = None
    facts: RobotFacts = field(default_factory=RobotFacts)
    source: Path | None = None  # the robot.yaml it came from


def example_robot_data_share() -> Path:
    """``.../share/example-robot-data`` of the installed package."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise ModelFileError(
            "this robot needs the 'example-robot-data' package; install the pinned requirements "
            "(./run does this)"
        ) from exc
    for f in dist.files or []:
        if str(f).endswith("share/example-robot-data/package.xml"):
            return Path(str(dist.locate_file(f))).parent
    raise ModelFileError("example-robot-data is installed but its share folder is not found")


def _file(folder: Path, ref: Any, where: str) -> Path:
    if not isinstance(ref, str) or not ref.strip():
        raise InvalidValueError(where, "must be a file path", ref)
    if ref.startswith(EXAMPLE_ROBOT_DATA):
        path = example_robot_data_share() / ref[len(EXAMPLE_ROBOT_DATA) :]
    else:
        path = Path(ref) if Path(ref).is_absolute() else folder / ref
    if not path.is_file():
        raise ModelFileError(f"{where}: file not found: {path}")
    return path


def _facts(raw: Any, where: str) -> RobotFacts:
    if raw is None:
        return RobotFacts()
    if not isinstance(raw, dict) or set(raw) - _FACT_KEYS:
        rule = f"must be a mapping with keys among {sorted(_FACT_KEYS)}"
        raise InvalidValueError(where, rule, raw)
    try:
        ranges = raw.get("sampling_ranges")
        return RobotFacts(
            keypoints=tuple(str(k) for k in raw.get("keypoints", ())),
            keypoint_segments=tuple(
                (str(a), str(b), int(k)) for a, b, k in raw.get("keypoint_segments", ())
            ),
            keypoint_points=tuple(
                (str(link), float(x), float(y), float(z))
                for link, x, y, z in raw.get("keypoint_points", ())
            ),
            sphere_radius=float(raw.get("sphere_radius", RobotFacts.sphere_radius)),
            sampling_ranges=None
            if ranges is None
            else tuple((float(lo), float(hi)) for lo, hi in ranges),
            reach_m=None if raw.get("reach_m") is None else float(raw["reach_m"]),
            accel_limits=None
            if raw.get("accel_limits") is None
            else tuple(float(a) for a in raw["accel_limits"]),
            accel_source=str(raw.get("accel_source", "")),
        )
    except (TypeError, ValueError) as exc:
        raise InvalidValueError(where, f"has a malformed entry ({exc})", raw) from None


def load_description(path: Path) -> RobotDescription:
    """Read and check one ``robot.yaml``; errors name the file and the field."""
    where = str(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ModelFileError(f"{where}: not a readable YAML file ({exc})") from exc
    if not isinstance(raw, dict):
        raise InvalidValueError(where, "must be a mapping with keys name, urdf, tip", raw)
    extra = sorted(set(raw) - _KEYS)
    if extra:
        raise InvalidValueError(where, f"may only have keys {sorted(_KEYS)}", extra)
    for key in ("name", "urdf", "tip"):
        if not isinstance(raw.get(key), str) or not raw[key].strip():
            raise InvalidValueError(f"{where}.{key}", "is required (text)", raw.get(key))
    if raw["name"] != path.parent.name:
        raise InvalidValueError(
            f"{where}.name", f"must be the folder's name {path.parent.name!r}", raw["name"]
        )
    folder = path.parent
    srdf = raw.get("srdf")
    return RobotDescription(
        name=raw["name"],
        urdf=_file(folder, raw["urdf"], f"{where}.urdf"),
        tip=raw["tip"],
        srdf=None if srdf is None else _file(folder, srdf, f"{where}.srdf"),
        facts=_facts(raw.get("facts"), f"{where}.facts"),
        source=path,
    )


def description_paths() -> dict[str, Path]:
    """Every robot's ``robot.yaml`` by name: the shipped ones, then those in ``NEHMO_ROBOTS``."""
    folders = [DATA_DIR] + [Path(p) for p in os.environ.get(ENV, "").split(os.pathsep) if p]
    found: dict[str, Path] = {}
    for folder in folders:
        if not folder.is_dir():
            raise ModelFileError(f"{ENV}: not a folder: {folder}")
        for path in sorted(folder.glob("*/robot.yaml")):
            name = path.parent.name
            if name in found:
                raise ModelFileError(f"robot {name!r} is described twice: {found[name]} and {path}")
            found[name] = path
    return found


def robot_names() -> tuple[str, ...]:
    return tuple(description_paths())


def robot_description(name: str) -> RobotDescription:
    paths = description_paths()
    if name not in paths:
        raise UnknownNameError("robot", name, paths)
    return load_description(paths[name])


def write_description(
    folder: Path,
    name: str,
    urdf: Path,
    tip: str,
    srdf: Path | None,
    facts: dict[str, Any] | None = None,
) -> Path:
    """``folder/name/robot.yaml`` for a checked URDF (paths absolute) and its ``facts``;
    returns its path."""
    out = folder / name / "robot.yaml"
    if out.exists():
        raise ModelFileError(f"{out} exists already (remove it to describe {name!r} anew)")
    data: dict[str, Any] = {"name": name, "urdf": str(urdf.resolve()), "tip": tip}
    if srdf is not None:
        data["srdf"] = str(srdf.resolve())
    if facts:
        data["facts"] = facts
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    load_description(out)  # what was written reads back
    return out
