"""Load robot models and cell layouts by name (no network access needed); which robots there
are, and what else is known about them, is in :mod:`nehmo_core.robots.registry`.

* ``ur5``: the URDF, collision meshes and SRDF of the ``example-robot-data`` package. Its
  ``package://`` URIs are rewritten into a cached copy (``$NEHMO_CACHE/robots``).
* ``kinova_gen3_6dof``: the project's own URDF (see its MODEL_CARD.json).
* ``planar_2link``: the planar arm of the HJR validation study.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import yaml

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError, UnknownNameError
from nehmo_core.robots.descriptions import robot_description
from nehmo_core.robots.model import (
    ArmSpec,
    Cell,
    JointSpec,
    Pose,
    RobotFacts,
    RobotModel,
    as_pose,
)
from nehmo_core.robots.registry import robot_facts
from nehmo_core.robots.urdf_check import check_urdf, mesh_path, package_roots

DATA_DIR = Path(__file__).resolve().parent / "data"
CELLS_DIR = Path(__file__).resolve().parent / "cells"


def cache_dir() -> Path:
    """Directory for derived files (rewritten URDFs, datasets, ground truth)."""
    root = os.environ.get("NEHMO_CACHE") or str(Path.home() / ".cache" / "nehmo")
    return Path(root)


def cell_names() -> tuple[str, ...]:
    return tuple(sorted(p.stem for p in CELLS_DIR.glob("*.yaml")))


def is_cell_file(ref: str | os.PathLike[str]) -> bool:
    """Whether a cell reference names a YAML file (not a shipped cell)."""
    return str(ref).endswith((".yaml", ".yml"))


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that a reader sees the old file or the new one, never half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as fh:
        fh.write(text)
    os.replace(fh.name, path)


def _resolved_urdf(urdf: Path) -> Path:
    """``urdf`` itself, or a cached copy with its ``package://`` URIs made absolute (PyBullet
    and the mesh readers need files): each resolves against the folders above the URDF and
    ``example-robot-data`` (:func:`~nehmo_core.robots.urdf_check.package_roots`)."""
    text = urdf.read_text()
    if "package://" not in text:
        return urdf
    roots = package_roots(urdf)

    def absolute(match: re.Match[str]) -> str:
        found = mesh_path(urdf, match.group(0), roots)
        if found is None:
            raise ModelFileError(f"{urdf}: unresolved mesh URI {match.group(0)!r}")
        return found.as_posix()

    text = re.sub(r"package://[^\"'<>\s]+", absolute, text)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    out = cache_dir() / "robots" / f"{urdf.stem.removesuffix('_robot')}_{digest}.urdf"
    if not out.exists():
        atomic_write(out, text)
    return out


def _parse_srdf(path: Path | None) -> frozenset[frozenset[str]]:
    if path is None or not path.exists():
        return frozenset()
    root = ET.parse(path).getroot()
    return frozenset(
        frozenset((e.attrib["link1"], e.attrib["link2"])) for e in root.iter("disable_collisions")
    )


def robot_from_urdf(
    name: str, urdf: Path, tip: str, srdf: Path | None = None, facts: RobotFacts | None = None
) -> RobotModel:
    """Build a :class:`RobotModel` from a URDF file (serial chain root → ``tip``), after the
    checks of :func:`~nehmo_core.robots.urdf_check.check_urdf` (one parser for both); its
    ``facts`` default to the description's for ``name`` (none for a robot without one). A
    revolute joint whose range spans a full turn is treated as continuous."""
    report = check_urdf(urdf, tip)
    joints = tuple(
        JointSpec(
            j.name,
            j.lower,
            j.upper,
            j.velocity,
            j.kind == "continuous" or j.upper - j.lower >= 2.0 * math.pi - 1e-9,
        )
        for j in report.joints
    )
    return RobotModel(
        name=name,
        urdf_path=urdf,
        root_link=report.root,
        tip_link=tip,
        joints=joints,
        links=report.collision_links,
        disabled_collision_pairs=_parse_srdf(srdf),
        facts=robot_facts(name) if facts is None else facts,
    )


@functools.cache
def load_robot(name: str) -> RobotModel:
    """Load a robot model by name: a shipped robot (``ur5``, ``kinova_gen3_6dof``,
    ``planar_2link``) or one described in a folder of ``NEHMO_ROBOTS``
    (:mod:`nehmo_core.robots.descriptions`)."""
    d = robot_description(name)
    return robot_from_urdf(name, _resolved_urdf(d.urdf), d.tip, d.srdf, d.facts)


def _require(mapping: dict[str, Any], key: str, where: str) -> Any:
    if key not in mapping:
        raise InvalidValueError(f"{where}.{key}", "is required", None)
    return mapping[key]


def _base_pose(base: Any, where: str) -> Pose:
    """An arm's ``base: {xyz: [3 m], rpy: [3 rad]}`` (both optional, zeros by default)."""
    base = {} if base is None else base
    if not isinstance(base, dict):
        raise InvalidValueError(where, "must be a mapping with keys xyz, rpy", base)
    extra = sorted(set(base) - {"xyz", "rpy"})
    if extra:
        raise InvalidValueError(where, "may only have keys xyz, rpy", extra)
    values = {}
    for key, unit in (("xyz", "m"), ("rpy", "rad")):
        raw = base.get(key, [0.0, 0.0, 0.0])
        try:
            numbers = [float(v) for v in raw] if isinstance(raw, list) else None
        except (TypeError, ValueError):
            numbers = None
        if numbers is None or len(numbers) != 3 or not all(math.isfinite(v) for v in numbers):
            raise InvalidValueError(
                f"{where}.{key}", f"must be a list of 3 finite numbers [{unit}]", raw
            )
        values[key] = numbers
    return as_pose(values["xyz"], values["rpy"])


def cell_from_dict(data: Any, source: str = "<cell>") -> Cell:
    """Build a :class:`Cell` from its YAML mapping, checking every field."""
    if not isinstance(data, dict):
        raise InvalidValueError(source, "must be a mapping with keys 'name' and 'arms'", data)
    arms_raw = _require(data, "arms", source)
    if not isinstance(arms_raw, list) or not arms_raw:
        raise InvalidValueError(f"{source}.arms", "must be a non-empty list of arms", arms_raw)
    arms = []
    for i, a in enumerate(arms_raw):
        where = f"{source}.arms[{i}]"
        if not isinstance(a, dict):
            raise InvalidValueError(where, "must be a mapping with keys id, robot, base", a)
        arm_id = str(_require(a, "id", where))
        if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", arm_id):
            raise InvalidValueError(
                f"{where}.id", "must be a valid ROS name (letter, then letters, digits, _)", arm_id
            )
        extra = sorted(set(a) - {"id", "robot", "base"})
        if extra:
            raise InvalidValueError(where, "may only have keys id, robot, base", extra)
        robot = load_robot(str(_require(a, "robot", where)))
        arms.append(ArmSpec(arm_id, robot, _base_pose(a.get("base", {}), f"{where}.base")))
    ids = [a.arm_id for a in arms]
    if len(set(ids)) != len(ids):
        raise InvalidValueError(f"{source}.arms", "must have unique ids", ids)
    return Cell(str(data.get("name", source)), tuple(arms))


def load_cell(name_or_path: str | os.PathLike[str]) -> Cell:
    """Load a cell layout: a shipped name (``dual_ur5``, ...) or a path to a YAML file."""
    text = str(name_or_path)
    if text in cell_names():
        path = CELLS_DIR / f"{text}.yaml"
    elif is_cell_file(text) or os.sep in text:
        path = Path(text)
        if not path.exists():
            raise ModelFileError(f"cell file not found: {path}")
    else:
        raise UnknownNameError("cell", text, cell_names())
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise NehmoError(f"{path}: not valid YAML ({exc})") from exc
    return cell_from_dict(data, source=str(path.name))
